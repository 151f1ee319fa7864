"""TD3's exploration (Fujimoto et al. 2018; the ILC-SAN paper): Gaussian noise on the deterministic action."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .base import Exploration, MethodContext


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
