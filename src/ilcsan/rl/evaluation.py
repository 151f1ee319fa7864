"""The paper's evaluation protocol for a trained policy: deterministic episodes (≤ the task's limit)."""

from __future__ import annotations

import numpy as np

from ..errors import UserError
from .tasks import make_env


def run_episodes(act, task: str, episodes: int, seed: int = 0) -> tuple[list[float], list[int]]:
    """Run ``episodes`` episodes of ``task`` with ``act(observation) -> action``; returns returns and lengths."""
    env = make_env(task)
    returns, lengths = [], []
    try:
        for episode in range(episodes):
            observation, _ = env.reset(seed=seed + episode)
            total, length, done = 0.0, 0, False
            while not done:
                observation, reward, terminated, truncated, _ = env.step(act(observation))
                total += float(reward)
                length += 1
                done = terminated or truncated
            returns.append(total)
            lengths.append(length)
    finally:
        env.close()
    return returns, lengths


def evaluate_policy(policy, episodes: int = 10, seed: int = 0, task: str | None = None):
    """Average the deterministic policy's return over ``episodes`` episodes (Section IV-A)."""
    task = task or policy.task
    env = make_env(task)
    shape = env.observation_space.shape
    env.close()
    if shape != (policy.state_dim,):
        raise UserError(f"task {task!r} has observations of shape {shape}; the policy was trained for "
                        f"({policy.state_dim},)")
    return run_episodes(policy.predict, task, episodes, seed)


def random_policy_return(task: str, episodes: int = 5, seed: int = 0) -> float:
    """Average return of uniformly random actions: the floor a trained actor must clear."""
    env = make_env(task)
    space = env.action_space
    env.close()
    rng = np.random.default_rng(seed)
    returns, _ = run_episodes(lambda _obs: rng.uniform(space.low, space.high), task, episodes, seed)
    return float(np.mean(returns))
