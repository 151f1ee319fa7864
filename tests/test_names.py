"""One meaning per name: no class name defined twice in the package."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import ilcsan

PACKAGE = Path(ilcsan.__file__).parent


def test_no_class_name_is_defined_twice():
    """Each class at the top of a module of ``ilcsan`` has a name no other module's class has (a declaration of
    :mod:`ilcsan.methods` is ``…Declaration``, its training class in :mod:`ilcsan.rl` the bare name). The numpy
    runtime's fallback ``UserError``, defined only when the package is absent, is inside a ``try`` and not counted."""
    defined: dict[str, list[str]] = defaultdict(list)
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.ClassDef):
                defined[node.name].append(str(path.relative_to(PACKAGE)))
    assert {name: places for name, places in defined.items() if len(places) > 1} == {}


def test_the_default_names_are_the_registered_defaults():
    """:data:`~ilcsan.methods.DEFAULT_ALGORITHM` and :data:`~ilcsan.methods.NO_NORMALIZATION` are the first
    registered of their kinds (:func:`ilcsan.methods.default`) and the defaults of a run and of an actor."""
    from ilcsan import methods
    from ilcsan.config import ActorConfig, RunConfig

    assert methods.default("algorithm") == methods.DEFAULT_ALGORITHM == RunConfig().algorithm
    assert methods.default("normalization") == methods.NO_NORMALIZATION == ActorConfig().normalization
