"""The pre-action penalty's training (declared in :mod:`ilcsan.methods.preaction_penalty`): λ·mean(O²) of the
actor's pre-tanh output O, per seed, added to the actor's loss by every algorithm."""

from __future__ import annotations

import torch

from .base import LossTerm, MethodContext


class PreactionPenalty(LossTerm):
    """Σ_k λ mean_{b,m} O_{k,b,m}², λ = ``training.preaction_penalty``."""

    def __init__(self, context: MethodContext):
        self.weight = context.training.preaction_penalty

    def loss(self, preaction: torch.Tensor) -> torch.Tensor:
        return self.weight * (preaction ** 2).mean(dim=(-2, -1)).sum()
