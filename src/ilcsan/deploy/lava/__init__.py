"""A trained actor on Loihi 2's own toolchain: Lava processes from a deploy bundle, floating or fixed point.

:mod:`.plan` (numpy only) plans the network and simulates Lava's rules; :mod:`.network` builds and runs the Lava
processes (it needs ``lava-nc``, Python 3.10: ``scripts/setup-lava``); ``python -m ilcsan.deploy.lava BUNDLE`` (in
that environment, which ``ilcsan lava`` calls) runs the task closed loop and compares with the numpy runtime.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ...arguments import non_negative_int, positive_int

LAVA_PYTHON_VARIABLE = "ILCSAN_LAVA_PYTHON"
SETUP = "bash scripts/setup-lava"
INSTALLED_STAMP = ".ilcsan-installed"
"""The file scripts/setup-lava writes in .venv-lava when the installation finished."""


def lava_python() -> Path:
    """The Python of the Lava environment: ``$ILCSAN_LAVA_PYTHON``, else the checkout's ``.venv-lava`` once
    ``scripts/setup-lava`` has finished installing it."""
    from ...runtime.errors import UserError

    configured = os.environ.get(LAVA_PYTHON_VARIABLE)
    environment = Path(__file__).resolve().parents[4] / ".venv-lava"
    python = Path(configured) if configured else environment / "bin" / "python"
    ready = python.exists() and (configured or (environment / INSTALLED_STAMP).exists())
    if not ready:
        raise UserError(f"Lava's environment {python} is missing or incomplete: run `{SETUP}` in the checkout (it "
                        f"needs Python 3.10) or set {LAVA_PYTHON_VARIABLE} to a Python with lava-nc")
    return python


def run_options() -> argparse.ArgumentParser:
    """The options of a closed-loop run, as a parent parser: declared once for ``ilcsan lava`` and for
    ``python -m ilcsan.deploy.lava`` (which ``ilcsan lava`` calls with :func:`run_arguments`)."""
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--episodes", type=positive_int, default=10,
                        help="deterministic episodes (default 10, the paper's)")
    parser.add_argument("--seed", type=non_negative_int, default=0,
                        help="environment seed of the first episode (default 0)")
    parser.add_argument("--task", help="task (default: the actor's)")
    parser.add_argument("--fixed-point", action="store_true",
                        help="Loihi 2's bit-accurate fixed-point models: 8-bit weights with exponents, 24-bit "
                             "states (default: floating point)")
    parser.add_argument("--check", type=non_negative_int, default=0, metavar="N",
                        help="compare the first N actions with the bundle's numpy runtime: largest, median and "
                             "90th-percentile error (default 0: no check)")
    parser.add_argument("--json", metavar="FILE",
                        help="also write the results to this JSON file, rewritten after every episode "
                             "(\"finished\": false until the last)")
    return parser


def run_arguments(args: argparse.Namespace) -> list[str]:
    """The :func:`run_options` of ``args`` as command-line arguments."""
    arguments = ["--episodes", str(args.episodes), "--seed", str(args.seed), "--check", str(args.check)]
    arguments += ["--task", args.task] if args.task else []
    arguments += ["--fixed-point"] if args.fixed_point else []
    return arguments + (["--json", args.json] if args.json else [])
