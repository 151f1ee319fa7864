"""A run's state per seed, as its files hold it: everything one seed's checkpoint needs to resume exactly, how a run
continues from the seeds' checkpoints, a seed's deployable policy (``policy.pt``) and what its ``result.json`` says.

The training loop (:class:`~ilcsan.rl.training.Trainer`) owns the parts — environments, algorithm, replay buffer,
normaliser, generators, evaluations — and these functions lay them out, so that each file's layout is written once,
here. ``run`` is the trainer: its ``config``, ``environments``, ``agent``, ``normalizer``, ``replay``, ``rngs``,
``evaluations``, ``step``, ``wall_seconds`` and ``log``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from ..config import RunConfig
from ..runs.checkpoint import as_arrays, as_tensors, slice_state


def seed_state(run, index: int, segments: list[str]) -> dict[str, Any]:
    """Everything seed ``index`` needs to resume exactly (with ``segments``, its replay so far), and to rebuild its
    policy without an environment: the checkpoint's layout."""
    config, environments = run.config, run.environments
    agent = run.agent.seed_state(index)
    noise = agent.pop("noise_generator")
    return {
        "config": config.for_seed(config.seeds[index]), "state_dim": environments.state_dim,
        "action_dim": environments.action_dim, "action_scale": torch.as_tensor(environments.action_scale),
        "action_offset": torch.as_tensor(environments.action_offset), "step": run.step,
        "wall_seconds": run.wall_seconds, **agent,
        "normalizer": as_tensors(run.normalizer.state(index)),
        "replay": {"total": run.replay.total, "capacity": run.replay.capacity, "segments": list(segments)},
        "rng": {"numpy": run.rngs[index].bit_generator.state, "noise": noise},
        "env": as_tensors(environments.snapshot(index)), "evaluations": run.evaluations[index],
    }


def load_seed_states(run, states: list[dict[str, Any]]) -> None:
    """Continue ``run`` from the seeds' checkpoints (:func:`seed_state`; the replay is the checkpoints' to rebuild)."""
    run.agent.load_seed_states([{**state, "noise_generator": state["rng"]["noise"]} for state in states])
    run.step, run.wall_seconds = states[0]["step"], float(states[0]["wall_seconds"])
    for index, state in enumerate(states):
        run.normalizer.load(index, as_arrays(state["normalizer"]))
        run.rngs[index].bit_generator.state = state["rng"]["numpy"]
        run.evaluations[index] = list(state["evaluations"])
        if not run.environments.restore(index, as_arrays(state["env"]), run.step):
            run.agent.end_episode(index)  # a new episode (for the exploration method too)
            run.log(f"note: {run.config.task} cannot restore a running episode; seed {run.config.seeds[index]} "
                    "resumes with a new episode (not bit-identical)")


def policy_state(run, index: int) -> dict[str, Any]:
    """The deployable actor of seed ``index``: weights and persistent buffers, config, frozen normaliser, action
    bounds: the layout of ``policy.pt``."""
    config, environments, normalizer = run.config, run.environments, run.normalizer
    return {
        "task": config.task, "contact_forces": config.task_contact_forces(), "algorithm": config.algorithm,
        "actor_config": config.actor.to_dict(), "state_dim": environments.state_dim,
        "action_dim": environments.action_dim, "action_scale": torch.as_tensor(environments.action_scale),
        "action_offset": torch.as_tensor(environments.action_offset),
        "actor": slice_state(run.agent.deployable_actor(), index, 1),
        "obs_mean": torch.as_tensor(normalizer.mean[index]), "obs_std": torch.as_tensor(normalizer.std[index]),
        "obs_clip": float(normalizer.clip), "step": run.step, "seed": config.seeds[index],
    }


def seed_result(config: RunConfig, index: int, directory: Path, rows: list[dict[str, float]], step: int,
                wall_seconds: float) -> dict[str, Any]:
    """What result.json says of seed ``index`` (and ``train`` returns): its best evaluation so far and progress."""
    best = max(rows, key=lambda row: row["eval_return_mean"]) if rows else None
    return {"seed": config.seeds[index], "directory": str(directory),
            "best_return": best["eval_return_mean"] if best else None, "best_step": best["step"] if best else None,
            "steps_done": step, "steps_total": config.steps, "finished": step >= config.steps,
            "wall_seconds": round(wall_seconds, 3)}
