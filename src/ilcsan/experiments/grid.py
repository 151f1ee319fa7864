"""A table expanded into runs: one per (task, row, seed), laid out as ``OUT/<table>/<task>/<row>/seed<k>/``.

Each run is an ordinary run folder (:mod:`ilcsan.runs.directory`) whose ``config.json`` carries ``table``,
``row`` and ``label``, so the report can place it in the table. A table's variants run on its own tasks or
on any task the user names (``--tasks``): one of the paper's tasks by its short name, or a registered
Gymnasium id with a Box action space. A task outside the table becomes one more column of the report,
without the paper's numbers.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import methods
from ..analysis.collect import RunRecord
from ..config import RunConfig, actor_config, check_settings, described_fields, training_config_class
from ..errors import UserError
from ..paper.layouts import TABLES, RowSpec, TableSpec
from ..paper.published import PAPER_TASK_NAMES
from ..rl.tasks import make_env, resolve_task
from .grid_files import load_grid

RUN_SETTINGS: tuple[str, ...] = tuple(item.name for item in described_fields(RunConfig))
"""The run settings a grid's options may set for all its runs (:attr:`GridOptions.run`)."""
PROTOCOL: tuple[str, ...] = tuple(item.name for item in dataclasses.fields(TableSpec) if item.name in RUN_SETTINGS)
"""The run settings a table fixes for its runs (steps, evaluation): an option replaces the table's."""


@dataclass(frozen=True)
class GridOptions:
    """How to shrink or place a table's grid (None and missing settings keep the table's protocol and the run
    defaults)."""

    seeds: tuple[int, ...] | None = None  # seed numbers (table: 0 .. seeds-1)
    tasks: tuple[str, ...] | None = None  # the table's tasks, or any others (paper short names, Gymnasium ids)
    rows: tuple[str, ...] | None = None  # a subset of the table's row slugs
    run: Mapping[str, Any] = field(default_factory=dict)  # RunConfig settings (RUN_SETTINGS), e.g. steps, matmul
    training: Mapping[str, Any] = field(default_factory=dict)  # training settings (TrainingConfig), e.g. start_steps


@dataclass(frozen=True)
class GridRun:
    """One (task, row, seed) of a grid: where it lives and its one-seed configuration."""

    task: str
    row: RowSpec
    seed: int
    directory: Path
    config: RunConfig

    @property
    def key(self) -> str:
        return run_key(self.task, self.row.slug, self.seed)


def run_key(task: str, row: str, seed: int) -> str:
    """How a run is named in logs and progress: ``task/row/seed<k>``."""
    return f"{task}/{row}/seed{seed}"


@dataclass(frozen=True)
class Grid:
    """A table expanded into runs below ``out/<table>``."""

    spec: TableSpec
    out: Path
    runs: tuple[GridRun, ...]
    seeds: tuple[int, ...]
    report_table: str | TableSpec
    """The layout the report uses: a paper table's name (the paper's full layout) or the user's grid."""

    @property
    def root(self) -> Path:
        return self.out / self.spec.name

    @property
    def total_steps(self) -> int:
        return sum(run.config.steps for run in self.runs)

    def cell(self, task: str, row: str) -> Path:
        return self.root / task_folder(task) / row


def task_folder(task: str) -> str:
    """A task's folder name: the task as written, with path separators replaced."""
    return task.replace("/", "_").replace(":", "_")


def table_to_reproduce(name: str) -> tuple[TableSpec, str | TableSpec]:
    """``ilcsan reproduce NAME``: a paper table by name or a TOML grid by path → (its grid, the layout its
    report uses: the paper table's name, or the user's grid itself)."""
    if name in TABLES:
        return TABLES[name], name
    if name.endswith(".toml") or Path(name).is_file():
        spec = load_grid(name)
        return spec, spec
    raise UserError(f"no table {name!r}: use one of {', '.join(TABLES)} or a grid file (.toml); "
                    "see `ilcsan reproduce --list`")


def report_layout(table: str | None, runs: Sequence[RunRecord] = ()) -> str | TableSpec | None:
    """The layout ``ilcsan report --table`` asks for: a paper table's name, a tag found among the runs,
    or a TOML grid file (None: every table found)."""
    if table is None or table in TABLES or any(run.table == table for run in runs):
        return table
    if table.endswith(".toml"):
        return load_grid(table)
    tags = sorted({run.table for run in runs if run.table and run.table not in TABLES})
    raise UserError(f"no table {table!r}: use one of {', '.join([*TABLES, *tags])} or a grid's .toml file")


