"""The paper's eight tasks on today's Gymnasium (``shared/TASKS.md``), and any other Box-action task.

The paper used Gym ``-v3``/``-v2`` ids on mujoco-py, which no longer installs. A short name maps to the
Gymnasium id and keyword arguments closest to the paper's state size (Table "task"); a full Gymnasium id
passes through as it is.
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import UserError


@dataclass(frozen=True)
class TaskSpec:
    """A paper task: its short name, the Gymnasium id and keyword arguments we use, and (N, M)."""

    name: str
    gym_id: str
    paper_id: str
    state_dim: int
    action_dim: int
    kwargs: dict[str, Any] = field(default_factory=dict)
    note: str = ""


PAPER_TASKS: dict[str, TaskSpec] = {spec.name: spec for spec in (
    TaskSpec("Ant", "Ant-v4", "Ant-v3", 111, 8, {"use_contact_forces": True},
             "contact forces on, as the paper's 111-dim state (mujoco-py zeroed them)"),
    TaskSpec("HalfCheetah", "HalfCheetah-v4", "HalfCheetah-v3", 17, 6),
    TaskSpec("Hopper", "Hopper-v4", "Hopper-v3", 11, 3),
    TaskSpec("Walker2d", "Walker2d-v4", "Walker2d-v3", 17, 6),
    TaskSpec("Humanoid", "Humanoid-v4", "Humanoid-v3", 376, 17, note="actions bounded at ±0.4"),
    TaskSpec("HumanoidStandup", "HumanoidStandup-v4", "HumanoidStandup-v2", 376, 17,
             note="actions bounded at ±0.4"),
    TaskSpec("InvertedDoublePendulum", "InvertedDoublePendulum-v4", "InvertedDoublePendulum-v2", 11, 1),
    TaskSpec("BipedalWalker", "BipedalWalker-v3", "BipedalWalker-v3", 24, 4,
             note="Box2D; episodes up to 1600 steps"),
)}

_LOWER_NAMES = {name.lower(): name for name in PAPER_TASKS}


def resolve_task(name: str) -> tuple[str, dict[str, Any]]:
    """Short name (case-insensitive) or Gymnasium id → (gym id, keyword arguments)."""
    short = _LOWER_NAMES.get(name.lower())
    if short is not None:
        spec = PAPER_TASKS[short]
        return spec.gym_id, dict(spec.kwargs)
    import gymnasium as gym

    if name not in gym.registry:
        raise UserError(
            f"unknown task {name!r}: use a paper task ({', '.join(PAPER_TASKS)}) or a registered "
            "Gymnasium id such as 'Pendulum-v1' (see `ilcsan tasks`)"
        )
    return name, {}


MUJOCO_WARNINGS: list[str] = []


def _route_mujoco_warnings() -> None:
    """Collect MuJoCo's warnings in :data:`MUJOCO_WARNINGS` instead of ``MUJOCO_LOG.TXT`` in the cwd."""
    try:
        import mujoco
    except ImportError:
        return
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(lambda message: MUJOCO_WARNINGS.append(str(message)))


@contextlib.contextmanager
def _quiet_environment_creation():
    """Silence Gymnasium's deprecation warnings and the MuJoCo compiler's notes on stderr while making."""
    _route_mujoco_warnings()
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as devnull, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            os.dup2(devnull.fileno(), 2)
            yield
    finally:
        sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)


