"""Running observation normalisation (as in the authors' code): z-score with running mean and
variance, clipped to ±3; used when acting and when training (the critic sees it too), saved with the
model and frozen at deployment. One set of statistics per seed (leading dimension K).
"""

from __future__ import annotations

import numpy as np

from ..errors import UserError
from ..runtime.host import normalize

DEFAULT_CLIP = 3.0
EPSILON = 1e-8


class RunningNormalizer:
    """Welford running mean/variance of observations for K seeds, shapes (K, N)."""

    def __init__(self, ensemble: int, state_dim: int, clip: float = DEFAULT_CLIP):
        self.clip = clip
        self.count = np.zeros(ensemble, dtype=np.float64)
        self.mean = np.zeros((ensemble, state_dim), dtype=np.float64)
        self.m2 = np.zeros((ensemble, state_dim), dtype=np.float64)

    def update(self, observations: np.ndarray, mask: np.ndarray | None = None) -> None:
        """Add one observation per seed (K, N); seeds where ``mask`` is False are left alone."""
        observations = np.asarray(observations, dtype=np.float64)
        weight = np.ones_like(self.count) if mask is None else np.asarray(mask, dtype=np.float64)
        self.count += weight
        safe_count = np.maximum(self.count, 1.0)[:, None]
        delta = observations - self.mean
        self.mean += weight[:, None] * delta / safe_count
        self.m2 += weight[:, None] * delta * (observations - self.mean)

    @property
    def variance(self) -> np.ndarray:
        variance = self.m2 / np.maximum(self.count, 1.0)[:, None]
        return np.where(self.count[:, None] > 0, variance, 1.0)

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(self.variance + EPSILON)

    def normalize(self, observations: np.ndarray) -> np.ndarray:
        """(K, ..., N) raw observations → clipped z-scores, float32: the deployed actor's normaliser
        (:func:`ilcsan.runtime.host.normalize`) with each seed's current statistics."""
        shape = (self.mean.shape[0],) + (1,) * (observations.ndim - 2) + (self.mean.shape[1],)
        return normalize(observations, self.mean.reshape(shape), self.std.reshape(shape), self.clip)

    def state(self, seed_index: int) -> dict:
        return {"count": float(self.count[seed_index]), "mean": self.mean[seed_index].copy(),
                "m2": self.m2[seed_index].copy(), "clip": float(self.clip)}

    def load(self, seed_index: int, state: dict) -> None:
        mean = np.asarray(state["mean"], dtype=np.float64)
        if mean.shape != self.mean.shape[1:]:
            raise UserError(f"checkpoint normaliser has {mean.shape} statistics, the task needs "
                            f"{self.mean.shape[1:]}: it belongs to another task")
        self.count[seed_index] = float(state["count"])
        self.mean[seed_index] = mean
        self.m2[seed_index] = np.asarray(state["m2"], dtype=np.float64)
        self.clip = float(state["clip"])