def expand_grid(spec: TableSpec, out: str | Path, options: GridOptions | None = None,
                report_table: str | TableSpec | None = None) -> Grid:
    """Every run of ``spec`` as shrunk by ``options``, placed below ``out/<table>``."""
    options = options or GridOptions()
    tasks = select_tasks(options.tasks, spec)
    rows = select_rows(options.rows, spec)
    seeds = tuple(range(spec.seeds)) if options.seeds is None else tuple(options.seeds)
    if not seeds:
        raise UserError("give at least one seed")
    settings = {name: value for name, value in options.run.items() if value is not None}
    unknown = sorted(set(settings) - set(RUN_SETTINGS))
    if unknown:
        raise UserError(f"unknown run setting {unknown[0]!r}; the run settings are {', '.join(RUN_SETTINGS)}")
    protocol = {name: settings.pop(name) for name in PROTOCOL if name in settings}
    shrunk = dataclasses.replace(spec, tasks=tasks, rows=rows, seeds=len(seeds), **protocol)
    try:
        training = training_config_class()(**dict(options.training))
    except TypeError as error:
        raise UserError(f"unknown training setting: {error}") from None
    out = Path(out).expanduser().absolute()
    runs = []
    for task in tasks:
        for row in rows:
            base = dataclasses.replace(RunConfig(
                task=task, seeds=(seeds[0],), actor=actor_config(row.preset, **row.overrides), algorithm=row.algorithm,
                training=dataclasses.replace(training, **row.training), threads=1, label=row.label, table=spec.name,
                row=row.slug,
                **{name: getattr(shrunk, name) for name in PROTOCOL}), **settings)
            check_settings(base)
            try:
                methods.check_run(task, base.algorithm, base.actor, base.training)
            except UserError as error:
                raise UserError(f"table {spec.name}, row {row.slug}, {task}: {error} (a grid's row takes a "
                                f"training setting in its training table: `ilcsan reproduce path/to/grid.toml`)"
                                ) from None
            for seed in seeds:
                directory = out / spec.name / task_folder(task) / row.slug / f"seed{seed}"
                runs.append(GridRun(task, row, seed, directory, dataclasses.replace(base, seeds=(seed,))))
    return Grid(shrunk, out, tuple(runs), seeds, report_table if report_table is not None else spec)


def select_rows(wanted: Sequence[str] | None, spec: TableSpec) -> tuple[RowSpec, ...]:
    """The table's runnable rows, or the named ones (a row that only carries the paper's numbers is refused)."""
    slugs = select_names(wanted, tuple(row.slug for row in spec.rows), "row", spec.name)
    rows = [spec.row(slug) for slug in slugs]
    not_runnable = [row.slug for row in rows if not row.runnable]
    if wanted and not_runnable:
        raise UserError(f"row {not_runnable[0]!r} of table {spec.name!r} carries the paper's numbers only "
                        "(no code exists for it); leave it out of --rows")
    return tuple(row for row in rows if row.runnable)


def select_tasks(wanted: Sequence[str] | None, spec: TableSpec) -> tuple[str, ...]:
    """The table's tasks, or the named ones in the order given.

    A name matches a table task whatever its case; any other name must be a task ``ilcsan train`` accepts
    (:func:`runnable_task`), so a table's variants can run on tasks the paper did not use for that table.
    """
    if not wanted:
        return spec.tasks
    own = {task.lower(): task for task in spec.tasks}
    picked: list[str] = []
    for name in wanted:
        task = own.get(name.lower()) or runnable_task(name)
        if task not in picked:
            picked.append(task)
    return tuple(picked)


def runnable_task(name: str) -> str:
    """A task's name as a grid writes it: a paper task's short name (any case), or a Gymnasium id that is
    registered and has a Box action space (checked by building it once); UserError otherwise."""
    short = next((task for task in PAPER_TASK_NAMES if task.lower() == name.lower()), None)
    if short is not None:
        return short
    resolve_task(name)  # an unknown name: one sentence naming the tasks there are
    make_env(name).close()  # a registered task that an actor cannot drive (e.g. discrete actions)
    return name


def select_names(wanted: Sequence[str] | None, available: tuple[str, ...], what: str, table: str) -> tuple[str, ...]:
    """The names of ``wanted`` that ``available`` has, each once, in the order given; all when none is."""
    if not wanted:
        return available
    picked: list[str] = []
    for name in wanted:
        if name not in available:
            raise UserError(f"table {table!r} has no {what} {name!r}; its {what}s are {', '.join(available)}")
        if name not in picked:
            picked.append(name)
    return tuple(picked)
