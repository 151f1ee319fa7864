"""Checkpoints of a training run: per-seed files cut from the stacked ensemble, written together, restored.

K seeds train in stacked weights (:mod:`ilcsan.rl.td3`), but each seed's folder holds an ordinary
one-seed checkpoint: its slice of every weight and of Adam's moments (the critic's slices are twice as
wide: seed k owns twins 2k and 2k+1), its normaliser, replay segments, random generators and running
episode. A checkpoint also holds the action bounds, so a policy is rebuilt from it without an environment.

Multi-seed runs commit in two phases so that every seed always resumes from the same step: phase 1
writes each seed's ``checkpoint.next.pt``, phase 2 renames them all to ``checkpoint.pt``; a crash in
between is completed or undone by :func:`finish_interrupted_commit` on resume.
"""

from __future__ import annotations

import contextlib
from typing import Any

import numpy as np
import torch

from ..config import RunConfig
from ..errors import UserError
from .directory import CHECKPOINT, RunDirectory

CHECKPOINT_FORMAT = "ilcsan-checkpoint"
POLICY_FORMAT = "ilcsan-policy"
FORMAT_VERSION = 1
RESUME_SETTINGS = ("task", "actor", "td3", "eval_every", "eval_episodes")
"""The settings a resumed run must share with its checkpoint. The budget (``steps``) may change: a run resumed
with a larger ``--steps`` continues to it exactly as a run started with that budget would have (nothing in
training depends on the budget but where it stops), so a finished 200 000-step run extends to 1 000 000."""


# ----------------------------------------------------------------------------- per-seed slices
def slice_params(module: torch.nn.Module, index: int, factor: int) -> dict[str, torch.Tensor]:
    """Seed ``index``'s rows [factor·index, factor·(index+1)) of every parameter, on the CPU."""
    return {name: p.detach()[factor * index: factor * (index + 1)].cpu().clone()
            for name, p in module.named_parameters()}


def load_params(module: torch.nn.Module, slices: list[dict[str, torch.Tensor]], what: str) -> None:
    """Stack the seeds' ``slices`` (of :func:`slice_params`) back into ``module``'s parameters."""
    with torch.no_grad():
        for name, param in module.named_parameters():
            parts = []
            for per_seed in slices:
                if name not in per_seed:
                    raise UserError(f"the {what} in the checkpoint has no {name!r}: it belongs to another actor")
                parts.append(per_seed[name])
            stacked = torch.cat(parts).to(param.device, param.dtype)
            if stacked.shape != param.shape:
                raise UserError(f"the checkpoint's {what} {name!r} has shape {tuple(stacked.shape)}, this run "
                                f"needs {tuple(param.shape)}: it belongs to another actor or task")
            param.copy_(stacked)


def slice_optimizer(optimizer: torch.optim.Optimizer, module: torch.nn.Module, index: int,
                    factor: int) -> dict[str, dict[str, torch.Tensor]]:
    """Seed ``index``'s slice of the optimizer state of ``module``'s parameters (scalars such as Adam's
    step count are shared by all seeds and kept whole)."""
    state = {}
    for name, param in module.named_parameters():
        entry = optimizer.state.get(param)
        if not entry:
            continue
        state[name] = {key: (value.detach().cpu().clone() if value.dim() == 0
                             else value.detach()[factor * index: factor * (index + 1)].cpu().clone())
                       for key, value in entry.items()}
    return state


def load_optimizer(optimizer: torch.optim.Optimizer, module: torch.nn.Module,
                   slices: list[dict[str, dict[str, torch.Tensor]]]) -> None:
    """Stack the seeds' optimizer ``slices`` (of :func:`slice_optimizer`) back into ``optimizer``."""
    for name, param in module.named_parameters():
        if not all(name in per_seed for per_seed in slices):
            continue
        entry = {}
        for key, value in slices[0][name].items():
            if value.dim() == 0:
                entry[key] = value.clone()
            else:
                entry[key] = torch.cat([per_seed[name][key] for per_seed in slices]).to(param.device)
                if entry[key].shape != param.shape:
                    raise UserError(f"the checkpoint's optimizer state {name!r} has shape {tuple(entry[key].shape)}, "
                                    f"this run needs {tuple(param.shape)}: it belongs to another actor or task")
        optimizer.state[param] = entry


AGENT_PARTS = (("actor", "actor", 1), ("actor_target", "target actor (Proxy Target: the proxy)", 1),
               ("critic", "critic", 2), ("critic_target", "target critic", 2))
"""(attribute of the agent and key of the checkpoint, what it is called in errors, rows per seed)."""


