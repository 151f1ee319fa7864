"""A run folder on disk: the one place that names its files, reads them and writes them.

One seed's run lives in one folder (``OUT`` for one seed, ``OUT/seed<k>`` for several)::

    config.json          the run's configuration (:meth:`RunConfig.for_seed`), enough to rebuild the actor
    metrics.csv          one row per evaluation (:data:`METRIC_FIELDS`)
    result.json          best evaluation so far, steps done, finished flag
    provenance.json      the code, libraries and machine of each start and resume (:mod:`.provenance`)
    policy.pt            the actor of the best evaluation with its frozen normaliser (deployable)
    checkpoint.pt        the full training state of the last evaluation (resume)
    checkpoint.next.pt   a new checkpoint waiting for the other seeds of its run (two-phase commit)
    replay/              the replay rows, one segment per checkpoint
    tensorboard/         TensorBoard event files
    .lock                held by the process that trains in this folder

The trainer writes through :class:`RunDirectory` (every file atomically, :mod:`ilcsan.files`);
``reproduce``, ``report`` and ``energy`` read through it. Reads that a report tolerates (a run still before
its first evaluation, a damaged file) raise :class:`RunFileError` whose message is the reason shown to the
user; reads that stop a command raise :class:`~ilcsan.errors.UserError`.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..config import RunConfig
from ..errors import UserError
from ..files import atomic_savez, atomic_torch_save, atomic_write_json, atomic_write_text, read_json, safe_torch_load
from .lock import DirectoryLock

CONFIG = "config.json"
METRICS = "metrics.csv"
RESULT = "result.json"
PROVENANCE = "provenance.json"
POLICY = "policy.pt"
CHECKPOINT = "checkpoint.pt"
PENDING_CHECKPOINT = "checkpoint.next.pt"
REPLAY = "replay"
TENSORBOARD = "tensorboard"
LOCK = ".lock"

DIAGNOSTICS: tuple[str, ...] = ("saturated_actions", "frozen_output_neurons", "surrogate_active",
                                "mean_abs_preaction", "action_spread")
"""The diagnostic columns of ``metrics.csv``, in order: what :mod:`ilcsan.snn.diagnostics` measures of a seed's
actor at each evaluation (each named and defined there)."""
METRIC_FIELDS: tuple[str, ...] = (
    "step", "eval_return_mean", "eval_return_std", "eval_length_mean", "wall_seconds", "steps_per_second",
    *DIAGNOSTICS,
)
"""The columns of ``metrics.csv``, one row per evaluation: the evaluation, the training speed, and the actor's
diagnostics (:data:`DIAGNOSTICS`; empty for runs written before they existed)."""
REQUIRED_METRICS: tuple[str, ...] = ("step", "eval_return_mean")
READ_METRICS: tuple[str, ...] = (*DIAGNOSTICS, "steps_per_second")
"""The optional columns of ``metrics.csv`` that :meth:`RunDirectory.evaluation_columns` reads beside the return."""
"""The columns a ``metrics.csv`` must have to be read (older or foreign files may lack the others)."""


class RunFileError(ValueError):
    """A run's file is missing or malformed; the message is the reason a report shows."""


def run_directories(out: Path, seeds: tuple[int, ...]) -> list[Path]:
    """``OUT`` for one seed, ``OUT/seed<k>`` for several."""
    out = Path(out)
    return [out] if len(seeds) == 1 else [out / f"seed{seed}" for seed in seeds]


