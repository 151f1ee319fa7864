"""Runs on disk, found and read for a report: every run folder below a directory becomes a :class:`RunRecord`.

Runs are found anywhere below a directory by their ``config.json``. The search does not descend into a
run (a folder with ``config.json`` and ``metrics.csv`` or ``result.json``), and a folder whose
``config.json`` sits above other runs is a container (e.g. a grid's own configuration), not a run.
Each run is read through :class:`~ilcsan.runs.directory.RunDirectory`; what a report needs of it:

``config.json``  ``task`` (short name or Gymnasium id), ``seed`` (int), ``label`` (row label), optionally
                 ``table`` and ``row`` (the grid's table name and row slug, set by ``ilcsan reproduce``)
                 and ``actor`` (the actor switches, with ``preset``);
``metrics.csv``  one line per evaluation, with at least ``step`` and ``eval_return_mean``;
``result.json``  ``best_return``, ``best_step``, ``steps_done``, ``steps_total``, ``finished``; absent
                 while the run is still before its first checkpoint (then the best evaluation of
                 ``metrics.csv`` is used);
``provenance.json``  optional: the code, libraries and machine of each segment (:mod:`ilcsan.runs.provenance`);
                 a run without it (older versions) or with a damaged one is reported as not recording it.

A run with a missing or malformed file is skipped and listed with the reason; two runs with the same
(table, row/label, task, seed) count once (the one with more steps done), the other is listed as a
duplicate.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import (
    RECORDED_BEFORE_CONTACT_FORCES,
    ActorConfig,
    TrainingProtocol,
    method_settings,
    saved_training,
    training_config_class,
)
from ..errors import UserError
from ..methods import DEFAULT_ALGORITHM, unused_settings
from ..runs.directory import CONFIG, DIAGNOSTICS, METRICS, RESULT, RunDirectory, RunFileError
from ..snn.diagnostics import is_stuck


@dataclass(frozen=True)
class RunRecord:
    """One run read from disk: its identity, its score and its learning curve."""

    path: Path
    task: str
    seed: int
    label: str
    table: str | None
    row: str | None
    actor: Mapping[str, Any] = field(hash=False, compare=False)
    best_return: float
    best_step: int
    steps_done: int
    steps_total: int | None
    finished: bool
    steps: tuple[int, ...]
    """Evaluation steps from ``metrics.csv`` (empty when it is absent)."""
    returns: tuple[float, ...]
    """``eval_return_mean`` at each of ``steps``."""
    training: Mapping[str, Any] = field(default_factory=dict, hash=False, compare=False)
    """The run's training settings as config.json holds them (``training``, or ``td3`` in files written before that
    name; empty for runs written without them)."""
    algorithm: str = field(default=DEFAULT_ALGORITHM, hash=False, compare=False)
    """The off-policy algorithm that trained the actor (config.json; runs written before the choice: TD3)."""
    diagnostics: Mapping[str, tuple[float, ...]] = field(default_factory=dict, hash=False, compare=False)
    """Each diagnostic column of ``metrics.csv`` (:data:`~ilcsan.runs.directory.DIAGNOSTICS`) at each of ``steps``,
    NaN where it was not measured."""
    steps_per_second: tuple[float, ...] = field(default=(), hash=False, compare=False)
    """The training speed ``metrics.csv`` records at each of ``steps`` (environment steps per second of wall time since
    the evaluation before; NaN where not recorded)."""
    wall_seconds: float | None = field(default=None, hash=False, compare=False)
    """Wall-clock time of the training process to ``steps_done`` (result.json; seeds stacked in one process share
    it), None when not recorded."""
    contact_forces: str = field(default=RECORDED_BEFORE_CONTACT_FORCES, hash=False, compare=False)
    """How the task's contact forces read (config.json; :data:`~ilcsan.config.CONTACT_FORCES`)."""
    provenance: tuple[Mapping[str, Any], ...] | None = field(default=None, hash=False, compare=False)
    """The segments of ``provenance.json`` (:mod:`ilcsan.runs.provenance`), None when the run has none or it is
    damaged."""

    def evaluation_rows(self) -> list[dict[str, float]]:
        """``metrics.csv`` as rows of step, return and diagnostics, as the training loop keeps its evaluations."""
        rows = [{"step": step, "eval_return_mean": value} for step, value in zip(self.steps, self.returns, strict=True)]
        for name, values in self.diagnostics.items():
            for row, value in zip(rows, values, strict=True):
                row[name] = value
        return rows

    @property
    def stuck(self) -> bool:
        """Whether the run ended stuck in one constant action that almost no gradient moves
        (:func:`~ilcsan.snn.diagnostics.is_stuck`)."""
        start_steps = self.training.get("start_steps", TrainingProtocol.start_steps)
        return is_stuck(self.evaluation_rows(), start_steps)

    @property
    def preset(self) -> str | None:
        preset = self.actor.get("preset")
        return preset if isinstance(preset, str) else None

    @property
    def is_dan(self) -> bool:
        """True for a deep-actor (DAN) run: preset ``dan``, row ``dan``, or label ``DAN`` with no actor."""
        return self.preset == "dan" or self.row == "dan" or (self.preset is None and self.label == "DAN")