def agent_state(agent: Any, index: int) -> dict[str, Any]:
    """Seed ``index``'s networks, targets and optimizer states."""
    state = {key: slice_params(getattr(agent, key), index, factor) for key, _, factor in AGENT_PARTS}
    state["actor_optimizer"] = slice_optimizer(agent.actor_optimizer, agent.actor, index, 1)
    state["critic_optimizer"] = slice_optimizer(agent.critic_optimizer, agent.critic, index, 2)
    if agent.proxy is not None:  # Proxy Target: the proxy is the "actor_target" above, here its optimizer
        state["proxy_optimizer"] = slice_optimizer(agent.proxy.optimizer, agent.proxy.actor, index, 1)
    exploration = agent.exploration
    if exploration is not None:  # NoisySAN: σ_d, its optimizer and the noise streams
        state["exploration"] = {"parameters": slice_params(exploration, index, 1),
                                "optimizer": slice_optimizer(exploration.optimizer, exploration, index, 1),
                                "streams": exploration.stream_state(index)}
    return state


def load_agent(agent: Any, states: list[dict[str, Any]]) -> None:
    """Stack the seeds' checkpoints ``states`` into ``agent`` (its seeds in the same order)."""
    for key, what, _ in AGENT_PARTS:
        load_params(getattr(agent, key), [state[key] for state in states], what)
    load_optimizer(agent.actor_optimizer, agent.actor, [state["actor_optimizer"] for state in states])
    load_optimizer(agent.critic_optimizer, agent.critic, [state["critic_optimizer"] for state in states])
    if agent.proxy is not None:
        load_optimizer(agent.proxy.optimizer, agent.proxy.actor, [state["proxy_optimizer"] for state in states])
    exploration = agent.exploration
    if exploration is not None:
        load_params(exploration, [state["exploration"]["parameters"] for state in states], "decoder noise scale")
        load_optimizer(exploration.optimizer, exploration, [state["exploration"]["optimizer"] for state in states])
        for index, state in enumerate(states):
            exploration.load_stream_state(index, state["exploration"]["streams"])
    agent.updates = states[0]["updates"]


def as_tensors(values: dict[str, Any]) -> dict[str, Any]:
    """numpy arrays → tensors (a checkpoint loads with ``weights_only``, which accepts tensors, not arrays)."""
    return {key: torch.as_tensor(value) if isinstance(value, np.ndarray) else value for key, value in values.items()}


def as_arrays(values: dict[str, Any]) -> dict[str, Any]:
    """The inverse of :func:`as_tensors`."""
    return {key: value.numpy() if torch.is_tensor(value) else value for key, value in values.items()}


# ------------------------------------------------------------------------------ commits on disk
@contextlib.contextmanager
def disk_errors(directory: RunDirectory, step: int):
    """A full or failing disk while writing results: one clear line; the last checkpoint is kept."""
    try:
        yield
    except OSError as error:
        raise UserError(f"step {step}: cannot write to {directory.path}: {error.strerror or error}; the last "
                        "checkpoint is kept: free some space, then continue with --resume") from None


def write_together(directories: list[RunDirectory], states: list[dict[str, Any]], step: int) -> None:
    """Write each seed's checkpoint; with several seeds first as pending files, then all renamed."""
    pending = len(directories) > 1
    for directory, state in zip(directories, states, strict=True):
        with disk_errors(directory, step):
            directory.write_checkpoint(state, pending=pending)
    if pending:
        for directory in directories:
            directory.commit_checkpoint()


def finish_interrupted_commit(directories: list[RunDirectory]) -> None:
    """Complete or undo a multi-seed checkpoint that a crash interrupted (see :func:`write_together`).

    If a seed still has only its old checkpoint while others have a pending one, phase 1 did not finish:
    the pending files are dropped. Otherwise (every seed either pending or already renamed) phase 2 is
    completed. So all seeds always resume from the same step."""
    pending = [d for d in directories if d.has_checkpoint(pending=True)]
    if not pending:
        return
    step = pending[0].read_checkpoint(pending=True).get("step")
    complete = all(d in pending or (d.has_checkpoint() and d.read_checkpoint().get("step") == step)
                   for d in directories)
    for directory in pending:
        if complete:
            directory.commit_checkpoint()
        else:
            directory.drop_pending_checkpoint()


