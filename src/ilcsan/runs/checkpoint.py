"""Checkpoints of a training run: per-seed files cut from the stacked ensemble, written together, restored.

The run and its parts give and take their own state (``seed_state``/``load_seed_states``); this module owns the files:
where they go, the checks a checkpoint must pass to resume, the per-seed slicing helpers the parts use
(:func:`slice_state`, :func:`load_state`: parameters and persistent buffers; :func:`first_readout`: the acting
readout's part of an actor with several), and the two-phase commit.

K seeds train in stacked weights (:mod:`ilcsan.rl.algorithms`), but each seed's folder holds an ordinary
one-seed checkpoint: its slice of every weight, persistent buffer and Adam moment (the critics' slices are C times
as wide: TD3's seed k owns twins 2k and 2k+1), its normaliser, replay segments, random generators and running
episode. A checkpoint also holds the action bounds, so a policy is rebuilt from it without an environment.

Multi-seed runs commit in two phases so that every seed always resumes from the same step: phase 1
writes each seed's ``checkpoint.next.pt``, phase 2 renames them all to ``checkpoint.pt``; a crash in
between is completed or undone by :func:`finish_interrupted_commit` on resume.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np
import torch

from ..config import RunConfig
from ..errors import UserError
from . import provenance
from .directory import CHECKPOINT, PROVENANCE, RunDirectory, RunFileError

CHECKPOINT_FORMAT = "ilcsan-checkpoint"
POLICY_FORMAT = "ilcsan-policy"
FORMAT_VERSION = 1
RESUME_SETTINGS = ("task", "algorithm", "actor", "training", "eval_every", "eval_episodes")
"""The settings a resumed run must share with its checkpoint. The budget (``steps``) may change: a run resumed
with a larger ``--steps`` continues to it exactly as a run started with that budget would have (nothing in
training depends on the budget but where it stops), so a finished 200 000-step run extends to 1 000 000."""


def differing_settings(saved: RunConfig, config: RunConfig) -> list[str]:
    """The :data:`RESUME_SETTINGS` in which ``config``, as its config.json records it (:meth:`RunConfig.recorded`),
    differs from the ``saved`` run's. Groups of settings compare by their values: a field at its default counts as
    unset, so training settings made before a method was registered (without its fields) equal the same settings
    made after."""
    recorded = config.recorded()
    return [name for name in RESUME_SETTINGS
            if _chosen_values(getattr(saved, name)) != _chosen_values(getattr(recorded, name))]


def _chosen_values(setting: Any) -> Any:
    """A dataclass of settings as its fields that differ from their defaults, by name; any other value as it is."""
    if not dataclasses.is_dataclass(setting):
        return setting
    fields = ((field.name, field.default if field.default_factory is dataclasses.MISSING else field.default_factory())
              for field in dataclasses.fields(setting))
    return {name: getattr(setting, name) for name, default in fields if getattr(setting, name) != default}


# ----------------------------------------------------------------------------- per-seed slices
def module_state(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    """What a file must keep of ``module``: its parameters and persistent buffers by name (``state_dict``'s names
    and order), the tensors themselves. Each carries the ensemble dimension first (the convention:
    :mod:`ilcsan.snn.ensemble`); the non-persistent constants are rebuilt from the config and left out. A module
    that breaks the convention (a tensor without the leading dimension its others have) is a bug, said here."""
    state = dict(module.state_dict(keep_vars=True))
    rows = {name: tensor.shape[0] if tensor.dim() else None for name, tensor in state.items()}
    if None in rows.values() or len(set(rows.values())) > 1:
        raise ValueError(f"{type(module).__name__}'s state does not carry one ensemble dimension first ({rows}): "
                         "register constants with persistent=False")
    return state


def missing_state(module: torch.nn.Module, name: str) -> str:
    """Why ``name`` of :func:`module_state` can be missing from a file, for its error: a parameter belongs to
    every version of the same actor, a persistent buffer may be newer than the file."""
    if name in dict(module.named_parameters()):
        return f"no {name!r}: it is incomplete or belongs to another actor"
    return (f"no {name!r}, a persistent buffer (state such as running statistics) this actor keeps: it was saved "
            "by another actor or by an ilcsan that did not save buffers")


def first_readout(tensors: Mapping[str, torch.Tensor], deployed: torch.nn.Module) -> dict[str, torch.Tensor]:
    """The part of an actor's ``tensors`` (its :func:`module_state` by name) with several readouts per action that
    ``deployed``, the same actor with one readout, holds: each cut to its shape there from the start, since the first
    readout's output populations come first in every tensor they occupy (output layer rows, intra-layer blocks,
    decoder, the output layer's normalisation). A SAC checkpoint's actor read as a policy, or deployed, is this
    part: its mean's populations."""
    return {name: tensors[name][tuple(slice(0, size) for size in tensor.shape)]
            for name, tensor in module_state(deployed).items() if name in tensors}


def slice_state(module: torch.nn.Module, index: int, factor: int) -> dict[str, torch.Tensor]:
    """Seed ``index``'s rows [factor·index, factor·(index+1)) of every tensor of :func:`module_state`, on the CPU."""
    return {name: tensor.detach()[factor * index: factor * (index + 1)].cpu().clone()
            for name, tensor in module_state(module).items()}


