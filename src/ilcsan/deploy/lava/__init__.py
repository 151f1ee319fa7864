"""A trained actor on Loihi 2's own toolchain: Lava processes from a deploy bundle, floating or fixed point.

:mod:`.plan` (numpy only) plans the network and simulates Lava's rules; :mod:`.network` builds and runs the Lava
processes (it needs ``lava-nc``, Python 3.10: ``scripts/setup-lava``); ``python -m ilcsan.deploy.lava BUNDLE`` (in
that environment, which ``ilcsan lava`` calls) runs the task closed loop and compares with the numpy runtime.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..runtime.errors import UserError

LAVA_PYTHON_VARIABLE = "ILCSAN_LAVA_PYTHON"
SETUP = "bash scripts/setup-lava"
INSTALLED_STAMP = ".ilcsan-installed"
"""The file scripts/setup-lava writes in .venv-lava when the installation finished."""


def lava_python() -> Path:
    """The Python of the Lava environment: ``$ILCSAN_LAVA_PYTHON``, else the checkout's ``.venv-lava`` once
    ``scripts/setup-lava`` has finished installing it."""
    configured = os.environ.get(LAVA_PYTHON_VARIABLE)
    environment = Path(__file__).resolve().parents[4] / ".venv-lava"
    python = Path(configured) if configured else environment / "bin" / "python"
    ready = python.exists() and (configured or (environment / INSTALLED_STAMP).exists())
    if not ready:
        raise UserError(f"Lava's environment {python} is missing or incomplete: run `{SETUP}` in the checkout (it "
                        f"needs Python 3.10) or set {LAVA_PYTHON_VARIABLE} to a Python with lava-nc")
    return python
