"""The package's layers only point down: every import of one part of ``ilcsan`` by another (at the top of a module or
inside a function) goes to a part below it in :data:`LAYERS`, the order docs/architecture.md explains."""

from __future__ import annotations

import ast
from pathlib import Path

import ilcsan

PACKAGE = Path(ilcsan.__file__).parent

LAYERS = ("errors", "arguments", "version", "runtime", "compute", "settings", "files", "methods", "config", "paper",
          "snn", "runs", "actors", "rl", "deploy", "analysis", "__init__", "experiments", "cli", "__main__")
"""The parts of the package from the ground up: a top-level module or package of ``ilcsan`` (``__init__`` is the
package's own face)."""


NEVER = {
    # the numpy runtime is copied alone next to a bundle: it takes the package's error type when there is a package
    "runtime": set(LAYERS) - {"runtime", "errors"},
    "snn": {"methods"},  # the spiking actor knows no training method: the builder (actors) hands it their parts
    "runs": {"snn"},  # a run's files are read without the network that wrote them
}
"""Imports that pointing down does not rule out, ruled out for a reason."""


def part_of(path: Path) -> str:
    """The part a source file belongs to: its top-level package, or its module's name."""
    relative = path.relative_to(PACKAGE)
    return relative.parts[0] if len(relative.parts) > 1 else relative.stem


def imported_parts(source: str, package: list[str]) -> set[str]:
    """The parts of ``ilcsan`` a module's ``source`` imports, absolutely or relatively (``package``: the dotted name
    of the package the module is in, as parts)."""
    tree = ast.parse(source)
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name.split(".") for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = (package[:len(package) - node.level + 1] if node.level else []) + (node.module or "").split(".")
            base = [part for part in base if part]
            names = [base + [alias.name] for alias in node.names] if node.module is None else [base]
        else:
            continue
        for name in names:
            if name[0] == "ilcsan":  # a name the package itself defines (``from ilcsan import __version__``): its face
                found.add(name[1] if len(name) > 1 and name[1] in LAYERS else "__init__")
    return found


def test_every_part_of_the_package_has_a_layer():
    parts = {part_of(path) for path in PACKAGE.rglob("*.py")}
    assert parts <= set(LAYERS), f"parts without a layer: {sorted(parts - set(LAYERS))}"


def test_imports_only_point_down():
    upward = []
    for path in sorted(PACKAGE.rglob("*.py")):
        source = part_of(path)
        package = ["ilcsan", *path.relative_to(PACKAGE).parent.parts]
        for target in imported_parts(path.read_text(), package) - {source}:
            if target in LAYERS and LAYERS.index(target) > LAYERS.index(source):
                upward.append(f"{path.relative_to(PACKAGE)} ({source}) imports {target}")
    assert not upward, "\n".join(upward)


def test_no_part_imports_what_it_must_not():
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        source = part_of(path)
        package = ["ilcsan", *path.relative_to(PACKAGE).parent.parts]
        found += [f"{path.relative_to(PACKAGE)} imports {target}"
                  for target in sorted(imported_parts(path.read_text(), package) & NEVER.get(source, set()))]
    assert not found, "\n".join(found)


def test_the_check_reads_relative_absolute_and_nested_imports():
    """What the test above relies on: imports of each form, in ``ilcsan/snn/``, are found with their part."""
    source = ("from ..rl import training\nfrom . import neurons\nimport ilcsan.deploy.bundle\n"
              "def f():\n    from ..cli import main\n    from .. import methods, __version__\n")
    assert imported_parts(source, ["ilcsan", "snn"]) == {"rl", "snn", "deploy", "cli", "methods", "__init__"}
