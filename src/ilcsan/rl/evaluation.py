"""The paper's evaluation protocol: deterministic episodes of the trained actor (Section IV-A).

One loop, :func:`run_lockstep`, runs every evaluation: the training evaluation (the E episodes of each of
the K seeds of a run, K × E environments stepped together, one actor call per step for all) and ``ilcsan
evaluate``. Episode ``e`` of an evaluation whose first episode has seed ``S`` is reset with
:func:`episode_seed` ``(S, e) = S + e``:

- ``ilcsan evaluate --seed S`` plays episodes with seeds S, S + 1, ...;
- the training evaluation number ``i`` (``i = step // eval_every``) of run seed ``k`` starts at
  :func:`training_evaluation_seed` ``(k, i) = 1 000 000 + 10 007 k + 101 i``, so
  ``ilcsan evaluate --seed 1000000+10007k+101i`` replays that evaluation's episodes with the saved policy.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch

from ..errors import UserError
from ..snn.diagnostics import DIAGNOSTIC_STATES, diagnose_actor
from .tasks import make_env, make_envs, trained_contact_forces

DIAGNOSTIC_SALT = 7
"""Offset of the generators that draw the diagnostics' replayed states from a seed and step."""
EVAL_SEED_OFFSET = 1_000_000
"""Training evaluations use seeds from here on, away from the training environments' own seeds."""


def episode_seed(first: int, episode: int) -> int:
    """The seed that resets episode ``episode`` (from 0) of an evaluation whose first episode has ``first``."""
    return first + episode


def training_evaluation_seed(run_seed: int, evaluation: int) -> int:
    """The first episode's seed of evaluation number ``evaluation`` (step // eval_every) of run seed ``run_seed``."""
    return EVAL_SEED_OFFSET + run_seed * 10_007 + evaluation * 101


def run_lockstep(envs: Sequence[Sequence], act: Callable[[np.ndarray], np.ndarray], first_seeds: Sequence[int],
                 check: Callable[[int, str, float | np.ndarray], None] | None = None,
                 observe: Callable[[np.ndarray, np.ndarray], None] | None = None,
                 ) -> tuple[list[list[float]], list[list[int]]]:
    """One episode in every environment ``envs[k][e]`` (K rows of E), all stepped together.

    ``act`` maps the current observations (K, E, N) to actions (K, E, M): one call per step for every row and
    episode (an environment whose episode has ended keeps its last observation; its action is ignored).
    Episode ``e`` of row ``k`` is reset with ``episode_seed(first_seeds[k], e)``, so the results equal the E
    episodes played one after another. ``check(k, what, value)`` sees every observation and reward before it
    is used (to stop on non-finite values); ``observe(actions, running)`` sees every step's actions (K, E, M) with
    the (K, E) mask of the episodes still running, whose actions are taken. Returns each row's returns and lengths,
    in episode order."""
    rows, episodes = len(envs), len(envs[0])
    observations = np.stack([np.stack([env.reset(seed=episode_seed(first_seeds[k], e))[0]
                                       for e, env in enumerate(row)]) for k, row in enumerate(envs)])
    check = check or (lambda *_: None)
    for k in range(rows):
        check(k, "observation", observations[k])
    returns, lengths = np.zeros((rows, episodes)), np.zeros((rows, episodes), int)
    running = np.ones((rows, episodes), bool)
    while running.any():
        actions = act(observations)
        if observe is not None:
            observe(actions, running)
        for k, e in zip(*np.nonzero(running), strict=True):
            observation, reward, terminated, truncated, _ = envs[k][e].step(actions[k, e])
            check(int(k), "observation", observation)
            check(int(k), "reward", reward)
            observations[k, e] = observation
            returns[k, e] += reward
            lengths[k, e] += 1
            running[k, e] = not (terminated or truncated)
    return returns.tolist(), lengths.tolist()


def replay_diagnostics(agent, replay, normalizer, seeds: Sequence[int], step: int) -> list[dict[str, float]]:
    """Each seed's actor diagnostics (:mod:`ilcsan.snn.diagnostics`) on ``DIAGNOSTIC_STATES`` replayed states,
    normalised as training sees them, drawn by generators of their own (from the seed and ``step``) so that the run's
    random streams are untouched."""
    generators = [np.random.default_rng([DIAGNOSTIC_SALT, seed, step]) for seed in seeds]
    states = normalizer.normalize(replay.sample_states(generators, DIAGNOSTIC_STATES))
    return diagnose_actor(agent.deployable_actor(), torch.as_tensor(states, device=agent.device))


