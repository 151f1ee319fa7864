"""What an off-policy agent is built for, beside its actor's configuration and its training settings: the task as its
networks see it (:class:`TaskSpace`) and where and how it computes (:class:`ComputeSettings`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ..compute.matmul import DEFAULT_MATMUL, MatmulPath


@dataclass(frozen=True)
class TaskSpace:
    """The sizes N of a state and M of an action; the action bounds as a = offset + scale · tanh(O), each (M,), from
    the task's Box; the task's name (``""`` for none: a method that needs it, as NoisySAN's return reference, says so)
    and its episode step limit (None: none)."""

    state_dim: int
    action_dim: int
    action_scale: Sequence[float]
    action_offset: Sequence[float]
    name: str = ""
    episode_steps: int | None = None

    def __post_init__(self) -> None:  # arrays as given (their dtype is the exploration's arithmetic)
        object.__setattr__(self, "action_scale", np.asarray(self.action_scale))
        object.__setattr__(self, "action_offset", np.asarray(self.action_offset))


@dataclass(frozen=True)
class ComputeSettings:
    """Where an agent computes: its ``device``; ``compile``, each update as one compiled program and a spiking actor's
    acting pass compiled; ``engine``, the actor's forward pass ('fast' or 'reference'); ``matmul_path``, where every
    network's products run."""

    device: str | torch.device = "cpu"
    compile: bool = False
    engine: str = "fast"
    matmul_path: MatmulPath = DEFAULT_MATMUL

    def __post_init__(self) -> None:
        object.__setattr__(self, "device", torch.device(self.device))


EAGER_ON_CPU = ComputeSettings()
"""An agent on the CPU, eager, the fast engine, torch's own matmul: what tests and small scripts build."""
