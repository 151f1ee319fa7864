"""ilcsan: fully spiking actor networks with intra-layer connections (ILC-SAN) for continuous control.

Train with TD3, evaluate, reproduce the paper's tables, analyse energy, deploy to neuromorphic formats.
The deployed call is ``ilcsan.load(path).predict(observation)``. Importing ``ilcsan`` imports only the
torch-free configuration; torch is imported when :func:`load` is first called, so the numpy-only runtime
``ilcsan.deploy`` stays torch-free.
"""

from __future__ import annotations

from typing import Any

from .config import PRESETS, ActorConfig, RunConfig, TrainingProtocol, actor_config, deprecated, training_config_class
from .errors import UserError
from .version import __version__


def load(path, compile=False):
    """Load a trained actor (run directory, policy.pt or checkpoint.pt) as a :class:`~ilcsan.deploy.policy.Policy`;
    ``compile=True`` makes its ``predict`` run compiled programs (:meth:`~ilcsan.deploy.policy.Policy.compile`)."""
    from .deploy.policy import load as load_policy

    return load_policy(path, compile=compile)


def __getattr__(name: str) -> Any:
    """``TrainingConfig``: the training settings of the methods registered now
    (:func:`ilcsan.config.training_config_class`); ``TD3Config``, its deprecated name."""
    if name == "TrainingConfig":
        return training_config_class()
    if name == "TD3Config":
        deprecated("ilcsan.TD3Config", "ilcsan.TrainingConfig")
        return training_config_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["ActorConfig", "RunConfig", "TrainingConfig", "TrainingProtocol", "PRESETS", "actor_config", "load",
           "UserError", "__version__"]
