"""Replay buffer for K seeds, with append-only segments for cheap, atomic checkpoints.

Transitions are stored per seed in arrays of shape (K, capacity, ·). Each seed samples its minibatch
with its own generator. For checkpointing, only the rows added since the last checkpoint are written
(one small ``.npz`` segment per checkpoint and seed) instead of the whole buffer every time; a resumed
run replays the segments in order, so a buffer that wrapped around is rebuilt exactly.
"""

from __future__ import annotations

import numpy as np

from ..errors import UserError
from ..runs.directory import RunDirectory

FIELDS = ("obs", "action", "reward", "next_obs", "terminal")


class ReplayBuffer:
    """FIFO of (s, a, r, s', terminal) for K seeds; ``total`` counts every insert ever made."""

    def __init__(self, ensemble: int, state_dim: int, action_dim: int, capacity: int):
        self.capacity = int(capacity)
        self.total = 0
        self.data = {
            "obs": np.zeros((ensemble, capacity, state_dim), np.float32),
            "action": np.zeros((ensemble, capacity, action_dim), np.float32),
            "reward": np.zeros((ensemble, capacity), np.float32),
            "next_obs": np.zeros((ensemble, capacity, state_dim), np.float32),
            "terminal": np.zeros((ensemble, capacity), np.float32),
        }

    @property
    def size(self) -> int:
        return min(self.total, self.capacity)

    def add(self, obs, action, reward, next_obs, terminal) -> None:
        """One transition per seed: obs (K, N), action (K, M), reward (K,), next_obs (K, N), terminal (K,)."""
        row = self.total % self.capacity
        for name, value in zip(FIELDS, (obs, action, reward, next_obs, terminal), strict=True):
            self.data[name][:, row] = value
        self.total += 1

    def sample(self, generators: list[np.random.Generator], batch_size: int) -> dict[str, np.ndarray]:
        """A minibatch per seed, indices drawn from that seed's generator → arrays (K, B, ·)."""
        indices = np.stack([generator.integers(0, self.size, batch_size) for generator in generators])
        seeds = np.arange(len(generators))[:, None]
        return {name: array[seeds, indices] for name, array in self.data.items()}

    def sample_states(self, generators: list[np.random.Generator], batch_size: int) -> np.ndarray:
        """States only (K, B, N), indices drawn as :meth:`sample` draws them (a training method's minibatches)."""
        indices = np.stack([generator.integers(0, self.size, batch_size) for generator in generators])
        return self.data["obs"][np.arange(len(generators))[:, None], indices]

    # ---------------------------------------------------------------------------- checkpoints
    def write_segment(self, directory: RunDirectory, seed_index: int, start: int) -> str | None:
        """Write rows inserted at [start, total) of one seed as ``replay/<start>-<end>.npz``; returns its name."""
        end = self.total
        if end <= start:
            return None
        start = max(start, end - self.capacity)
        rows = np.arange(start, end) % self.capacity
        name = f"{start:010d}-{end:010d}.npz"
        directory.write_replay_segment(name, {f: self.data[f][seed_index, rows] for f in FIELDS})
        return name

    def load_segments(self, directory: RunDirectory, seed_index: int, names: list[str], total: int) -> None:
        """Rebuild one seed's rows from its segments (in order) up to insert count ``total``."""
        for name in names:
            start, end = (int(part) for part in name.removesuffix(".npz").split("-"))
            arrays = directory.read_replay_segment(name, FIELDS)
            if len(arrays["obs"]) != end - start:
                raise UserError(f"replay segment {name} in {directory.path} has the wrong length; it is corrupt")
            rows = np.arange(start, end) % self.capacity
            for field in FIELDS:
                self.data[field][seed_index, rows] = arrays[field]
        self.total = total
