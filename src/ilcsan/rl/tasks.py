"""The paper's eight tasks on today's Gymnasium, and any other registered task with a Box action space.

The paper ran Gym ``-v3``/``-v2`` ids on mujoco-py, which no longer installs. A short name ("Hopper") maps
to the Gymnasium id and keyword arguments whose state has the paper's size N (Table ``tab:task``): the
MuJoCo ``-v4`` tasks, because ``-v5`` changed the state of Ant, Humanoid, HumanoidStandup and
InvertedDoublePendulum. Gymnasium marks ``-v4`` "out of date"; that notice is expected here and is kept
off the console (:data:`VERSION_NOTE`, printed once by ``ilcsan tasks``). A full Gymnasium id passes
through as it is.

The paper's facts (order, Gym id, N, M) come from :mod:`ilcsan.paper.published`; only the Gymnasium side
(id, keyword arguments, a note) is declared here. Every failure to build a task, whatever Gymnasium or
the simulator raises, becomes one :class:`UserError` naming the task, the cause and a fix.

**Contact forces.** The paper's code ran gym 0.18 on mujoco-py 2.1, which never calls MuJoCo's
``mj_rnePostConstraint``: the external contact forces ``cfrc_ext`` (and ``cacc``, ``cfrc_int``) stay zero. The states
of Ant (84 of 111 values), Humanoid and HumanoidStandup (84 of 376) were therefore partly zeros, and so were the reward
terms computed from those forces (Ant's contact cost, HumanoidStandup's impact cost). Gymnasium calls it after every
step. ``contact_forces="zeroed"`` (:data:`ilcsan.config.CONTACT_FORCES`) restores the paper's simulator by zeroing
those arrays right after each simulation step, before the task reads them; ``"simulated"`` keeps MuJoCo's forces. The
default follows the task name (:func:`ilcsan.config.contact_forces_of`): the paper's tasks by short name whose state
holds the forces are zeroed, everything else simulated.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..config import CONTACT_FORCE_TASKS, RECORDED_BEFORE_CONTACT_FORCES, contact_forces_of
from ..errors import UserError
from ..paper.published import PAPER_TASK_NAMES
from ..paper.published import TASKS as PAPER_DIMS

MUJOCO_VERSION = "v4"
VERSION_NOTE = (f"MuJoCo tasks use Gymnasium's -{MUJOCO_VERSION} versions, whose states have the paper's sizes N "
                "(-v5 changed those of Ant, Humanoid, HumanoidStandup and InvertedDoublePendulum); "
                f"Gymnasium's notice that -{MUJOCO_VERSION} is out of date is expected and silenced.")


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


_GYMNASIUM_SIDE: dict[str, dict[str, Any]] = {
    "Ant": {"kwargs": {"use_contact_forces": True},
            "note": "use_contact_forces=True: the paper's 111 values (27 + 84 contact forces)"},
    "Humanoid": {"note": "actions bounded at ±0.4; 84 of the 376 values are contact forces"},
    "HumanoidStandup": {"note": "actions bounded at ±0.4; 84 of the 376 values are contact forces"},
    "BipedalWalker": {"gym_id": "BipedalWalker-v3", "note": "Box2D; episodes up to 1600 steps"},
}
"""What differs from "the paper's task at -v4 without keyword arguments": ours, not the paper's."""

CONTACT_FORCES_NOTE = ("contact_forces: zeroed reads MuJoCo's external contact forces as the paper's simulator did "
                       "(mujoco-py 2.1 never computed them: zeros in the state and in the rewards made from them); "
                       "--contact-forces simulated gives MuJoCo's; '-': the task's state and reward do not read them.")


def _spec(name: str) -> TaskSpec:
    dims, ours = PAPER_DIMS[name], _GYMNASIUM_SIDE.get(name, {})
    return TaskSpec(name, ours.get("gym_id", f"{name}-{MUJOCO_VERSION}"), dims.paper_id, dims.n, dims.m,
                    dict(ours.get("kwargs", {})), ours.get("note", ""))


TASK_SPECS: dict[str, TaskSpec] = {name: _spec(name) for name in PAPER_TASK_NAMES}
"""The paper's tasks by short name, in the paper's order."""

_LOWER_NAMES = {name.lower(): name for name in TASK_SPECS}


