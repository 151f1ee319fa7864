"""The paper's reward tables built from runs: cells, rows, APR (Section V-A, Tables ``tab:perf`` … ``tab:layer``).

* a run's score is its **max average reward**: the best evaluation's mean return over its episodes;
* a cell is the mean ± std of the scores of its seed runs, the sample standard deviation (``ddof=1``, as a
  spread over 10 seeds is usually quoted; none for a single seed), with the number of seeds n;
* APR = mean over tasks of (cell mean / DAN cell mean), in percent, **only over the tasks where both
  the row and DAN have runs** (the count is shown when it is fewer than the table's tasks). The DAN
  reference is, per task: the table's own DAN row if it has one, else the runs of Table ``perf``'s
  DAN row, else any other run whose actor preset is ``dan`` — as in the paper, where the APRs of
  ``decode``/``dec_intra``/``intra``/``layer`` are relative to the DAN of ``perf``;
* the best mean of each column (and the best APR) is marked best.

A run that ``ilcsan reproduce`` did not write (no table/row tags) is placed in a table's row by its label, else
by its configuration: the same algorithm, the same actor settings, all of them, and the same training method
(:func:`~ilcsan.config.method_settings`) as the row's — so ``ilcsan train --task Hopper --actor
ilc-san`` lands in Table perf's ILC-SAN (E_pop_det) row.

A cell carries the paper's value for its (table, row, task) where the paper has one; a task the paper
did not run in that table (e.g. ``reproduce intra --tasks Pendulum-v1``) is one more column without them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..config import actor_config
from ..paper.layouts import TABLES, RowSpec, TableSpec
from ..paper.published import PAPER_TASK_NAMES, Stat, published_apr, published_cell
from .collect import RunRecord, configuration_key, row_identity

SEED_STD_DDOF = 1
"""Spreads over seeds are sample standard deviations: ``numpy.std(..., ddof=1)``."""


def seed_std(scores: Sequence[float]) -> float | None:
    """Sample standard deviation of per-seed scores (``ddof=1``); None for fewer than two seeds, where it is
    undefined."""
    return float(np.std(scores, ddof=SEED_STD_DDOF)) if len(scores) > 1 else None


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
        """Sample standard deviation over seeds (:func:`seed_std`); None below two seeds."""
        return seed_std(self.scores)


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
    dan: Mapping[str, tuple[RunRecord, ...]] = field(default_factory=dict, compare=False)
    """The DAN reference's seed runs per task (by seed), the runs whose mean is each task's APR denominator."""

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
class _RowDraft:
    """A row being assembled: its runs and where the paper's numbers for it are."""

    key: str
    label: str
    paper: tuple[str, str] | None = None
    runnable: bool = True
    paper_apr: bool = True  # False where ``paper`` is another table's row (its APR averages other tasks)
    runs: list[RunRecord] = field(default_factory=list)
    table: str | None = None
    actor: Mapping[str, Any] = field(default_factory=dict)


def build_table(runs: Sequence[RunRecord], table: str | TableSpec | None = None) -> TableResult:
    """Build one table from runs.

    ``table`` a table name of :data:`ilcsan.paper.layouts.TABLES` or a :class:`TableSpec`: its rows and tasks,
    every cell present (``—`` where there are no runs), runs placed by their ``table``/``row`` tags, untagged
    runs by their label (or row slug) matching a row's, else by their configuration, and runs of other grids by
    their configuration. Any other name selects the runs tagged with it. None: all runs, rows by label (by tag
    when tagged), columns the tasks found.
    See the module docstring for the statistics (mean ± std with ``ddof=1``, APR over tasks where both exist).
    """
    spec = TABLES.get(table) if isinstance(table, str) else table
    if spec is not None:
        return _build_from_spec(runs, spec, place_others=True, reference=runs)
    if isinstance(table, str):
        return _build_free([run for run in runs if run.table == table], table, table, reference=runs)
    return _build_free(runs, None, "All runs", reference=runs)


def _rows_by_configuration(rows: Sequence[RowSpec]) -> dict[str, str]:
    """Row slug by configuration, for the runnable rows whose configuration no other row of the table shares."""
    keys: dict[str, list[str]] = {}
    for row in rows:
        if row.runnable and row.preset is not None:
            key = configuration_key(actor_config(row.preset, **row.overrides).to_dict(), dict(row.training),
                                    row.algorithm)
            keys.setdefault(key, []).append(row.slug)
    return {key: slugs[0] for key, slugs in keys.items() if len(slugs) == 1}


def _build_from_spec(runs: Sequence[RunRecord], spec: TableSpec, place_others: bool,
                     reference: Sequence[RunRecord]) -> TableResult:
    builtin = spec.name in TABLES
    groups = {row.slug: _RowDraft(row.slug, row.label, row.published or ((spec.name, row.slug) if builtin else None),
                                  row.runnable, paper_apr=row.published is None)
              for row in spec.rows}
    by_label = {row.label: row.slug for row in spec.rows}
    by_configuration = _rows_by_configuration(spec.rows)
    extra: dict[str, _RowDraft] = {}
    for run in runs:
        if run.table == spec.name:
            slug = run.row if run.row in groups else None
        elif place_others:
            slug = _row_of_foreign_run(run, groups, by_label, by_configuration)
            if slug is None:
                continue
        else:
            continue
        if slug is None:  # tagged with this table but a row the grid does not have
            group = extra.setdefault(run.label, _RowDraft(run.row or run.label, run.label))
        else:
            group = groups[slug]
        group.runs.append(run)
    found = _tasks_in(run for group in (*groups.values(), *extra.values()) for run in group.runs)
    tasks = spec.tasks + tuple(task for task in found if task not in spec.tasks)
    return _table_result(spec.name, spec.caption, tasks, [*groups.values(), *extra.values()], reference)