@dataclass(frozen=True)
class SkippedRun:
    """A run directory the report could not use, and why."""

    path: Path
    reason: str


@dataclass(frozen=True)
class RunScan:
    """Everything found below a directory: usable runs and skipped ones."""

    runs: tuple[RunRecord, ...]
    skipped: tuple[SkippedRun, ...]


RunFolders = str | Path | Sequence[str | Path]
"""One folder of runs or several (searched together, as one)."""


def folders_of(directories: RunFolders) -> list[Path]:
    """``directories`` as a list of paths (one folder or several)."""
    return [Path(directories)] if isinstance(directories, str | Path) else [Path(item) for item in directories]


def scan_runs(directories: RunFolders) -> RunScan:
    """Find every run below ``directories`` (one folder or several; a run by its ``config.json``), read it, and list
    the skipped: unreadable runs, and all but one run of a (row, task, seed) found more than once."""
    roots = folders_of(directories)
    for root in roots:
        if not root.is_dir():
            raise UserError(f"run directory {root} does not exist or is not a directory")
    found = {path.resolve(): path for root in roots for path in _run_folders(root)}  # a folder below two roots: once
    runs: list[RunRecord] = []
    skipped: list[SkippedRun] = []
    for path in sorted(found.values()):
        try:
            runs.append(read_run(path))
        except RunFileError as error:
            skipped.append(SkippedRun(path, str(error)))
    kept, duplicates = _drop_duplicates(runs)
    return RunScan(tuple(kept), tuple(skipped + duplicates))


def _run_folders(root: Path) -> list[Path]:
    """The run folders below ``root``: those with a ``config.json`` and an evaluation, and those with a
    ``config.json`` only (a run before its first evaluation) that hold no other run folder."""
    candidates: list[Path] = []
    pending: list[Path] = []  # config.json without metrics.csv/result.json: a container or a fresh run
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(name for name in dirnames if not name.startswith("."))
        if CONFIG not in filenames:
            continue
        if METRICS in filenames or RESULT in filenames:
            dirnames[:] = []  # a run's subdirectories (checkpoints, replay, ...) hold no runs
            candidates.append(Path(dirpath))
        else:
            pending.append(Path(dirpath))
    found = candidates + pending
    return candidates + [path for path in pending if not any(path in other.parents for other in found)]


def collect_runs(directories: RunFolders) -> list[RunRecord]:
    """Every usable run below ``directories`` (see :func:`scan_runs` for the skipped ones)."""
    return list(scan_runs(directories).runs)


def read_run(directory: str | Path) -> RunRecord:
    """Read one run folder; raises :class:`~ilcsan.runs.directory.RunFileError` saying what is missing or
    malformed."""
    run = RunDirectory(directory)
    config = run.config_object()
    task, seed, label, table, row, actor = _parse_config(config)
    training = saved_training(config) if isinstance(saved_training(config), dict) else {}
    steps, columns = run.evaluation_columns()
    returns = columns.get("eval_return_mean", ())
    result = run.result()
    if result is None and not steps:
        raise RunFileError("neither result.json nor metrics.csv (no evaluation yet)")
    if result is not None and result.get("best_return") is None and not steps:
        raise RunFileError("no evaluation yet (result.json has no best_return, metrics.csv no rows)")
    if result is not None and result.get("best_return") is not None:
        best_return, best_step, steps_done, steps_total, finished = _parse_result(result, steps)
    else:  # still running: the best evaluation so far
        best = int(np.argmax(returns))
        best_return, best_step, steps_done, steps_total, finished = (
            returns[best], steps[best], steps[-1], None, False)
    return RunRecord(
        path=run.path, task=task, seed=seed, label=label, table=table, row=row, actor=actor,
        best_return=best_return, best_step=best_step, steps_done=steps_done, steps_total=steps_total,
        finished=finished, steps=steps, returns=returns, training=training,
        algorithm=str(config.get("algorithm") or DEFAULT_ALGORITHM),
        diagnostics={name: columns[name] for name in DIAGNOSTICS if name in columns},
        steps_per_second=columns.get("steps_per_second", ()),
        wall_seconds=_wall_seconds(result), provenance=_provenance(run),
        contact_forces=str(config.get("contact_forces") or RECORDED_BEFORE_CONTACT_FORCES),
    )


def _provenance(run: RunDirectory) -> tuple[Mapping[str, Any], ...] | None:
    try:
        segments = run.provenance()
    except RunFileError:
        return None
    return None if segments is None else tuple(segments)