def resolve_task(name: str) -> tuple[str, dict[str, Any]]:
    """Short name (case-insensitive), Gymnasium id, or ``module:id`` → (gym id, keyword arguments).

    ``module:id`` is Gymnasium's own form for a task of your own: the module (e.g. ``my_robot.envs``) is imported
    first, so that its ``gymnasium.register(id=..., entry_point=...)`` calls run, and ``id`` is then made. Every
    process that builds the task imports the module again (grid workers, Ray nodes), so it must be importable there.
    """
    short = _LOWER_NAMES.get(name.lower())
    if short is not None:
        spec = TASK_SPECS[short]
        return spec.gym_id, dict(spec.kwargs)
    import gymnasium as gym

    module, separator, gym_id = name.rpartition(":")
    if separator:
        _import_task_module(module, name)
    if gym_id not in gym.registry:
        if separator:
            raise UserError(f"unknown task {gym_id!r}: importing {module!r} registered no task of that id; check "
                            "the id given to gymnasium.register in that module")
        raise UserError(
            f"unknown task {name!r}: use a paper task ({', '.join(TASK_SPECS)}), a registered Gymnasium id such as "
            "'Pendulum-v1' (see `ilcsan tasks`), or a task of your own as module:id (e.g. my_robot.envs:Arm-v0)"
        )
    return gym_id, {}


def task_file_name(name: str) -> str:
    """A task's name as part of a file or folder name: the id of a ``module:id`` task, any character other than
    letters, digits, ``.``, ``_`` and ``-`` replaced by ``-``."""
    return re.sub(r"[^A-Za-z0-9._-]+", "-", name.rpartition(":")[2])


def _import_task_module(module: str, name: str) -> None:
    """Import the module named by a ``module:id`` task; any failure is one UserError line."""
    import importlib

    if not module:
        raise UserError(f"task {name!r} names no module before ':'; write it as module:id, e.g. my_robot.envs:Arm-v0")
    try:
        importlib.import_module(module)
    except Exception as error:  # noqa: BLE001 - the module is the user's code: any failure is reported in one line
        cause = one_line(str(error)) or type(error).__name__
        raise UserError(f"task {name!r}: cannot import module {module!r} ({cause}); install it, or add its folder "
                        "to PYTHONPATH") from None


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


def one_line(text: str) -> str:
    """An exception's message as one plain line: terminal colour codes dropped, whitespace collapsed."""
    return " ".join(re.sub(r"\x1b\[[0-9;]*m", "", text).split()).rstrip(".")


def _newest_other_version(gym_id: str) -> str | None:
    """The newest registered version of the same environment, other than ``gym_id`` (None if none)."""
    import gymnasium as gym

    base, _, version = gym_id.rpartition("-v")
    others = [(int(v), f"{base}-v{v}") for other in gym.registry
              for b, _, v in [other.rpartition("-v")] if b == base and v.isdigit() and other != gym_id]
    return max(others)[1] if others else None


def _fix_for(name: str, gym_id: str, error: Exception) -> str:
    """What the user can do about ``error`` raised while building ``gym_id``."""
    paper_name = _LOWER_NAMES.get(gym_id.rpartition("-v")[0].lower())
    if paper_name is not None and gym_id != TASK_SPECS[paper_name].gym_id:
        return f"use the paper's task as `--task {paper_name}` ({TASK_SPECS[paper_name].gym_id} here)"
    if isinstance(error, ModuleNotFoundError) and error.name:
        return f"install the missing package ({error.name}) into this environment"
    if isinstance(error, TypeError):
        return "check the task's keyword arguments"
    if "MUJOCO_GL" in str(error):
        return RENDERING_FIX
    newer = _newest_other_version(gym_id)
    if newer is not None:
        return f"use another version of the task, e.g. --task {newer}"
    return "install what it asks for, or pick another task (see `ilcsan tasks`)"


RENDERING_FIX = ("set MUJOCO_GL=egl (needs libEGL) or MUJOCO_GL=osmesa (needs libOSMesa), or run where a display "
                 "exists")
"""What to do when a task cannot render its frames (videos)."""


def _build(name: str, gym_id: str, kwargs: dict[str, Any], seed: int | None):
    """``gym.make`` and the first reset; any exception becomes one UserError line with the cause and a fix."""
    import gymnasium as gym

    env = None
    try:
        with _quiet_environment_creation():
            env = gym.make(gym_id, **kwargs)
            env.reset(seed=seed)
    except Exception as error:  # noqa: BLE001 - every cause is reported to the user, in one line
        if env is not None:
            with contextlib.suppress(Exception):
                env.close()
        cause = one_line(str(error)) or type(error).__name__
        shown = name if name == gym_id else f"{name} ({gym_id})"
        if "render_mode" in kwargs:
            raise UserError(f"task {shown!r} cannot be built for rendering here: {cause}; {RENDERING_FIX}") from None
        raise UserError(f"task {shown!r} cannot be built here: {cause}; {_fix_for(name, gym_id, error)}") from None
    return env