@dataclass(frozen=True)
class RunDirectory:
    """One seed's run folder (it need not exist yet)."""

    path: Path

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))

    def file(self, name: str) -> Path:
        """The path of one of the folder's files (:data:`CONFIG`, :data:`CHECKPOINT`, ...)."""
        return self.path / name

    # ---------------------------------------------------------------------------------- what is there
    def holds_run(self) -> bool:
        """True once training has written anything worth keeping (a checkpoint or an evaluation)."""
        return any(self.file(name).exists() for name in (CHECKPOINT, PENDING_CHECKPOINT, METRICS))

    def has_checkpoint(self, pending: bool = False) -> bool:
        """True when ``checkpoint.pt`` (or, with ``pending``, ``checkpoint.next.pt``) exists."""
        return self.file(PENDING_CHECKPOINT if pending else CHECKPOINT).exists()

    def checkpoint_step(self) -> int | None:
        """The step of ``checkpoint.pt``, None without one (a damaged file raises UserError)."""
        if not self.has_checkpoint():
            return None
        return int(self.read_checkpoint()["step"])

    # ------------------------------------------------------------------------------------------ reads
    def run_config(self) -> RunConfig:
        """The :class:`RunConfig` of ``config.json`` (UserError when missing or damaged)."""
        return RunConfig.from_dict(read_json(self.file(CONFIG), "run config"))

    def config_object(self) -> dict[str, Any]:
        """``config.json`` as a JSON object, for readers that accept other versions' files (RunFileError)."""
        return _json_object(self.file(CONFIG))

    def matmul_choice(self) -> Any:
        """``matmul_path`` of ``config.json``: the matmul path the run computes on and how it was chosen (``{"path":
        "aten", "gflops": {...}, ...}``), as recorded — None when absent (RunFileError when the file is damaged)."""
        return self.config_object().get("matmul_path")

    def result(self) -> dict[str, Any] | None:
        """``result.json`` as a JSON object, None when absent (RunFileError when damaged)."""
        return _json_object(self.file(RESULT)) if self.file(RESULT).exists() else None

    def result_or_empty(self) -> dict[str, Any]:
        """``result.json`` or ``{}`` whatever is wrong with it: for progress polls of a run being written."""
        with contextlib.suppress(RunFileError):
            return self.result() or {}
        return {}

    def provenance(self) -> list[dict[str, Any]] | None:
        """The segments of ``provenance.json`` (:mod:`.provenance`), None when absent (a run of an older version;
        RunFileError when damaged)."""
        if not self.file(PROVENANCE).exists():
            return None
        segments = _json_object(self.file(PROVENANCE)).get("segments")
        if not isinstance(segments, list) or not all(isinstance(segment, dict) for segment in segments):
            raise RunFileError(f"{PROVENANCE}: 'segments' must be a list of objects")
        return segments

    def read_checkpoint(self, pending: bool = False) -> dict[str, Any]:
        """``checkpoint.pt`` (or ``checkpoint.next.pt``) as data, never code (UserError when damaged)."""
        return safe_torch_load(self.file(PENDING_CHECKPOINT if pending else CHECKPOINT))

    def read_replay_segment(self, name: str, fields: tuple[str, ...]) -> dict[str, Any]:
        """The arrays ``fields`` of ``replay/<name>`` (UserError when missing or damaged)."""
        path = self.path / REPLAY / name
        try:
            with np.load(path, allow_pickle=False) as segment:
                return {field: segment[field] for field in fields}
        except (OSError, KeyError, ValueError) as error:
            raise UserError(f"replay segment {path} is missing or corrupt ({error}); "
                            "the run cannot resume exactly — start it again without --resume") from None

    def evaluation_columns(self) -> tuple[tuple[int, ...], dict[str, tuple[float, ...]]]:
        """Steps of ``metrics.csv`` sorted by step (a repeated step keeping its last line) and, aligned with them,
        ``eval_return_mean`` and each column of :data:`READ_METRICS` (NaN where a row leaves it empty or the file has
        no such column); empty when the file is absent (RunFileError when damaged)."""
        path = self.file(METRICS)
        if not path.exists():
            return (), {}
        return _read_metrics(_read_text(path))

    # ----------------------------------------------------------------------------------------- writes
    def write_config(self, config: RunConfig, seed: int, measured: dict[str, Any] | None = None) -> None:
        """config.json: the seed's settings, plus ``measured`` (machine-dependent choices; readers ignore them)."""
        atomic_write_json(self.file(CONFIG), {**config.for_seed(seed), **(measured or {})})

    def write_budget(self, steps: int) -> None:
        """Set config.json's ``steps`` (a run resumed with another budget), keeping everything else in it."""
        atomic_write_json(self.file(CONFIG), {**self.config_object(), "steps": steps})

    def write_provenance(self, segments: list[dict[str, Any]]) -> None:
        atomic_write_json(self.file(PROVENANCE), {"segments": segments})

    def write_metrics(self, rows: list[dict[str, Any]]) -> None:
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=METRIC_FIELDS, extrasaction="ignore", lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        atomic_write_text(self.file(METRICS), buffer.getvalue())

    def write_result(self, result: dict[str, Any]) -> None:
        atomic_write_json(self.file(RESULT), result)

    def write_policy(self, state: dict[str, Any]) -> None:
        atomic_torch_save(self.file(POLICY), state)

    def write_checkpoint(self, state: dict[str, Any], pending: bool = False) -> None:
        """Write ``checkpoint.pt``, or with ``pending`` ``checkpoint.next.pt`` (see :meth:`commit_checkpoint`)."""
        atomic_torch_save(self.file(PENDING_CHECKPOINT if pending else CHECKPOINT), state)

    def commit_checkpoint(self) -> None:
        """Make the pending checkpoint the checkpoint (one atomic rename)."""
        os.replace(self.file(PENDING_CHECKPOINT), self.file(CHECKPOINT))

    def drop_pending_checkpoint(self) -> None:
        os.remove(self.file(PENDING_CHECKPOINT))

    def write_replay_segment(self, name: str, arrays: dict[str, Any]) -> None:
        atomic_savez(self.path / REPLAY / name, **arrays)

    def prune_replay_segments(self, keep: list[str]) -> None:
        """Delete the replay segments no checkpoint refers to (written by an interrupted checkpoint)."""
        folder = self.path / REPLAY
        if not folder.is_dir():
            return
        for path in folder.iterdir():
            if path.name not in keep and path.suffix == ".npz":
                with contextlib.suppress(FileNotFoundError):
                    os.remove(path)

    # ------------------------------------------------------------------------------------ training use
    def check_writable(self) -> None:
        """Create the folder and write (then delete) 64 KiB in it: an unwritable or full disk is one line
        before anything is trained."""
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            probe = self.path / ".ilcsan-write-test"
            probe.write_bytes(b"0" * 65536)
            probe.unlink()
        except (OSError, ValueError) as error:  # ValueError: a path with a NUL byte
            message = getattr(error, "strerror", None) or error
            raise UserError(f"cannot write results to {self.path}: {message}; choose another --out") from None

    def lock(self) -> DirectoryLock:
        """Hold ``.lock`` exclusively until the returned lock is closed; a second trainer is refused."""
        return DirectoryLock(self.file(LOCK), self.path)

    def tensorboard_folder(self) -> Path:
        return self.file(TENSORBOARD)

    def remove_temporary_files(self) -> None:
        """Delete the half-written temporary files an interrupted atomic write left (hold the lock first)."""
        for folder in (self.path, self.path / REPLAY):
            if folder.is_dir():
                for path in folder.glob(".*.tmp"):
                    with contextlib.suppress(FileNotFoundError):
                        path.unlink()


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise RunFileError(f"{path.name}: cannot be read ({error})") from None


