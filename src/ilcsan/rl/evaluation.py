"""The paper's evaluation protocol: deterministic episodes of the trained actor (Section IV-A).

One loop, :func:`run_lockstep`, runs every evaluation: the training evaluation (the K seeds of a run in
lockstep, one environment each) and ``ilcsan evaluate`` (one environment). Episode ``e`` of an environment
whose first episode has seed ``S`` is reset with :func:`episode_seed` ``(S, e) = S + e``:

- ``ilcsan evaluate --seed S`` plays episodes with seeds S, S + 1, ...;
- the training evaluation number ``i`` (``i = step // eval_every``) of run seed ``k`` starts at
  :func:`training_evaluation_seed` ``(k, i) = 1 000 000 + 10 007 k + 101 i``, so
  ``ilcsan evaluate --seed 1000000+10007k+101i`` replays that evaluation's episodes with the saved policy.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..errors import UserError
from .tasks import make_env

EVAL_SEED_OFFSET = 1_000_000
"""Training evaluations use seeds from here on, away from the training environments' own seeds."""


def episode_seed(first: int, episode: int) -> int:
    """The seed that resets episode ``episode`` (from 0) of an evaluation whose first episode has ``first``."""
    return first + episode


def training_evaluation_seed(run_seed: int, evaluation: int) -> int:
    """The first episode's seed of evaluation number ``evaluation`` (step // eval_every) of run seed ``run_seed``."""
    return EVAL_SEED_OFFSET + run_seed * 10_007 + evaluation * 101


def run_lockstep(envs: Sequence, act: Callable[[np.ndarray], np.ndarray], episodes: int, first_seeds: Sequence[int],
                 check: Callable[[int, str, float | np.ndarray], None] | None = None
                 ) -> tuple[list[list[float]], list[list[int]]]:
    """``episodes`` episodes in each of the K environments ``envs``, stepped together.

    ``act`` maps the K current observations (K, N) to K actions (K, M) (an environment that has finished
    its episodes keeps its last observation, its action is ignored); environment ``k`` resets episode ``e``
    with ``episode_seed(first_seeds[k], e)``. ``check(k, what, value)`` sees every observation and reward
    before it is used (to stop on non-finite values). Returns each environment's returns and lengths."""
    count = len(envs)
    returns: list[list[float]] = [[] for _ in range(count)]
    lengths: list[list[int]] = [[] for _ in range(count)]
    observations = np.zeros((count, *envs[0].observation_space.shape))
    running = np.ones(count, bool)
    episode_return, episode_length = np.zeros(count), np.zeros(count, int)
    check = check or (lambda *_: None)

    def reset(index: int) -> None:
        observations[index] = envs[index].reset(seed=episode_seed(first_seeds[index], len(returns[index])))[0]
        check(index, "observation", observations[index])
        episode_return[index], episode_length[index] = 0.0, 0

    for index in range(count):
        reset(index)
    while running.any():
        actions = act(observations)
        for index in np.flatnonzero(running):
            observation, reward, terminated, truncated, _ = envs[index].step(actions[index])
            check(index, "observation", observation)
            check(index, "reward", reward)
            observations[index] = observation
            episode_return[index] += reward
            episode_length[index] += 1
            if terminated or truncated:
                returns[index].append(float(episode_return[index]))
                lengths[index].append(int(episode_length[index]))
                if len(returns[index]) >= episodes:
                    running[index] = False
                else:
                    reset(int(index))
    return returns, lengths


def run_episodes(act, task: str, episodes: int, seed: int = 0) -> tuple[list[float], list[int]]:
    """Run ``episodes`` episodes of ``task`` with ``act(observation) -> action``, episode ``e`` seeded
    ``episode_seed(seed, e)``; returns the returns and lengths."""
    env = make_env(task)
    try:
        returns, lengths = run_lockstep([env], lambda observations: [act(observations[0].copy())], episodes, [seed])
    finally:
        env.close()
    return returns[0], lengths[0]


def evaluate_policy(policy, episodes: int = 10, seed: int = 0, task: str | None = None):
    """The deterministic policy's returns and lengths over ``episodes`` episodes (Section IV-A), seeded as
    the module docstring says (``seed`` is the first episode's seed)."""
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