def make_env(name: str, seed: int | None = None, render_mode: str | None = None, contact_forces: str | None = None):
    """A Gymnasium environment for ``name`` with a Box action space and a flat Box observation, reset once
    (seeded if ``seed`` is given); ``render_mode`` is Gymnasium's (e.g. ``"rgb_array"`` for videos);
    ``contact_forces``: one of :data:`ilcsan.config.CONTACT_FORCES`, None for the task's default (module docstring)."""
    import gymnasium as gym
    from gymnasium import logger

    gym_id, kwargs = resolve_task(name)
    if render_mode is not None:
        kwargs = {**kwargs, "render_mode": render_mode}
    logger.min_level = logger.ERROR if hasattr(logger, "ERROR") else 40
    env = _build(name, gym_id, kwargs, seed)
    if contact_forces_of(name, contact_forces) == "zeroed":
        _zero_contact_forces(env, name)  # a reset computes none of them: the first state is the paper's already
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
        env.action_space.seed(seed)
    return env


ZEROED_ARRAYS = ("cacc", "cfrc_int", "cfrc_ext")
"""The arrays only ``mj_rnePostConstraint`` computes, which the paper's mujoco-py never called: zeros there."""


def _zero_contact_forces(env, name: str) -> None:
    """Make ``env``'s simulation step leave :data:`ZEROED_ARRAYS` at zero, as the paper's simulator did, before the
    task reads its state and reward from them. The dynamics are untouched: MuJoCo computes these arrays from the
    state after a step and never reads them back."""
    unwrapped = env.unwrapped
    step = getattr(unwrapped, "_step_mujoco_simulation", None)
    if step is None or not hasattr(unwrapped, "data"):
        env.close()
        raise UserError(f"--contact-forces zeroed needs a MuJoCo task of Gymnasium's MujocoEnv; {name!r} is not "
                        "one: leave --contact-forces unset")

    def step_with_zero_contact_forces(ctrl, n_frames):
        step(ctrl, n_frames)
        for array in ZEROED_ARRAYS:
            getattr(unwrapped.data, array)[:] = 0.0

    unwrapped._step_mujoco_simulation = step_with_zero_contact_forces


def trained_contact_forces(policy) -> str:
    """The contact forces ``policy`` (a Policy or a deploy bundle's actor) was trained with; one saved before the
    setting existed trained with MuJoCo's (:data:`~ilcsan.config.RECORDED_BEFORE_CONTACT_FORCES`)."""
    return getattr(policy, "contact_forces", None) or RECORDED_BEFORE_CONTACT_FORCES


def make_envs(name: str, count: int, render_mode: str | None = None, contact_forces: str | None = None) -> list:
    """``count`` environments of ``name`` (see :func:`make_env`); if one cannot be built, those already built
    are closed before the error propagates."""
    envs: list = []
    try:
        for _ in range(count):
            envs.append(make_env(name, render_mode=render_mode, contact_forces=contact_forces))
    except BaseException:
        for env in envs:
            with contextlib.suppress(Exception):
                env.close()
        raise
    return envs


def action_bounds(env) -> tuple[np.ndarray, np.ndarray]:
    """(scale, offset) with action = offset + scale · tanh(O) spanning the Box [low, high]."""
    low = np.asarray(env.action_space.low, dtype=np.float64)
    high = np.asarray(env.action_space.high, dtype=np.float64)
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
        raise UserError("the task's action space is unbounded; a tanh-squashed actor needs finite bounds")
    return (high - low) / 2.0, (high + low) / 2.0


def describe_tasks() -> list[dict[str, Any]]:
    """Rows for ``ilcsan tasks``: the paper's tasks with the sizes the paper used (see :data:`VERSION_NOTE`)."""
    return [
        {"task": spec.name, "gym_id": spec.gym_id, "paper_id": spec.paper_id, "N": spec.state_dim,
         "M": spec.action_dim, "kwargs": spec.kwargs, "note": spec.note,
         "contact_forces": contact_forces_of(spec.name, None) if spec.name in CONTACT_FORCE_TASKS else "-"}
        for spec in TASK_SPECS.values()
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