def run_episodes(act, task: str, episodes: int, seed: int = 0, batched: bool = False,
                 video: Path | None = None, progress: bool = False,
                 contact_forces: str | None = None) -> tuple[list[float], list[int]]:
    """Run ``episodes`` episodes of ``task`` with ``act(observation) -> action``, episode ``e`` seeded
    ``episode_seed(seed, e)`` (in lockstep, one environment per episode); returns the returns and lengths.
    ``batched``: ``act`` maps all episodes' observations (E, N) to their actions (E, M) in one call.
    ``video``: a folder that receives one MP4 per episode (:mod:`ilcsan.rl.video`); the episodes are the same.
    ``progress``: a bar on stderr over the episodes' steps (each episode counts its time limit; an episode that ends
    sooner completes its share at the end). ``contact_forces``: see :func:`~ilcsan.rl.tasks.make_env`."""
    if video is None:
        envs = make_envs(task, episodes, contact_forces=contact_forces)
    else:
        from .video import EpisodeVideo, ffmpeg, prepare_rendering

        ffmpeg()  # a missing encoder is reported before any episode runs
        prepare_rendering()
        envs = [EpisodeVideo(env, video, task) for env in make_envs(task, episodes, render_mode="rgb_array",
                                                                      contact_forces=contact_forces)]
    try:
        def act_all(observations: np.ndarray) -> np.ndarray:
            if batched:
                return act(observations[0].copy())[None]
            return np.stack([act(observation.copy()) for observation in observations[0]])[None]

        with _step_bar(task, envs, enabled=progress) as count_steps:
            returns, lengths = run_lockstep([envs], act_all, [seed], observe=count_steps)
    finally:
        for env in envs:
            env.close()
    return returns[0], lengths[0]


@contextlib.contextmanager
def _step_bar(task: str, envs: Sequence, enabled: bool):
    """A tqdm bar over the steps of ``envs``' episodes; yields the ``observe`` hook of :func:`run_lockstep`."""
    from tqdm import tqdm

    limit = getattr(envs[0].spec, "max_episode_steps", None)
    bar = tqdm(total=limit and limit * len(envs), disable=not enabled, unit="step", dynamic_ncols=True, leave=False,
               desc=f"{task}: {len(envs)} episode" + ("s" if len(envs) != 1 else ""))
    try:
        yield lambda _actions, running: bar.update(int(running.sum()))
        if bar.total:
            bar.update(bar.total - bar.n)
    finally:
        bar.close()


def evaluate_policy(policy, episodes: int = 10, seed: int = 0, task: str | None = None, video: Path | None = None,
                    progress: bool = False, contact_forces: str | None = None):
    """The deterministic policy's returns and lengths over ``episodes`` episodes (Section IV-A), seeded as
    the module docstring says (``seed`` is the first episode's seed); one call per step for all episodes, as the
    training loop evaluates. ``policy``: an ``ilcsan.Policy`` (its ``predict``) or a deploy bundle's numpy runtime,
    ``ilcsan.deploy.DeployedActor`` (its ``act``: the deployed network itself, int8 weights included).
    ``video``: also write each episode to ``video/<task>-seed<S>.mp4`` (:mod:`ilcsan.rl.video`); ``progress``: a
    bar over the steps on stderr. ``contact_forces``: as the policy was trained (:func:`trained_contact_forces`)
    unless given."""
    task = task or policy.task
    if not task:
        raise UserError("the actor does not name its task; pass --task")
    contact_forces = contact_forces or trained_contact_forces(policy)
    env = make_env(task, contact_forces=contact_forces)
    shape = env.observation_space.shape
    env.close()
    if shape != (policy.state_dim,):
        raise UserError(f"task {task!r} has observations of shape {shape}; the policy was trained for "
                        f"({policy.state_dim},)")
    act = policy.predict if hasattr(policy, "predict") else policy.act
    return run_episodes(act, task, episodes, seed, batched=True, video=video, progress=progress,
                        contact_forces=contact_forces)


def random_policy_return(task: str, episodes: int = 5, seed: int = 0, contact_forces: str | None = None) -> float:
    """Average return of uniformly random actions: the floor a trained actor must clear."""
    env = make_env(task, contact_forces=contact_forces)
    space = env.action_space
    env.close()
    rng = np.random.default_rng(seed)
    returns, _ = run_episodes(lambda _obs: rng.uniform(space.low, space.high), task, episodes, seed,
                              contact_forces=contact_forces)
    return float(np.mean(returns))
