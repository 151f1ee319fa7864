"""Argument types shared by the ``ilcsan`` command and ``python -m ilcsan.deploy.lava``.

Plain :mod:`argparse` (no torch, no numpy), so that the Lava environment, which imports only the torch-free parts of
the package, checks its counts with the same types and messages as the main command.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable


def int_at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type: a whole number (underscores allowed, as in ``1_000_000``) of at least ``minimum``."""

    def parse(text: str) -> int:
        try:
            value = int(text.replace("_", ""))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{text!r} must be at least {minimum}")
        return value

    return parse


positive_int = int_at_least(1)
non_negative_int = int_at_least(0)
