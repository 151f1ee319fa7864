"""TD3's own training methods (Fujimoto et al. 2018; the ILC-SAN paper): Gaussian noise on the deterministic action,
and a target actor that follows the actor slowly."""

from __future__ import annotations

import copy
from collections.abc import Sequence

import numpy as np

from .base import Exploration, MethodContext, TargetActor


class GaussianActionNoise(Exploration):
    """a = clip(π(s) + σ·scale·ε, low, high), ε ~ N(0, I) per seed from the seed's own generator, σ =
    ``td3.exploration_noise`` relative to the action half-range ``scale``."""

    def __init__(self, context: MethodContext):
        self.scale, self.offset = context.action_scale, context.action_offset
        self.sigma, self.action_dim = context.td3.exploration_noise, context.action_dim

    def explore(self, agent, states: np.ndarray, rngs: Sequence[np.random.Generator]) -> np.ndarray:
        low, high = self.offset - self.scale, self.offset + self.scale
        action = agent.act(states)
        noise = np.stack([rng.standard_normal(self.action_dim) for rng in rngs])
        return np.clip(action + noise * self.sigma * self.scale, low, high)


class PolyakTarget(TargetActor):
    """π' is a copy of the actor made at the start, moved at every delayed step by θ' ← τθ + (1 − τ)θ'."""

    soft_update = True

    def __init__(self, context: MethodContext):
        self.module = copy.deepcopy(context.actor)
        self.module.requires_grad_(False)