def open_for_training(directories: list[RunDirectory], resume: bool, log) -> tuple[list, bool]:
    """Claim the seeds' folders for one training process; returns their locks and whether to resume.

    A folder that holds a run is refused without ``resume``; every folder must take a 64 KiB write; then
    each is locked, cleared of temporary files an interrupted write left, and an interrupted multi-seed
    commit is finished. Resuming needs a checkpoint in every seed's folder or in none."""
    existing = [d.path for d in directories if d.holds_run()]
    if existing and not resume:
        raise UserError(f"{existing[0]} already holds a run; add --resume to continue it, or choose another --out")
    for directory in directories:
        directory.check_writable()
    locks = []
    try:
        for directory in directories:
            locks.append(directory.lock())
        for directory in directories:
            directory.remove_temporary_files()
        if resume:
            finish_interrupted_commit(directories)
        with_checkpoint = [d for d in directories if d.has_checkpoint()]
        if with_checkpoint and len(with_checkpoint) != len(directories):
            raise UserError("only some seeds of this run have a checkpoint; resume them one by one or remove the "
                            "incomplete seed folders")
    except BaseException:
        for lock in locks:
            lock.close()
        raise
    if resume and not with_checkpoint:
        log(f"no checkpoint in {directories[0].path} yet; starting from step 0")
    return locks, resume and bool(with_checkpoint)


def check_resumable(directory: RunDirectory, state: dict[str, Any], config: RunConfig, state_dim: int,
                    action_dim: int) -> None:
    """Refuse a checkpoint of another format, other settings or another task shape (one line each)."""
    if state.get("format") != CHECKPOINT_FORMAT or state.get("version") != FORMAT_VERSION:
        raise UserError(f"{directory.file(CHECKPOINT)} is not an ilcsan training checkpoint (format "
                        f"{state.get('format')!r} v{state.get('version')})")
    saved = RunConfig.from_dict(state["config"])
    mismatch = [name for name in RESUME_SETTINGS if getattr(saved, name) != getattr(config, name)]
    if mismatch:
        raise UserError(f"{directory.path} was trained with different settings ({', '.join(mismatch)}); resume "
                        "with the same command, or choose another --out")
    if state["state_dim"] != state_dim or state["action_dim"] != action_dim:
        raise UserError(f"{directory.path}'s checkpoint was made for another task shape")
    if state["step"] > config.steps:
        raise UserError(f"{directory.path}'s checkpoint is at step {state['step']}, past --steps {config.steps}; "
                        f"give --steps {state['step']} or more")


# ------------------------------------------------------------------------- a trainer's state
def policy_state(trainer: Any, index: int) -> dict[str, Any]:
    """The deployable actor of seed ``index``: weights, config, frozen normaliser, action bounds."""
    config, environments, normalizer = trainer.config, trainer.environments, trainer.normalizer
    return {
        "format": POLICY_FORMAT, "version": FORMAT_VERSION, "task": config.task,
        "actor_config": config.actor.to_dict(), "state_dim": environments.state_dim,
        "action_dim": environments.action_dim, "action_scale": torch.as_tensor(environments.action_scale),
        "action_offset": torch.as_tensor(environments.action_offset),
        "actor": slice_params(trainer.agent.actor, index, 1),
        "obs_mean": torch.as_tensor(normalizer.mean[index]), "obs_std": torch.as_tensor(normalizer.std[index]),
        "obs_clip": float(normalizer.clip), "step": trainer.step, "seed": config.seeds[index],
    }


def checkpoint_state(trainer: Any, index: int, segments: list[str]) -> dict[str, Any]:
    """Everything seed ``index`` needs to resume exactly, and to rebuild its policy without an environment."""
    config, environments, agent = trainer.config, trainer.environments, trainer.agent
    return {
        "format": CHECKPOINT_FORMAT, "version": FORMAT_VERSION, "config": config.for_seed(config.seeds[index]),
        "state_dim": environments.state_dim, "action_dim": environments.action_dim,
        "action_scale": torch.as_tensor(environments.action_scale),
        "action_offset": torch.as_tensor(environments.action_offset),
        "step": trainer.step, "updates": agent.updates, "wall_seconds": trainer.wall_seconds,
        **agent_state(agent, index),
        "normalizer": as_tensors(trainer.normalizer.state(index)),
        "replay": {"total": trainer.replay.total, "capacity": trainer.replay.capacity, "segments": list(segments)},
        "rng": {"numpy": trainer.rngs[index].bit_generator.state, "noise": agent.noise_generators[index].get_state()},
        "env": as_tensors(environments.snapshot(index)),
        "evaluations": trainer.evaluations[index],
    }


