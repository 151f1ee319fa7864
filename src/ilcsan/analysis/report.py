"""The paper's reward tables and learning curves, built from whatever runs exist on disk.

A run is a directory holding (written by the trainer):

``config.json``  a JSON object with ``task`` (short name or Gymnasium id), ``seed`` (int), ``label``
                 (row label), optionally ``table`` and ``row`` (the grid's table name and row slug,
                 set by ``ilcsan reproduce``) and ``actor`` (the actor switches, with ``preset``);
``metrics.csv``  header ``step,eval_return_mean,eval_return_std,eval_length_mean,wall_seconds,
                 steps_per_second``, one line per evaluation;
``result.json``  ``best_return``, ``best_step``, ``steps_done``, ``steps_total``, ``finished``; absent
                 while the run is still going (then the best evaluation of ``metrics.csv`` is used).

Runs are found anywhere below a directory by their ``config.json``. The search does not descend into a
run (a directory with ``config.json`` and ``metrics.csv`` or ``result.json``), and a directory whose
``config.json`` sits above other runs is a container (e.g. a grid's own configuration), not a run.
A run with a missing or malformed file is skipped and listed with the reason; two runs with the same
(table, row/label, task, seed) count once (the one with more steps done), the other is listed as a
duplicate.

Statistics, as in the paper (Section V-A, Tables ``tab:perf`` … ``tab:layer``):

* a run's score is its **max average reward**: the best evaluation's mean return over its episodes;
* a cell is the mean ± std of the scores of its seed runs, ``numpy.std`` with ``ddof=0`` (population
  standard deviation), with the number of seeds n;
* APR = mean over tasks of (cell mean / DAN cell mean), in percent, **only over the tasks where both
  the row and DAN have runs** (the count is shown when it is fewer than the table's tasks). The DAN
  reference is, per task: the table's own DAN row if it has one, else the runs of Table ``perf``'s
  DAN row, else any other run whose actor preset is ``dan`` — as in the paper, where the APRs of
  ``decode``/``dec_intra``/``intra``/``layer`` are relative to the DAN of ``perf``;
* the best mean of each column (and the best APR) is in bold.

Every cell shows our value and, where the paper has one for that (table, row, task), the published
value beside it: ``3583 ± 86 (n=3) · paper 3583 ± 86``; a cell without runs shows ``—``.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import json
import math
import os
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import UserError
from ..experiments.tables import TABLES, TableSpec
from .paper import PAPER_TASKS, Stat, published_apr, published_cell

METRICS_HEADER: tuple[str, ...] = (
    "step", "eval_return_mean", "eval_return_std", "eval_length_mean", "wall_seconds", "steps_per_second",
)
REQUIRED_METRICS: tuple[str, ...] = ("step", "eval_return_mean")
SMOOTHING_WINDOW = 5
"""Learning curves are smoothed by a trailing moving average over this many evaluations."""

PANELS_PER_LINE = 4
"""Learning-curve panels per line of the figure (the paper's figures show four tasks side by side)."""


# ----------------------------------------------------------------------------------------------
# Runs on disk


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


class RunFileError(ValueError):
    """A run's files are missing or malformed; the message is the reason shown in the report."""


def scan_runs(directory: str | Path) -> RunScan:
    """Find every run below ``directory`` (by its ``config.json``), read it, and list the skipped."""
    root = Path(directory)
    if not root.is_dir():
        raise UserError(f"run directory {root} does not exist or is not a directory")
    candidates: list[Path] = []
    pending: list[Path] = []  # config.json without metrics.csv/result.json: a container or a fresh run
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(name for name in dirnames if not name.startswith("."))
        if "config.json" not in filenames:
            continue
        if "metrics.csv" in filenames or "result.json" in filenames:
            dirnames[:] = []  # a run's subdirectories (checkpoints, replay, ...) hold no runs
            candidates.append(Path(dirpath))
        else:
            pending.append(Path(dirpath))
    found = candidates + pending
    candidates += [path for path in pending if not any(path in other.parents for other in found)]
    runs: list[RunRecord] = []
    skipped: list[SkippedRun] = []
    for path in sorted(candidates):
        try:
            runs.append(read_run(path))
        except RunFileError as error:
            skipped.append(SkippedRun(path, str(error)))
    kept, duplicates = _drop_duplicates(runs)
    return RunScan(tuple(kept), tuple(skipped + duplicates))


def collect_runs(directory: str | Path) -> list[RunRecord]:
    """Every usable run below ``directory`` (see :func:`scan_runs` for the skipped ones)."""
    return list(scan_runs(directory).runs)


def read_run(directory: str | Path) -> RunRecord:
    """Read one run directory; raises :class:`RunFileError` saying what is missing or malformed."""
    directory = Path(directory)
    config = _read_json_object(directory / "config.json")
    task, seed, label, table, row, actor = _parse_config(config)
    metrics, result_file = directory / "metrics.csv", directory / "result.json"
    steps, returns = _read_metrics(metrics) if metrics.exists() else ((), ())
    result = _read_json_object(result_file) if result_file.exists() else None
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
        path=directory, task=task, seed=seed, label=label, table=table, row=row, actor=actor,
        best_return=best_return, best_step=best_step, steps_done=steps_done, steps_total=steps_total,
        finished=finished, steps=steps, returns=returns,
    )


