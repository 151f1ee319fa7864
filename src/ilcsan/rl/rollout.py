"""The training environments of a run: one per seed, stepped together, with their running episodes.

Environment ``k`` is made with the run's seed ``k`` and its first episode is reset with that seed; later
episodes continue the environment's own random generator. Every observation and reward is checked before
it is stored: NaN, inf or a value beyond float32's range (the replay buffer stores float32) stops the run
with one line naming the step (:class:`~ilcsan.errors.TrainingDiverged`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from ..errors import TrainingDiverged
from .tasks import action_bounds, capture_env_state, make_env, restore_env_state

FLOAT32_MAX = float(np.finfo(np.float32).max)


def check_finite(value: Any, what: str, seed: int, step: int, where: str = "environment") -> None:
    """Stop at once on a non-finite ``what`` from the ``where`` of run seed ``seed`` at ``step``."""
    if not np.all(np.abs(np.asarray(value, dtype=np.float64)) <= FLOAT32_MAX):
        raise TrainingDiverged(
            f"step {step}: the {where} returned a non-finite {what} for seed {seed} (NaN, inf or beyond "
            "float32's range); the run stopped and kept its last checkpoint")


class Transition(NamedTuple):
    """One environment step of every seed, as the replay buffer stores it: (s, a, r, s', terminal)."""

    obs: np.ndarray
    action: np.ndarray
    reward: np.ndarray
    next_obs: np.ndarray
    terminal: np.ndarray


class TrainingEnvironments:
    """K environments of ``task`` (one per seed), their current observations (K, N) and episode returns (K,);
    ``contact_forces``: see :func:`~ilcsan.rl.tasks.make_env`."""

    def __init__(self, task: str, seeds: Sequence[int], contact_forces: str | None = None):
        self.task, self.seeds = task, tuple(seeds)
        self.envs: list = []
        try:
            for seed in self.seeds:
                self.envs.append(make_env(task, seed, contact_forces=contact_forces))
        except BaseException:
            self.close()
            raise
        self.state_dim = int(self.envs[0].observation_space.shape[0])
        self.action_dim = int(self.envs[0].action_space.shape[0])
        self.action_scale, self.action_offset = action_bounds(self.envs[0])
        self.observations = np.zeros((len(self.seeds), self.state_dim))
        self.episode_returns = np.zeros(len(self.seeds))

    def __len__(self) -> int:
        return len(self.envs)

    @property
    def episode_steps(self) -> int | None:
        """The task's step limit per episode (None without one)."""
        spec = getattr(self.envs[0], "spec", None)
        return getattr(spec, "max_episode_steps", None)

    def start(self) -> None:
        """Reset environment k with seed k: the first episode of a new run."""
        for index, (env, seed) in enumerate(zip(self.envs, self.seeds, strict=True)):
            self.observations[index] = self._checked(env.reset(seed=seed)[0], "observation", index, 0)
        self.episode_returns = np.zeros(len(self.envs))

    def step(self, actions: np.ndarray, step: int) -> tuple[Transition, list[int]]:
        """Step every environment once (``step`` counts from 1); returns the transitions and the indices of
        the environments whose episode ended (reset them with :meth:`reset`). A time-limit truncation ends
        an episode but is not terminal."""
        count = len(self.envs)
        next_observations = np.zeros_like(self.observations)
        rewards, terminals = np.zeros(count), np.zeros(count)
        finished = []
        for index, env in enumerate(self.envs):
            observation, reward, terminated, truncated, _ = env.step(actions[index])
            next_observations[index] = self._checked(observation, "observation", index, step)
            rewards[index] = self._checked(reward, "reward", index, step)
            terminals[index] = float(terminated)
            if terminated or truncated:
                finished.append(index)
        transition = Transition(self.observations, actions, rewards, next_observations, terminals)
        self.observations = next_observations
        self.episode_returns = self.episode_returns + rewards
        return transition, finished

    def reset(self, index: int, step: int) -> None:
        """Start the next episode of environment ``index`` (its own generator picks the initial state)."""
        self.observations[index] = self._checked(self.envs[index].reset()[0], "observation", index, step)
        self.episode_returns[index] = 0.0

    def _checked(self, value: Any, what: str, index: int, step: int) -> Any:
        check_finite(value, what, self.seeds[index], step)
        return value

    # --------------------------------------------------------------------------------- resume
    def snapshot(self, index: int) -> dict[str, Any]:
        """The running episode of environment ``index``: observation, return so far and the simulator state."""
        state = capture_env_state(self.envs[index])
        return {"observation": self.observations[index].copy(), "episode_return": float(self.episode_returns[index]),
                "physics": state["physics"], "kind": state["kind"], "elapsed": state["elapsed"],
                "np_random": state["np_random"]}

    def restore(self, index: int, saved: dict[str, Any], step: int) -> bool:
        """Continue the episode of :meth:`snapshot` ``saved``; where the task cannot be restored, start a new
        episode seeded ``seed + step`` and return False (the run then differs from an uninterrupted one)."""
        env, seed = self.envs[index], self.seeds[index]
        env.reset(seed=seed)
        if restore_env_state(env, saved):
            self.observations[index] = saved["observation"]
            self.episode_returns[index] = saved["episode_return"]
            return True
        self.observations[index] = env.reset(seed=seed + step)[0]
        self.episode_returns[index] = 0.0
        return False

    def close(self) -> None:
        for env in self.envs:
            env.close()