def load_state(module: torch.nn.Module, slices: list[dict[str, torch.Tensor]], what: str) -> None:
    """Stack the seeds' ``slices`` (of :func:`slice_state`) back into ``module``'s parameters and persistent
    buffers, in place (compiled programs hold them). A file saved before buffers were kept loads into a module
    without persistent buffers; one whose module has a buffer the file lacks is refused."""
    with torch.no_grad():
        for name, tensor in module_state(module).items():
            parts = []
            for per_seed in slices:
                if name not in per_seed:
                    raise UserError(f"the {what} in the checkpoint has {missing_state(module, name)}")
                parts.append(per_seed[name])
            stacked = torch.cat(parts).to(tensor.device, tensor.dtype)
            if stacked.shape != tensor.shape:
                raise UserError(f"the checkpoint's {what} {name!r} has shape {tuple(stacked.shape)}, this run "
                                f"needs {tuple(tensor.shape)}: it belongs to another actor or task")
            tensor.copy_(stacked)


def as_tensors(values: dict[str, Any]) -> dict[str, Any]:
    """numpy arrays → tensors (a checkpoint loads with ``weights_only``, which accepts tensors, not arrays)."""
    return {key: torch.as_tensor(value) if isinstance(value, np.ndarray) else value for key, value in values.items()}


def as_arrays(values: dict[str, Any]) -> dict[str, Any]:
    """The inverse of :func:`as_tensors`."""
    return {key: value.numpy() if torch.is_tensor(value) else value for key, value in values.items()}


# ------------------------------------------------------------------------------ commits on disk
def kept_checkpoint(step: int | None) -> str:
    """What a failed write leaves to continue from: the checkpoint committed at ``step``, or none yet (None). Without
    one, starting again still needs --resume, which starts from step 0: the folder may hold the first evaluation's
    metrics, which a start without it refuses to overwrite."""
    if step is None:
        return "no checkpoint has been written yet: free some space, then start again with --resume (from step 0)"
    return f"the checkpoint at step {step} is kept: free some space, then continue with --resume"


@contextlib.contextmanager
def disk_errors(directory: RunDirectory, step: int, kept: int | None):
    """A full or failing disk while writing results at ``step``: one clear line that says which checkpoint is kept
    (``kept``: the step of the last one committed, None before the first; :func:`kept_checkpoint`)."""
    try:
        yield
    except OSError as error:
        raise UserError(f"step {step}: cannot write to {directory.path}: {error.strerror or error}; "
                        f"{kept_checkpoint(kept)}") from None


def write_together(directories: list[RunDirectory], states: list[dict[str, Any]], step: int,
                   kept: int | None) -> None:
    """Write each seed's checkpoint; with several seeds first as pending files, then all renamed. ``kept`` is the
    step of the checkpoint already committed (None before the first), which a failed write leaves in place."""
    pending = len(directories) > 1
    for directory, state in zip(directories, states, strict=True):
        with disk_errors(directory, step, kept):
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
    mismatch = differing_settings(RunConfig.from_dict(state["config"]), config)
    if mismatch:
        raise UserError(f"{directory.path} was trained with different settings ({', '.join(mismatch)}); resume "
                        "with the same command, or choose another --out")
    if state["state_dim"] != state_dim or state["action_dim"] != action_dim:
        raise UserError(f"{directory.path}'s checkpoint was made for another task shape")
    if state["step"] > config.steps:
        raise UserError(f"{directory.path}'s checkpoint is at step {state['step']}, past --steps {config.steps}; "
                        f"give --steps {state['step']} or more")


# ------------------------------------------------------------------------------- the run's side
class CheckpointedRun(Protocol):
    """What :class:`TrainingCheckpoints` needs of a training run: it gives and takes each seed's state itself."""

    step: int
    replay: Any
    """The replay buffer: ``write_segment(directory, index, start)`` and ``load_segments(directory, index, names,
    total)`` (:class:`~ilcsan.rl.replay.ReplayBuffer`)."""
    evaluations: list[list[dict[str, float]]]

    def seed_state(self, index: int, segments: list[str]) -> dict[str, Any]:
        """Everything seed ``index`` needs to resume exactly, ``segments`` its replay segments so far."""

    def load_seed_states(self, states: list[dict[str, Any]]) -> None:
        """Continue from the seeds' checkpoints (already checked), replay excepted."""

    def results(self) -> list[dict[str, Any]]:
        """Each seed's result.json (with its ``directory``)."""