def _wall_seconds(result: Mapping[str, Any] | None) -> float | None:
    value = None if result is None else result.get("wall_seconds")
    return None if value is None else _number(value, "wall_seconds")


def _optional_str(config: Mapping[str, Any], key: str) -> str | None:
    value = config.get(key)
    if value is None:
        return None
    if not isinstance(value, str) or not value:
        raise RunFileError(f"config.json: {key!r} must be a non-empty string, got {value!r}")
    return value


def _parse_config(config: Mapping[str, Any]) -> tuple[str, int, str, str | None, str | None, dict]:
    task = _optional_str(config, "task")
    if task is None:
        raise RunFileError("config.json: missing 'task'")
    seed = config.get("seed")
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise RunFileError(f"config.json: 'seed' must be an integer, got {seed!r}")
    actor = config.get("actor", {})
    if actor is None:
        actor = {}
    if not isinstance(actor, dict):
        raise RunFileError(f"config.json: 'actor' must be an object, got {actor!r}")
    table, row = _optional_str(config, "table"), _optional_str(config, "row")
    label = _optional_str(config, "label") or row or actor.get("preset")
    if not isinstance(label, str):
        raise RunFileError("config.json: missing 'label'")
    return task, seed, label, table, row, actor


def _number(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise RunFileError(f"result.json: {name!r} must be a finite number, got {value!r}")
    return float(value)


def _parse_result(result: Mapping[str, Any],
                  steps: tuple[int, ...]) -> tuple[float, int, int, int | None, bool]:
    if "best_return" not in result:
        raise RunFileError("result.json: missing 'best_return'")
    best_return = _number(result["best_return"], "best_return")
    fallback_step = steps[-1] if steps else 0
    best_step = int(_number(result.get("best_step") or 0, "best_step"))
    steps_done = int(_number(result.get("steps_done", fallback_step), "steps_done"))
    total = result.get("steps_total")
    steps_total = None if total is None else int(_number(total, "steps_total"))
    finished = result.get("finished", False)
    if not isinstance(finished, bool):
        raise RunFileError(f"result.json: 'finished' must be true or false, got {finished!r}")
    return best_return, best_step, steps_done, steps_total, finished


def configuration_key(actor: Mapping[str, Any], training: Mapping[str, Any],
                      algorithm: str = DEFAULT_ALGORITHM) -> str:
    """Algorithm, actor settings and training method (every declared method's settings,
    :func:`~ilcsan.config.method_settings`, but those the algorithm does not use,
    :func:`~ilcsan.methods.unused_settings`, which its config.json may or may not hold) as one comparable key; a
    setting a saved config lacks (saved before it existed) counts as its default, as it does when the run is
    loaded."""
    settings, unused = training_config_class(), set(unused_settings(algorithm))
    method = {key: _current(settings, key, training.get(key, getattr(settings, key)))
              for key in method_settings() if key not in unused}
    return json.dumps({"algorithm": algorithm, "actor": _complete_actor(actor), "method": method}, sort_keys=True,
                      default=str)


def _current(settings: type, name: str, value: Any) -> Any:
    """A saved training setting of ``settings`` in today's spelling (a choice renamed since:
    :func:`~ilcsan.config.current_spellings`)."""
    renamed = settings.__dataclass_fields__[name].metadata.get("renamed", {})
    return renamed.get(value, value) if isinstance(value, str) else value


def _complete_actor(actor: Mapping[str, Any]) -> dict[str, Any]:
    """The saved actor settings with the ones it lacks filled in as :meth:`ActorConfig.from_dict` fills them (as
    saved where they cannot be read)."""
    try:
        return ActorConfig.from_dict(dict(actor)).to_dict()
    except (UserError, TypeError, ValueError):
        return dict(actor)


def row_identity(run: RunRecord) -> tuple:
    """A grid run's row is its (table, row) tag; any other run's is its label, actor settings and method."""
    if run.table and run.row:
        return run.table, run.row
    return run.table, run.label, configuration_key(run.actor, run.training, run.algorithm)


def _identity(run: RunRecord) -> tuple:
    return *row_identity(run), run.task, run.seed


def _drop_duplicates(runs: Sequence[RunRecord]) -> tuple[list[RunRecord], list[SkippedRun]]:
    """Keep one run per (row, task, seed): the one with more steps done (then the first path)."""
    best: dict[tuple, RunRecord] = {}
    for run in runs:
        kept = best.get(_identity(run))
        if kept is None or run.steps_done > kept.steps_done:
            best[_identity(run)] = run
    winners = {id(run) for run in best.values()}
    kept_runs = [run for run in runs if id(run) in winners]
    dropped = [
        SkippedRun(run.path, f"duplicate of {best[_identity(run)].path} (same table, row, task and seed)")
        for run in runs if id(run) not in winners
    ]
    return kept_runs, dropped