def _row_of_foreign_run(run: RunRecord, groups: Mapping[str, Any], by_label: Mapping[str, str],
                        by_configuration: Mapping[str, str]) -> str | None:
    """The row of the asked table that a run not tagged with it joins, if any: an untagged run by its row slug or
    label, else by its configuration; a run of another grid by its configuration alone (its row and label name that
    grid's rows), so that a grid's ILC-SAN seeds count in Table perf's ILC-SAN cell."""
    key = configuration_key(run.actor, run.training, run.algorithm)
    if run.table is None:
        return (run.row if run.row in groups else by_label.get(run.label)) or by_configuration.get(key)
    return by_configuration.get(key)


def _build_free(runs: Sequence[RunRecord], name: str | None, caption: str,
                reference: Sequence[RunRecord]) -> TableResult:
    groups: dict[tuple, _RowDraft] = {}
    for run in sorted(runs, key=_free_order):
        key = row_identity(run)
        if key not in groups:
            tagged = len(key) == 2
            paper = key if tagged and run.table in TABLES else None
            groups[key] = _RowDraft(run.row if tagged else run.label, run.label, paper, table=run.table,
                                 actor=run.actor)
        groups[key].runs.append(run)
    _disambiguate(list(groups.values()))
    return _table_result(name, caption, _tasks_in(runs), list(groups.values()), reference)


def _free_order(run: RunRecord) -> tuple:
    """Grid rows in the paper's order (table, then row), then the rest by label."""
    names = list(TABLES)
    if run.table in TABLES:
        slugs = [row.slug for row in TABLES[run.table].rows]
        if run.row in slugs:
            return 0, names.index(run.table), slugs.index(run.row), "", str(run.path)
    return 1, 0, 0, run.label, str(run.path)


def _disambiguate(groups: list[_RowDraft]) -> None:
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


def _same_label(groups: Sequence[_RowDraft]) -> list[list[_RowDraft]]:
    """Groups that share a label, for every label shared by more than one group."""
    labels = [group.label for group in groups]
    shared = sorted({label for label in labels if labels.count(label) > 1})
    return [[group for group in groups if group.label == label] for label in shared]


def _tasks_in(runs: Iterable[RunRecord]) -> tuple[str, ...]:
    """Tasks found, the paper's eight first in the paper's order, then the others alphabetically."""
    found = {run.task for run in runs}
    return tuple(task for task in PAPER_TASK_NAMES if task in found) + tuple(sorted(found - set(PAPER_TASK_NAMES)))


def _dan_reference(groups: Sequence[_RowDraft], reference: Sequence[RunRecord],
                   tasks: Sequence[str]) -> tuple[dict[str, tuple[RunRecord, ...]], str]:
    """DAN runs per task (by seed): the table's DAN row, else Table perf's DAN row, else any DAN run."""
    own = [run for group in groups if group.runs and all(run.is_dan for run in group.runs)
           for run in group.runs]
    perf = [run for run in reference if run.table == "perf" and run.row == "dan"]
    other = [run for run in reference if run.is_dan]
    sources = (("this table's DAN row", own), ("Table perf's DAN row", perf), ("other DAN runs", other))
    runs: dict[str, tuple[RunRecord, ...]] = {}
    used: list[str] = []
    for task in tasks:
        for name, pool in sources:
            found = sorted((run for run in pool if run.task == task), key=lambda run: run.seed)
            if found:
                runs[task] = tuple(found)
                if name not in used:
                    used.append(name)
                break
    description = " and ".join(used) if used else "no DAN runs found (APR not computed)"
    return runs, description


def dan_means(dan: Mapping[str, Sequence[RunRecord]]) -> dict[str, float]:
    """The APR's denominator per task: the mean max average reward of the DAN reference's runs on it."""
    return {task: float(np.mean([run.best_return for run in runs])) for task, runs in dan.items()}


def _apr(cells: Sequence[Cell], dan: Mapping[str, float]) -> tuple[float | None, int]:
    ratios = [cell.mean / dan[cell.task] for cell in cells
              if cell.mean is not None and dan.get(cell.task) not in (None, 0.0)]
    return (100.0 * float(np.mean(ratios)), len(ratios)) if ratios else (None, 0)


def _table_result(name: str | None, caption: str, tasks: tuple[str, ...], groups: Sequence[_RowDraft],
            reference: Sequence[RunRecord]) -> TableResult:
    dan, described = _dan_reference(groups, reference, tasks)
    rows = []
    for group in groups:
        cells = tuple(
            Cell(task, tuple(sorted((r for r in group.runs if r.task == task), key=lambda r: r.seed)),
                 published_cell(*group.paper, task) if group.paper else None)
            for task in tasks
        )
        apr, count = _apr(cells, dan_means(dan))
        rows.append(RowResult(group.key, group.label, cells, apr, count,
                              published_apr(*group.paper) if group.paper and group.paper_apr else None,
                              group.runnable))
    return TableResult(name, caption, tasks, _mark_best(rows, tasks), described, dan)


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
        _build_from_spec(runs, TABLES[tag], place_others=False, reference=runs) if tag in TABLES
        else _build_free([run for run in runs if run.table == tag], tag, tag, reference=runs)
        for tag in tags
    ]
    untagged = [run for run in runs if not run.table]
    if untagged:
        caption = "Runs without a table tag" if tags else "All runs"
        results.append(_build_free(untagged, None, caption, reference=runs))
    return results