def make_env(name: str, seed: int | None = None):
    """A Gymnasium environment for ``name`` with a Box action space, seeded if ``seed`` is given."""
    import gymnasium as gym
    from gymnasium import logger

    gym_id, kwargs = resolve_task(name)
    logger.min_level = logger.ERROR if hasattr(logger, "ERROR") else 40
    with _quiet_environment_creation():
        try:
            env = gym.make(gym_id, **kwargs)
        except gym.error.DependencyNotInstalled as error:
            raise UserError(f"task {name!r} needs an extra package: {error}") from None
    if not isinstance(env.action_space, gym.spaces.Box):
        env.close()
        raise UserError(
            f"task {name!r} has a {type(env.action_space).__name__} action space; spiking actors here "
            "produce continuous actions, so pick a task with a Box action space"
        )
    if not isinstance(env.observation_space, gym.spaces.Box) or len(env.observation_space.shape) != 1:
        env.close()
        raise UserError(f"task {name!r} needs a flat Box observation space, got {env.observation_space}")
    if seed is not None:
        env.reset(seed=seed)
        env.action_space.seed(seed)
    return env


def action_bounds(env) -> tuple[np.ndarray, np.ndarray]:
    """(scale, offset) with action = offset + scale · tanh(O) spanning the Box [low, high]."""
    low = np.asarray(env.action_space.low, dtype=np.float64)
    high = np.asarray(env.action_space.high, dtype=np.float64)
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
        raise UserError("the task's action space is unbounded; a tanh-squashed actor needs finite bounds")
    return (high - low) / 2.0, (high + low) / 2.0


def describe_tasks() -> list[dict[str, Any]]:
    """Rows for ``ilcsan tasks``: the paper's tasks with the sizes the paper used."""
    return [
        {"task": spec.name, "gym_id": spec.gym_id, "paper_id": spec.paper_id, "N": spec.state_dim,
         "M": spec.action_dim, "kwargs": spec.kwargs, "note": spec.note}
        for spec in PAPER_TASKS.values()
    ]


# ------------------------------------------------------------------ episode snapshots for resume
def capture_env_state(env) -> dict[str, Any]:
    """What an exact resume needs of a running episode: the simulator's integration state, the
    environment's random generator and the time-limit counter. Only tasks whose simulator state can be
    read (MuJoCo, and classic-control tasks with a ``state`` array) resume mid-episode; others start a
    new episode on resume (``physics`` is None)."""
    unwrapped = env.unwrapped
    snapshot: dict[str, Any] = {"physics": None, "kind": "none",
                                "elapsed": int(getattr(env, "_elapsed_steps", 0) or 0),
                                "np_random": unwrapped.np_random.bit_generator.state}
    if hasattr(unwrapped, "model") and hasattr(unwrapped, "data"):
        import mujoco

        signature = mujoco.mjtState.mjSTATE_INTEGRATION
        physics = np.empty(mujoco.mj_stateSize(unwrapped.model, signature))
        mujoco.mj_getState(unwrapped.model, unwrapped.data, physics, signature)
        snapshot.update(physics=physics, kind="mujoco")
    elif isinstance(getattr(unwrapped, "state", None), np.ndarray):
        snapshot.update(physics=np.array(unwrapped.state, dtype=np.float64), kind="state")
    return snapshot


def restore_env_state(env, snapshot: dict[str, Any]) -> bool:
    """Put a freshly reset ``env`` back into ``snapshot``; False if this task cannot be restored."""
    unwrapped = env.unwrapped
    physics = snapshot.get("physics")
    if physics is None:
        return False
    physics = np.asarray(physics, dtype=np.float64)
    if snapshot.get("kind") == "mujoco" and hasattr(unwrapped, "data"):
        import mujoco

        signature = mujoco.mjtState.mjSTATE_INTEGRATION
        if physics.shape != (mujoco.mj_stateSize(unwrapped.model, signature),):
            return False
        mujoco.mj_setState(unwrapped.model, unwrapped.data, physics, signature)
    elif snapshot.get("kind") == "state" and isinstance(getattr(unwrapped, "state", None), np.ndarray):
        unwrapped.state = physics.astype(unwrapped.state.dtype)
    else:
        return False
    unwrapped.np_random.bit_generator.state = snapshot["np_random"]
    if hasattr(env, "_elapsed_steps"):
        env._elapsed_steps = int(snapshot["elapsed"])
    return True
