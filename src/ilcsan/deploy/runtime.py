"""The numpy runtime's former import path, kept for scripts: the runtime is :mod:`ilcsan.runtime`.

Importing this module warns (DeprecationWarning) and gives the runtime's own objects: its names here, and each of its
modules as ``ilcsan.deploy.runtime.<module>`` (``from ilcsan.deploy.runtime.host import normalize`` still works).
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
import warnings

from .. import runtime as _runtime
from ..runtime import *  # noqa: F403
from ..runtime import __all__  # noqa: F401

for _module in pkgutil.iter_modules(_runtime.__path__):
    globals()[_module.name] = sys.modules[f"{__name__}.{_module.name}"] = importlib.import_module(
        f"{_runtime.__name__}.{_module.name}")

warnings.warn("ilcsan.deploy.runtime is deprecated: import from ilcsan.runtime", DeprecationWarning, stacklevel=2)