def _read_json_object(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise RunFileError(f"{path.name}: cannot be read ({error})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise RunFileError(f"{path.name}: invalid JSON ({error.msg} at line {error.lineno})") from None
    if not isinstance(data, dict):
        raise RunFileError(f"{path.name}: expected a JSON object, got {type(data).__name__}")
    return data


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


def _read_metrics(path: Path) -> tuple[tuple[int, ...], tuple[float, ...]]:
    """Steps and mean returns of ``metrics.csv``, sorted by step (a repeated step keeps its last line)."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise RunFileError(f"metrics.csv: cannot be read ({error})") from None
    lines = [line for line in csv.reader(io.StringIO(text)) if any(cell.strip() for cell in line)]
    if not lines:
        raise RunFileError("metrics.csv: empty file")
    header = [name.strip() for name in lines[0]]
    for name in REQUIRED_METRICS:
        if name not in header:
            raise RunFileError(f"metrics.csv: the header has no {name!r} column")
    i_step, i_return = header.index("step"), header.index("eval_return_mean")
    by_step: dict[int, float] = {}
    for number, line in enumerate(lines[1:], start=2):
        if len(line) != len(header):
            raise RunFileError(f"metrics.csv line {number}: {len(line)} fields, the header has {len(header)}")
        try:
            step, value = float(line[i_step]), float(line[i_return])
        except ValueError:
            raise RunFileError(f"metrics.csv line {number}: not a number") from None
        if not (math.isfinite(step) and step == int(step) and step >= 0 and math.isfinite(value)):
            raise RunFileError(f"metrics.csv line {number}: bad step or return "
                            f"({line[i_step]}, {line[i_return]})")
        by_step[int(step)] = value
    if not by_step:
        raise RunFileError("metrics.csv: no evaluation rows")
    ordered = sorted(by_step)
    return tuple(ordered), tuple(by_step[step] for step in ordered)


def _actor_key(run: RunRecord) -> str:
    return json.dumps(run.actor, sort_keys=True, default=str)


def _row_identity(run: RunRecord) -> tuple:
    """A grid run's row is its (table, row) tag; any other run's is its label and actor switches."""
    if run.table and run.row:
        return run.table, run.row
    return run.table, run.label, _actor_key(run)


def _identity(run: RunRecord) -> tuple:
    return *_row_identity(run), run.task, run.seed


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


# ----------------------------------------------------------------------------------------------
# Tables


@dataclass(frozen=True)
class Cell:
    """One (row, task) cell: the scores of its seed runs, and the paper's value where there is one."""

    task: str
    runs: tuple[RunRecord, ...] = field(compare=False)
    paper: Stat | None
    best: bool = False

    @property
    def scores(self) -> tuple[float, ...]:
        """Max average reward of each seed run."""
        return tuple(run.best_return for run in self.runs)

    @property
    def n(self) -> int:
        return len(self.runs)

    @property
    def running(self) -> int:
        """How many of the seed runs are not finished yet."""
        return sum(not run.finished for run in self.runs)

    @property
    def mean(self) -> float | None:
        return float(np.mean(self.scores)) if self.runs else None

    @property
    def std(self) -> float | None:
        """Population standard deviation over seeds (``numpy.std``, ``ddof=0``)."""
        return float(np.std(self.scores, ddof=0)) if self.runs else None


@dataclass(frozen=True)
class RowResult:
    """One row: its cells in task order and its APR (percent) against DAN."""

    key: str
    label: str
    cells: tuple[Cell, ...]
    apr: float | None
    apr_tasks: int
    """Number of tasks the APR averages over (where both this row and DAN have runs)."""
    paper_apr: float | None
    runnable: bool = True
    best_apr: bool = False

    def cell(self, task: str) -> Cell:
        for cell in self.cells:
            if cell.task == task:
                return cell
        raise KeyError(f"row {self.key!r} has no task {task!r}")


@dataclass(frozen=True)
class TableResult:
    """A table built from runs: rows × tasks, with what the APR was computed against."""

    name: str | None
    caption: str
    tasks: tuple[str, ...]
    rows: tuple[RowResult, ...]
    reference: str
    """Where the DAN reference of the APR came from, in words."""

    def row(self, key: str) -> RowResult:
        """The row with this key (row slug for a grid table, else the label)."""
        for row in self.rows:
            if row.key == key or row.label == key:
                return row
        raise KeyError(f"table {self.name!r} has no row {key!r}")

    def cell(self, row: str, task: str) -> Cell:
        return self.row(row).cell(task)

    @property
    def missing(self) -> list[tuple[str, str]]:
        """(row label, task) of every cell without runs (rows that cannot run are left out)."""
        return [(row.label, cell.task)
                for row in self.rows if row.runnable for cell in row.cells if not cell.n]


@dataclass
class _Group:
    """A row being assembled: its runs and where the paper's numbers for it are."""

    key: str
    label: str
    paper: tuple[str, str] | None = None
    runnable: bool = True
    runs: list[RunRecord] = field(default_factory=list)
    table: str | None = None
    actor: Mapping[str, Any] = field(default_factory=dict)


def build_table(runs: Sequence[RunRecord], table: str | TableSpec | None = None) -> TableResult:
    """Build one table from runs.

    ``table`` a grid name of :data:`ilcsan.grids.TABLES` or a :class:`TableSpec`: its rows and tasks,
    every cell present (``—`` where there are no runs), runs placed by their ``table``/``row`` tags, and
    untagged runs by their label (or row slug) matching a row's. Any other name selects the runs tagged
    with it. None: all runs, rows by label (by tag when tagged), columns the tasks found. See the
    module docstring for the statistics (mean ± std with ``ddof=0``, APR over tasks where both exist).
    """
    spec = TABLES.get(table) if isinstance(table, str) else table
    if spec is not None:
        return _build_from_spec(runs, spec, match_untagged=True, reference=runs)
    if isinstance(table, str):
        return _build_free([run for run in runs if run.table == table], table, table, reference=runs)
    return _build_free(runs, None, "All runs", reference=runs)


def _build_from_spec(runs: Sequence[RunRecord], spec: TableSpec, match_untagged: bool,
                     reference: Sequence[RunRecord]) -> TableResult:
    builtin = spec.name in TABLES
    groups = {row.slug: _Group(row.slug, row.label, (spec.name, row.slug) if builtin else None, row.runnable)
              for row in spec.rows}
    by_label = {row.label: row.slug for row in spec.rows}
    extra: dict[str, _Group] = {}
    for run in runs:
        if run.table == spec.name:
            slug = run.row if run.row in groups else None
        elif run.table is None and match_untagged:
            slug = run.row if run.row in groups else by_label.get(run.label)
            if slug is None:
                continue
        else:
            continue
        if slug is None:  # tagged with this table but a row the grid does not have
            group = extra.setdefault(run.label, _Group(run.row or run.label, run.label))
        else:
            group = groups[slug]
        group.runs.append(run)
    found = _tasks_in(run for group in (*groups.values(), *extra.values()) for run in group.runs)
    tasks = spec.tasks + tuple(task for task in found if task not in spec.tasks)
    return _finish(spec.name, spec.caption, tasks, [*groups.values(), *extra.values()], reference)


def _build_free(runs: Sequence[RunRecord], name: str | None, caption: str,
                reference: Sequence[RunRecord]) -> TableResult:
    groups: dict[tuple, _Group] = {}
    for run in sorted(runs, key=_free_order):
        key = _row_identity(run)
        if key not in groups:
            tagged = len(key) == 2
            paper = key if tagged and run.table in TABLES else None
            groups[key] = _Group(run.row if tagged else run.label, run.label, paper, table=run.table,
                                 actor=run.actor)
        groups[key].runs.append(run)
    _disambiguate(list(groups.values()))
    return _finish(name, caption, _tasks_in(runs), list(groups.values()), reference)


def _free_order(run: RunRecord) -> tuple:
    """Grid rows in the paper's order (table, then row), then the rest by label."""
    names = list(TABLES)
    if run.table in TABLES:
        slugs = [row.slug for row in TABLES[run.table].rows]
        if run.row in slugs:
            return 0, names.index(run.table), slugs.index(run.row), "", str(run.path)
    return 1, 0, 0, run.label, str(run.path)


def _disambiguate(groups: list[_Group]) -> None:
    """Make row labels and keys unique: the same label in two tables (``D_fr [decode]``), or on runs
    with different actor switches (``ilc-san (intra=none)``, the switches that differ are shown)."""
    for same in _same_label(groups):
        if len({group.table for group in same}) > 1:
            for group in same:
                if group.table:
                    group.label, group.key = f"{group.label} [{group.table}]", f"{group.table}/{group.key}"
    for same in _same_label(groups):
        switches = sorted({key for group in same for key in group.actor})
        differing = [key for key in switches if len({repr(group.actor.get(key)) for group in same}) > 1]
        for group in same if differing else ():
            group.label += " (" + ", ".join(f"{key}={group.actor.get(key)}" for key in differing) + ")"
            group.key = group.label
    seen: dict[str, int] = {}
    for group in groups:  # last resort: number what is still ambiguous
        seen[group.key] = seen.get(group.key, 0) + 1
        if seen[group.key] > 1:
            group.key = group.label = f"{group.label} #{seen[group.key]}"


def _same_label(groups: Sequence[_Group]) -> list[list[_Group]]:
    """Groups that share a label, for every label shared by more than one group."""
    labels = [group.label for group in groups]
    shared = sorted({label for label in labels if labels.count(label) > 1})
    return [[group for group in groups if group.label == label] for label in shared]


def _tasks_in(runs: Iterable[RunRecord]) -> tuple[str, ...]:
    """Tasks found, the paper's eight first in the paper's order, then the others alphabetically."""
    found = {run.task for run in runs}
    return tuple(task for task in PAPER_TASKS if task in found) + tuple(sorted(found - set(PAPER_TASKS)))


def _dan_reference(groups: Sequence[_Group], reference: Sequence[RunRecord],
                   tasks: Sequence[str]) -> tuple[dict[str, float], str]:
    """Mean DAN score per task: the table's DAN row, else Table perf's DAN row, else any DAN run."""
    own = [run for group in groups if group.runs and all(run.is_dan for run in group.runs)
           for run in group.runs]
    perf = [run for run in reference if run.table == "perf" and run.row == "dan"]
    other = [run for run in reference if run.is_dan]
    sources = (("this table's DAN row", own), ("Table perf's DAN row", perf), ("other DAN runs", other))
    means: dict[str, float] = {}
    used: list[str] = []
    for task in tasks:
        for name, pool in sources:
            scores = [run.best_return for run in pool if run.task == task]
            if scores:
                means[task] = float(np.mean(scores))
                if name not in used:
                    used.append(name)
                break
    description = " and ".join(used) if used else "no DAN runs found (APR not computed)"
    return means, description


def _apr(cells: Sequence[Cell], dan: Mapping[str, float]) -> tuple[float | None, int]:
    ratios = [cell.mean / dan[cell.task] for cell in cells
              if cell.mean is not None and dan.get(cell.task) not in (None, 0.0)]
    return (100.0 * float(np.mean(ratios)), len(ratios)) if ratios else (None, 0)


def _finish(name: str | None, caption: str, tasks: tuple[str, ...], groups: Sequence[_Group],
            reference: Sequence[RunRecord]) -> TableResult:
    dan, described = _dan_reference(groups, reference, tasks)
    rows = []
    for group in groups:
        cells = tuple(
            Cell(task, tuple(sorted((r for r in group.runs if r.task == task), key=lambda r: r.seed)),
                 published_cell(*group.paper, task) if group.paper else None)
            for task in tasks
        )
        apr, count = _apr(cells, dan)
        rows.append(RowResult(group.key, group.label, cells, apr, count,
                              published_apr(*group.paper) if group.paper else None, group.runnable))
    return TableResult(name, caption, tasks, _mark_best(rows, tasks), described)


def _mark_best(rows: list[RowResult], tasks: Sequence[str]) -> tuple[RowResult, ...]:
    """Bold the highest mean of each column and the highest APR (ties are all bold)."""
    best = {}
    for index, task in enumerate(tasks):
        means = [row.cells[index].mean for row in rows if row.cells[index].mean is not None]
        best[task] = max(means) if means else None
    aprs = [row.apr for row in rows if row.apr is not None]
    top_apr = max(aprs) if aprs else None
    marked = []
    for row in rows:
        cells = tuple(dataclasses.replace(cell, best=cell.mean is not None and cell.mean == best[cell.task])
                      for cell in row.cells)
        best_apr = row.apr is not None and row.apr == top_apr
        marked.append(dataclasses.replace(row, cells=cells, best_apr=best_apr))
    return tuple(marked)


# ----------------------------------------------------------------------------------------------
# Rendering: Markdown, LaTeX (booktabs), CSV


def _decimals(value: float) -> int:
    magnitude = abs(value)
    return 0 if magnitude >= 100 else 1 if magnitude >= 10 else 2


def format_stat(mean: float, std: float) -> str:
    """``3583 ± 86``: integers as in the paper for |mean| ≥ 100, more decimals for small returns."""
    places = _decimals(mean)
    return f"{mean:.{places}f} ± {std:.{places}f}"


def _ours(cell: Cell) -> str:
    if cell.mean is None or cell.std is None:
        return ""
    return format_stat(cell.mean, cell.std)


def _count(cell: Cell) -> str:
    return f"n={cell.n}, {cell.running} running" if cell.running else f"n={cell.n}"


def _paper(cell: Cell) -> str:
    return format_stat(cell.paper.mean, cell.paper.std) if cell.paper else ""


def _apr_parts(row: RowResult, n_tasks: int) -> tuple[str, str]:
    """(``98.61%``, `` (3/4 tasks)`` when the APR averages fewer tasks than the table has)."""
    if row.apr is None:
        return "", ""
    partial = f" ({row.apr_tasks}/{n_tasks} tasks)" if row.apr_tasks < n_tasks else ""
    return f"{row.apr:.2f}%", partial


def _md_escape(text: str) -> str:
    for char in ("\\", "|", "*", "_"):
        text = text.replace(char, "\\" + char)
    return text


def _md_cell(cell: Cell) -> str:
    ours = _ours(cell)
    text = "—" if not ours else (f"**{ours}**" if cell.best else ours) + f" ({_count(cell)})"
    return text + (f" · paper {_paper(cell)}" if cell.paper else "")


def _md_apr(row: RowResult, n_tasks: int) -> str:
    ours, partial = _apr_parts(row, n_tasks)
    text = "—" if not ours else (f"**{ours}**" if row.best_apr else ours) + partial
    return text + (f" · paper {row.paper_apr:.2f}%" if row.paper_apr is not None else "")


def render_markdown(results: TableResult | Sequence[TableResult], skipped: Sequence[SkippedRun] = (),
                    title: str = "ILC-SAN reproduction report") -> str:
    """The tables as Markdown, with the statistics explained, missing cells and skipped runs listed."""
    results = [results] if isinstance(results, TableResult) else list(results)
    lines = [f"# {title}", ""]
    if not results:
        lines += ["No runs found.", ""]
    for result in results:
        lines += _md_table(result)
    lines += [
        "Cell: max average reward, i.e. each seed run's best evaluation (mean return over its evaluation "
        "episodes), as mean ± std over seeds (numpy std, ddof=0), n = number of seeds; bold = best of "
        "the column; `—` = no runs (missing). APR = mean over tasks of (cell / DAN cell), only over tasks "
        "where both exist. \"paper\" = the published value for the same table, row and task.",
        "",
    ]
    if skipped:
        lines += ["## Skipped runs", ""]
        lines += [f"- `{run.path}`: {run.reason}" for run in skipped]
        lines.append("")
    return "\n".join(lines)


def _md_table(result: TableResult) -> list[str]:
    heading = f"## Table `{result.name}`: {result.caption}" if result.name else f"## {result.caption}"
    header = ["Row", *result.tasks, "APR"]
    lines = [heading, "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in result.rows:
        label = _md_escape(row.label) + ("" if row.runnable else " (paper only)")
        cells = [_md_cell(cell) for cell in row.cells]
        lines.append("| " + " | ".join([label, *cells, _md_apr(row, len(result.tasks))]) + " |")
    lines += ["", f"APR reference (DAN): {result.reference}."]
    missing = result.missing
    if missing:
        total = sum(len(row.cells) for row in result.rows if row.runnable)
        lines.append(f"Missing cells (no runs): {len(missing)} of {total}: {_missing_text(result)}.")
    lines.append("")
    return lines


def _missing_text(result: TableResult) -> str:
    """Missing cells grouped by row: ``PopSAN: all tasks; I_self: Walker2d``."""
    parts = []
    for row in result.rows:
        tasks = [cell.task for cell in row.cells if not cell.n]
        if row.runnable and tasks:
            listed = "all tasks" if len(tasks) == len(row.cells) else ", ".join(tasks)
            parts.append(f"{_md_escape(row.label)}: {listed}")
    return "; ".join(parts)


_LATEX_SPECIAL = {
    "\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
    "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
    "α": r"$\alpha$", "±": r"$\pm$", "—": "--", "·": r"$\cdot$",
}


def latex_escape(text: str) -> str:
    """Escape LaTeX's special characters (and map α, ±, —, · to math or ASCII)."""
    return "".join(_LATEX_SPECIAL.get(char, char) for char in text)


def _tex_cell(cell: Cell) -> str:
    ours = _ours(cell)
    value = "--" if not ours else latex_escape(ours)
    value = rf"\textbf{{{value}}}" if cell.best else value
    notes = [_count(cell)] if ours else []
    if cell.paper:
        notes.append("paper " + latex_escape(_paper(cell)))
    return value + (rf" {{\scriptsize ({'; '.join(notes)})}}" if notes else "")


def _tex_apr(row: RowResult, n_tasks: int) -> str:
    ours, partial = _apr_parts(row, n_tasks)
    value = "--" if not ours else latex_escape(ours)
    value = (rf"\textbf{{{value}}}" if row.best_apr else value) + partial
    if row.paper_apr is not None:
        value += rf" {{\scriptsize (paper {row.paper_apr:.2f}\%)}}"
    return value


def render_latex(results: TableResult | Sequence[TableResult], skipped: Sequence[SkippedRun] = ()) -> str:
    """The tables as LaTeX ``table*`` environments with booktabs rules (needs ``\\usepackage{booktabs}``)."""
    results = [results] if isinstance(results, TableResult) else list(results)
    lines = ["% ILC-SAN reproduction report; requires \\usepackage{booktabs}",
             "% Cells: mean $\\pm$ std over seeds (ddof=0) of each run's max average reward; -- = no runs."]
    for result in results:
        label = f"tab:ours-{result.name}" if result.name else "tab:ours"
        lines += [
            r"\begin{table*}[t]",
            rf"\caption{{{latex_escape(result.caption)} (this reproduction)}}",
            rf"\label{{{latex_escape(label)}}}",
            r"\centering",
            r"\resizebox{\textwidth}{!}{",
            rf"\begin{{tabular}}{{l{'c' * (len(result.tasks) + 1)}}}",
            r"\toprule",
            " & ".join(["Row", *map(latex_escape, result.tasks), "APR"]) + r" \\",
            r"\midrule",
        ]
        for row in result.rows:
            cells = [_tex_cell(cell) for cell in row.cells]
            apr = _tex_apr(row, len(result.tasks))
            lines.append(" & ".join([latex_escape(row.label), *cells, apr]) + r" \\")
        lines += [r"\bottomrule", r"\end{tabular}}", r"\end{table*}", ""]
    lines += [f"% skipped {run.path}: {run.reason}".replace("\n", " ") for run in skipped]
    return "\n".join(lines) + "\n"


CSV_COLUMNS: tuple[str, ...] = (
    "table", "row", "label", "task", "kind", "status", "n", "running", "mean", "std", "best",
    "paper_mean", "paper_std",
)
"""Long format: one line per (row, task) cell (``kind`` = reward) and one per row for its APR
(``kind`` = apr, ``task`` = APR, ``n`` = number of tasks averaged, ``mean`` = APR in percent)."""


def render_csv(results: TableResult | Sequence[TableResult]) -> str:
    """The tables in long format (:data:`CSV_COLUMNS`); ``status`` is ok, running or missing."""
    results = [results] if isinstance(results, TableResult) else list(results)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for result in results:
        for row in result.rows:
            for cell in row.cells:
                status = "missing" if not cell.n else "running" if cell.running else "ok"
                writer.writerow([
                    result.name or "", row.key, row.label, cell.task, "reward", status, cell.n, cell.running,
                    _csv_number(cell.mean), _csv_number(cell.std), int(cell.best),
                    _csv_number(cell.paper.mean if cell.paper else None),
                    _csv_number(cell.paper.std if cell.paper else None),
                ])
            status = "ok" if row.apr is not None else "missing"
            writer.writerow([
                result.name or "", row.key, row.label, "APR", "apr", status, row.apr_tasks, "",
                _csv_number(row.apr), "", int(row.best_apr), _csv_number(row.paper_apr), "",
            ])
    return buffer.getvalue()


def _csv_number(value: float | None) -> str:
    return "" if value is None else repr(float(value))


# ----------------------------------------------------------------------------------------------
# Learning curves


def smooth(values: np.ndarray, window: int = SMOOTHING_WINDOW) -> np.ndarray:
    """Trailing moving average over ``window`` evaluations along the last axis.

    Point i is the mean of evaluations max(0, i − window + 1) … i, so the first points average fewer
    evaluations; the curve keeps its length and never looks ahead.
    """
    values = np.asarray(values, dtype=float)
    cumulative = np.cumsum(values, axis=-1)
    shifted = np.zeros_like(cumulative)
    shifted[..., window:] = cumulative[..., :-window]
    counts = np.minimum(np.arange(1, values.shape[-1] + 1), window)
    return (cumulative - shifted) / counts


def smoothing_window(points: int) -> int:
    """Smooth long curves only: 5 evaluations for the paper's 100-point curves, none below 20 points
    (a short run's few evaluations would lag far behind what it reached)."""
    return max(1, min(SMOOTHING_WINDOW, points // 20))


def curve(runs: Sequence[RunRecord], window: int | None = None) -> tuple[np.ndarray, ...] | None:
    """(steps, mean, std) over seeds at the steps every run evaluated, each run smoothed first.

    Curves are aligned on the common steps (the intersection of the runs' evaluation steps), so a
    seed that is still running shortens the curve. None when there are no common steps. ``window``
    defaults to :func:`smoothing_window` of the curve's length.
    """
    with_curves = [run for run in runs if run.steps]
    if not with_curves:
        return None
    common = sorted(set.intersection(*(set(run.steps) for run in with_curves)))
    if not common:
        return None
    values = np.array([[dict(zip(run.steps, run.returns, strict=True))[step] for step in common]
                       for run in with_curves])
    smoothed = smooth(values, smoothing_window(len(common)) if window is None else window)
    return np.array(common, dtype=float), smoothed.mean(axis=0), smoothed.std(axis=0, ddof=0)


def plot_curves(runs: Sequence[RunRecord], path: str | Path, table: str | TableSpec | None = None):
    """Learning curves as a PNG, in the style of the paper's figures; returns the matplotlib Figure.

    One panel per task of :func:`build_table` ``(runs, table)``, one line per row with runs: the mean
    over seeds of ``eval_return_mean`` against the step, shaded ± half the std (as the paper's
    figures), smoothed by :func:`smooth` (trailing moving average over 5 evaluations for curves of 100
    or more evaluations, fewer for shorter curves, none below 20: :func:`smoothing_window`) and aligned on
    the steps common to the row's seeds (:func:`curve`). Written atomically.
    """
    return draw_curves([build_table(runs, table)], path)


def draw_curves(results: Sequence[TableResult], path: str | Path):
    """Draw the curves of several tables in one figure (each table its own panels) and save it."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    tasks = [_plotted_tasks(result) for result in results]
    panels = [(result, task) for result, shown in zip(results, tasks, strict=True) for task in shown]
    lines_per = [math.ceil(len(shown) / PANELS_PER_LINE) for shown in tasks]
    n_lines, n_cols = max(1, sum(lines_per)), max(1, min(PANELS_PER_LINE, max(map(len, tasks), default=1)))
    single = len(panels) == 1  # one task (e.g. a grid shrunk with --tasks): a larger panel for its many rows
    figure = Figure(figsize=(6.4, 4.0) if single else (3.6 * n_cols, 2.9 * n_lines), layout="constrained")
    FigureCanvasAgg(figure)
    if not panels:
        axes = figure.add_subplot(1, 1, 1)
        axes.text(0.5, 0.5, "no runs found", ha="center", va="center", transform=axes.transAxes)
        axes.set_axis_off()
    first_line = 0
    for result, lines, shown in zip(results, lines_per, tasks, strict=True):
        for index, task in enumerate(shown):
            position = (first_line + index // PANELS_PER_LINE) * n_cols + index % PANELS_PER_LINE + 1
            _draw_panel(figure.add_subplot(n_lines, n_cols, position), result, task, len(results) > 1)
        first_line += lines
    _save_figure(figure, Path(path))
    return figure


def _plotted_tasks(result: TableResult) -> tuple[str, ...]:
    """The tasks that have runs (a shrunk reproduction shows only its own); all of them when none has."""
    with_runs = tuple(task for task in result.tasks if any(row.cell(task).runs for row in result.rows))
    return with_runs or result.tasks


def _draw_panel(axes, result: TableResult, task: str, prefix: bool) -> None:
    drawn = 0
    for index, row in enumerate(result.rows):
        data = curve(row.cell(task).runs)
        if data is None:
            continue
        steps, mean, std = data
        color = f"C{index % 10}"
        axes.plot(steps, mean, color=color, linewidth=1.2, label=row.label)
        axes.fill_between(steps, mean - std / 2, mean + std / 2, color=color, alpha=0.2, linewidth=0)
        drawn += 1
    title = f"{result.name}: {task}" if prefix and result.name else task
    axes.set_title(title, fontsize=10)
    axes.set_xlabel("steps", fontsize=8)
    axes.set_ylabel("average reward", fontsize=8)
    axes.tick_params(labelsize=7)
    axes.grid(alpha=0.3)
    if drawn:
        axes.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
        axes.legend(fontsize=6, loc="best")
    else:
        axes.text(0.5, 0.5, "no runs", ha="center", va="center", transform=axes.transAxes, color="0.5")


def _save_figure(figure, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(handle)
    try:
        figure.savefig(temporary, format="png", dpi=110)
        os.replace(temporary, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)


def _write_text(path: Path, text: str) -> None:
    """Write a text file atomically: a temporary file in the same directory, then ``os.replace``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "w", encoding="utf-8", newline="") as stream:
            stream.write(text)
        os.replace(temporary, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)


# ----------------------------------------------------------------------------------------------
# The whole report


def report_tables(runs: Sequence[RunRecord], table: str | TableSpec | None = None) -> list[TableResult]:
    """The tables of a report: the one asked for, or one per grid table found plus one for untagged runs.

    With ``table`` None, runs tagged with a grid table are shown in that table's layout (every row and
    task, in the paper's order for the paper's tables); runs without a tag go to one more table whose
    rows are their labels. DAN references are looked up among all runs.
    """
    if table is not None:
        return [build_table(runs, table)]
    tags = [name for name in TABLES if any(run.table == name for run in runs)]
    tags += sorted({run.table for run in runs if run.table and run.table not in TABLES})
    results = [
        _build_from_spec(runs, TABLES[tag], match_untagged=False, reference=runs) if tag in TABLES
        else _build_free([run for run in runs if run.table == tag], tag, tag, reference=runs)
        for tag in tags
    ]
    untagged = [run for run in runs if not run.table]
    if untagged:
        caption = "Runs without a table tag" if tags else "All runs"
        results.append(_build_free(untagged, None, caption, reference=runs))
    return results


def write_report(directory: str | Path, out_dir: str | Path | None = None,
                 table: str | TableSpec | None = None) -> dict[str, Path]:
    """Scan ``directory`` for runs and write ``report.md``, ``report.tex``, ``report.csv`` and
    ``curves.png`` into ``out_dir`` (default: ``directory``), each atomically.

    Returns the paths by kind: ``{"markdown", "latex", "csv", "curves"}``.
    """
    scan = scan_runs(directory)
    out = Path(out_dir) if out_dir is not None else Path(directory)
    results = report_tables(scan.runs, table)
    paths = {
        "markdown": out / "report.md",
        "latex": out / "report.tex",
        "csv": out / "report.csv",
        "curves": out / "curves.png",
    }
    _write_text(paths["markdown"], render_markdown(results, scan.skipped))
    _write_text(paths["latex"], render_latex(results, scan.skipped))
    _write_text(paths["csv"], render_csv(results))
    draw_curves(results, paths["curves"])
    return paths


def resolve_table(table: str | None, runs: Sequence[RunRecord] = ()) -> str | TableSpec | None:
    """The ``--table`` option: a paper table's name, a tag found among the runs, or a TOML grid file."""
    if table is None or table in TABLES or any(run.table == table for run in runs):
        return table
    if table.endswith(".toml"):
        from ..experiments.tables import load_grid

        return load_grid(table)
    tags = sorted({run.table for run in runs if run.table and run.table not in TABLES})
    raise UserError(f"no table {table!r}: use one of {', '.join([*TABLES, *tags])} or a grid's .toml file")