def _json_object(path: Path) -> dict[str, Any]:
    text = _read_text(path)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise RunFileError(f"{path.name}: invalid JSON ({error.msg} at line {error.lineno})") from None
    if not isinstance(data, dict):
        raise RunFileError(f"{path.name}: expected a JSON object, got {type(data).__name__}")
    return data


def _optional_number(text: str) -> float:
    """A diagnostic cell: its number, NaN when empty or not a number (the column is informative, never fatal)."""
    try:
        return float(text)
    except ValueError:
        return math.nan


def _read_metrics(text: str) -> tuple[tuple[int, ...], dict[str, tuple[float, ...]]]:
    lines = [line for line in csv.reader(io.StringIO(text)) if any(cell.strip() for cell in line)]
    if not lines:
        raise RunFileError(f"{METRICS}: empty file")
    header = [name.strip() for name in lines[0]]
    for name in REQUIRED_METRICS:
        if name not in header:
            raise RunFileError(f"{METRICS}: the header has no {name!r} column")
    i_step, i_return = header.index("step"), header.index("eval_return_mean")
    optional = {name: header.index(name) for name in READ_METRICS if name in header}
    by_step: dict[int, float] = {}
    diagnostics: dict[int, dict[str, float]] = {}
    for number, line in enumerate(lines[1:], start=2):
        if len(line) != len(header):
            raise RunFileError(f"{METRICS} line {number}: {len(line)} fields, the header has {len(header)}")
        try:
            step, value = float(line[i_step]), float(line[i_return])
        except ValueError:
            raise RunFileError(f"{METRICS} line {number}: not a number") from None
        if not (math.isfinite(step) and step == int(step) and step >= 0 and math.isfinite(value)):
            raise RunFileError(f"{METRICS} line {number}: bad step or return ({line[i_step]}, {line[i_return]})")
        by_step[int(step)] = value
        diagnostics[int(step)] = {name: _optional_number(line[index]) for name, index in optional.items()}
    if not by_step:
        raise RunFileError(f"{METRICS}: no evaluation rows")
    ordered = sorted(by_step)
    columns = {"eval_return_mean": tuple(by_step[step] for step in ordered)}
    for name in READ_METRICS:
        columns[name] = tuple(diagnostics[step].get(name, math.nan) for step in ordered)
    return tuple(ordered), columns
