"""ilcsan: fully spiking actor networks with intra-layer connections (ILC-SAN) for continuous control.

Train with TD3, evaluate, reproduce the paper's tables, analyse energy, deploy to neuromorphic formats.
The deployed call is ``ilcsan.load(path).predict(observation)``.
"""

from __future__ import annotations

from .config import PRESETS, ActorConfig, TD3Config, actor_config
from .errors import UserError

__version__ = "0.1.0"


def load(path):
    """Load a trained actor (run directory, policy.pt or checkpoint.pt) as a :class:`~ilcsan.policy.Policy`."""
    from .policy import load as _load

    return _load(path)


__all__ = ["ActorConfig", "TD3Config", "PRESETS", "actor_config", "load", "UserError", "__version__"]