class TrainingCheckpoints:
    """Saves and restores a trainer's seeds, one :class:`RunDirectory` each: checkpoints, replay segments,
    metrics, results and the best policy.

    ``trainer`` is the :class:`~ilcsan.rl.training.Trainer` being saved or restored (its ``config``,
    ``step``, ``wall_seconds``, ``agent``, ``replay``, ``normalizer``, ``rngs``, ``environments`` and
    ``evaluations``)."""

    def __init__(self, directories: list[RunDirectory], log=print):
        self.directories, self.log = directories, log
        self.segments: list[list[str]] = [[] for _ in directories]  # each seed's replay segments, in order
        self.checkpointed_total = 0  # replay inserts already written as segments

    def write_configs(self, config: RunConfig, measured: dict[str, Any] | None = None) -> None:
        """Each seed's config.json (:meth:`RunConfig.for_seed`) when a new run starts, with ``measured`` (what
        the run chose on this machine, e.g. its matmul path) beside the settings."""
        for directory, seed in zip(self.directories, config.seeds, strict=True):
            directory.write_config(config, seed, measured)

    def _record_budget(self, config: RunConfig, saved_steps: int) -> None:
        """A run resumed with another budget says so, and its config.json records the new one."""
        if saved_steps == config.steps:
            return
        self.log(f"budget: {saved_steps} → {config.steps} steps (the run continues as if started with {config.steps})")
        for directory in self.directories:
            directory.write_budget(config.steps)

    def save(self, trainer: Any) -> None:
        """Segments, metrics, then the checkpoints (committed together), then result.json: a crash anywhere
        keeps the previous checkpoint, and result.json never says "finished" before the final checkpoint."""
        for index, directory in enumerate(self.directories):
            with disk_errors(directory, trainer.step):
                segment = trainer.replay.write_segment(directory, index, self.checkpointed_total)
                if segment is not None:
                    self.segments[index].append(segment)
                directory.write_metrics(trainer.evaluations[index])
        states = [checkpoint_state(trainer, index, self.segments[index]) for index in range(len(self.directories))]
        write_together(self.directories, states, trainer.step)
        self.write_results(trainer)
        for directory, segments in zip(self.directories, self.segments, strict=True):
            directory.prune_replay_segments(segments)
        self.checkpointed_total = trainer.replay.total

    def save_policy(self, trainer: Any, index: int, eval_return_mean: float) -> None:
        """Seed ``index``'s actor as ``policy.pt`` (after an evaluation better than all before)."""
        state = policy_state(trainer, index)
        state["eval_return_mean"] = eval_return_mean
        with disk_errors(self.directories[index], trainer.step):
            self.directories[index].write_policy(state)

    def write_results(self, trainer: Any) -> None:
        for directory, result in zip(self.directories, trainer.results(), strict=True):
            with disk_errors(directory, trainer.step):
                directory.write_result({key: value for key, value in result.items() if key != "directory"})

    def restore(self, trainer: Any) -> None:
        """Continue ``trainer`` from its folders' checkpoints; anything wrong with them is one line."""
        try:
            self._restore(trainer)
        except UserError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError, IndexError, RuntimeError) as error:
            where = self.directories[0].path if len(self.directories) == 1 else "a seed"
            raise UserError(f"the checkpoint in {where} is incomplete or from another version of ilcsan "
                            f"({type(error).__name__}: {str(error)[:120]}); start again without --resume, or "
                            "choose another --out") from None

    def _restore(self, trainer: Any) -> None:
        environments = trainer.environments
        states = [directory.read_checkpoint() for directory in self.directories]
        for directory, state in zip(self.directories, states, strict=True):
            check_resumable(directory, state, trainer.config, environments.state_dim, environments.action_dim)
        steps = {state["step"] for state in states}
        if len(steps) != 1:
            raise UserError(f"the seeds' checkpoints are at different steps ({sorted(steps)}); resume them one by one")
        self._record_budget(trainer.config, RunConfig.from_dict(states[0]["config"]).steps)
        load_agent(trainer.agent, states)
        trainer.step, trainer.wall_seconds = states[0]["step"], float(states[0]["wall_seconds"])
        for index, (directory, state) in enumerate(zip(self.directories, states, strict=True)):
            trainer.normalizer.load(index, as_arrays(state["normalizer"]))
            self.segments[index] = list(state["replay"]["segments"])
            trainer.replay.load_segments(directory, index, self.segments[index], state["replay"]["total"])
            directory.prune_replay_segments(self.segments[index])
            trainer.rngs[index].bit_generator.state = state["rng"]["numpy"]
            trainer.agent.noise_generators[index].set_state(state["rng"]["noise"])
            trainer.evaluations[index] = list(state["evaluations"])
            directory.write_metrics(trainer.evaluations[index])
            if not environments.restore(index, as_arrays(state["env"]), trainer.step):
                if trainer.agent.exploration is not None:  # a new episode draws a new noise series
                    trainer.agent.exploration.end_episode(index)
                self.log(f"note: {trainer.config.task} cannot restore a running episode; seed "
                         f"{trainer.config.seeds[index]} resumes with a new episode (not bit-identical)")
        self.write_results(trainer)  # a crash may have come between the checkpoint and its result.json
        self.checkpointed_total = trainer.replay.total
        where = self.directories[0].path if len(self.directories) == 1 else self.directories[0].path.parent
        self.log(f"resumed {where} at step {trainer.step}")
