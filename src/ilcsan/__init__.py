"""ilcsan: fully spiking actor networks with intra-layer connections (ILC-SAN) for continuous control.

Train with TD3, evaluate, reproduce the paper's tables, analyse energy, deploy to neuromorphic formats.
The deployed call is ``ilcsan.load(path).predict(observation)``. Importing ``ilcsan`` does not import torch
until a torch-backed name is used, so the numpy-only runtime ``ilcsan.deploy`` stays torch-free.
"""

from __future__ import annotations

import importlib

from .errors import UserError

__version__ = "0.1.0"

_LAZY = {"ActorConfig": "config", "TD3Config": "config", "PRESETS": "config", "actor_config": "config"}


def __getattr__(name: str):
    """Import the torch-backed names on first use."""
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def load(path):
    """Load a trained actor (run directory, policy.pt or checkpoint.pt) as a :class:`~ilcsan.runs.policy.Policy`."""
    from .runs.policy import load as _load

    return _load(path)


__all__ = ["ActorConfig", "TD3Config", "PRESETS", "actor_config", "load", "UserError", "__version__"]