class TrainingCheckpoints:
    """Saves and restores a run's seeds, one :class:`RunDirectory` each: checkpoints (two-phase commit), replay
    segments, metrics, results and the best policy. The run (:class:`CheckpointedRun`) gives and takes its own state;
    this class owns the files."""

    def __init__(self, directories: list[RunDirectory], log=print):
        self.directories, self.log = directories, log
        self.segments: list[list[str]] = [[] for _ in directories]  # each seed's replay segments, in order
        self.checkpointed_total = 0  # replay inserts already written as segments
        self.committed_step: int | None = None
        """The step of the checkpoint on disk: the last one :meth:`save` committed or :meth:`restore` read; None
        while there is none. A failed write says it is kept (:func:`disk_errors`)."""

    def write_configs(self, config: RunConfig, measured: dict[str, Any] | None = None) -> None:
        """Each seed's config.json (:meth:`RunConfig.for_seed`) when a new run starts, with ``measured`` (what
        the run chose on this machine, e.g. its matmul path) beside the settings."""
        for directory, seed in zip(self.directories, config.seeds, strict=True):
            directory.write_config(config, seed, measured)

    def record_provenance(self, segment: dict[str, Any]) -> None:
        """Add ``segment`` (:func:`.provenance.collect`, at the step the run starts or resumes from) to each seed's
        ``provenance.json`` (:func:`.provenance.extend`). A damaged file is started again, with a line saying so."""
        for directory in self.directories:
            try:
                segments = directory.provenance() or []
            except RunFileError as error:
                self.log(f"note: {directory.file(PROVENANCE)} is damaged ({error}); it starts again with this segment")
                segments = []
            with disk_errors(directory, segment["step"], self.committed_step):
                directory.write_provenance(provenance.extend(segments, segment))

    def _record_budget(self, config: RunConfig, saved_steps: int) -> None:
        """A run resumed with another budget says so, and its config.json records the new one."""
        if saved_steps == config.steps:
            return
        self.log(f"budget: {saved_steps} → {config.steps} steps (the run continues as if started with {config.steps})")
        for directory in self.directories:
            directory.write_budget(config.steps)

    def save(self, run: CheckpointedRun) -> None:
        """Segments, metrics, then the checkpoints (committed together), then result.json: a crash anywhere
        keeps the previous checkpoint, and result.json never says "finished" before the final checkpoint."""
        for index, directory in enumerate(self.directories):
            with disk_errors(directory, run.step, self.committed_step):
                segment = run.replay.write_segment(directory, index, self.checkpointed_total)
                if segment is not None:
                    self.segments[index].append(segment)
                directory.write_metrics(run.evaluations[index])
        states = [{"format": CHECKPOINT_FORMAT, "version": FORMAT_VERSION, **run.seed_state(index, segments)}
                  for index, segments in enumerate(self.segments)]
        write_together(self.directories, states, run.step, self.committed_step)
        self.committed_step = run.step
        self.write_results(run)
        for directory, segments in zip(self.directories, self.segments, strict=True):
            directory.prune_replay_segments(segments)
        self.checkpointed_total = run.replay.total

    def save_policy(self, index: int, state: dict[str, Any], step: int) -> None:
        """Seed ``index``'s deployable actor as ``policy.pt`` (after an evaluation better than all before)."""
        with disk_errors(self.directories[index], step, self.committed_step):
            self.directories[index].write_policy({"format": POLICY_FORMAT, "version": FORMAT_VERSION, **state})

    def write_results(self, run: CheckpointedRun) -> None:
        for directory, result in zip(self.directories, run.results(), strict=True):
            with disk_errors(directory, run.step, self.committed_step):
                directory.write_result({key: value for key, value in result.items() if key != "directory"})

    def restore(self, run: CheckpointedRun, config: RunConfig, state_dim: int, action_dim: int) -> None:
        """Continue ``run`` from its folders' checkpoints; anything wrong with them is one line."""
        try:
            self._restore(run, config, state_dim, action_dim)
        except UserError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError, IndexError, RuntimeError) as error:
            where = self.directories[0].path if len(self.directories) == 1 else "a seed"
            raise UserError(f"the checkpoint in {where} is incomplete or from another version of ilcsan "
                            f"({type(error).__name__}: {str(error)[:120]}); start again without --resume, or "
                            "choose another --out") from None

    def _restore(self, run: CheckpointedRun, config: RunConfig, state_dim: int, action_dim: int) -> None:
        states = [directory.read_checkpoint() for directory in self.directories]
        for directory, state in zip(self.directories, states, strict=True):
            check_resumable(directory, state, config, state_dim, action_dim)
        steps = {state["step"] for state in states}
        if len(steps) != 1:
            raise UserError(f"the seeds' checkpoints are at different steps ({sorted(steps)}); resume them one by one")
        self._record_budget(config, RunConfig.from_dict(states[0]["config"]).steps)
        for index, (directory, state) in enumerate(zip(self.directories, states, strict=True)):
            self.segments[index] = list(state["replay"]["segments"])
            run.replay.load_segments(directory, index, self.segments[index], state["replay"]["total"])
            directory.prune_replay_segments(self.segments[index])
        run.load_seed_states(states)
        self.committed_step = steps.pop()
        for directory, rows in zip(self.directories, run.evaluations, strict=True):
            directory.write_metrics(rows)
        self.write_results(run)  # a crash may have come between the checkpoint and its result.json
        self.checkpointed_total = run.replay.total
        where = self.directories[0].path if len(self.directories) == 1 else self.directories[0].path.parent
        self.log(f"resumed {where} at step {run.step}")
