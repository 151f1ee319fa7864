"""Where each run of a grid stands, and the jobs that train the unfinished ones.

A **job** is one process's work: the unfinished seeds of one (task, row) cell that stand at the same
checkpoint step; they train together with their weights stacked (``RunConfig(seeds=...)``), which is
faster in aggregate than one process per seed. Jobs are split when there are fewer of them than worker
slots, or when the seeds' replay buffers would not fit in memory (:func:`seed_replay_bytes`).
"""

from __future__ import annotations

import dataclasses
import math
import time
import traceback
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from ..config import RunConfig
from ..errors import TrainingDiverged, UserError
from ..rl.ram import physical_memory, replay_bytes
from ..rl.tasks import TASK_SPECS, make_env
from ..rl.training import train
from ..runs.checkpoint import differing_settings
from ..runs.directory import CONFIG, RunDirectory
from .grid import Grid, GridRun, run_key, task_folder

MEMORY_FRACTION = 0.7
"""Share of the machine's memory the replay buffers of all worker processes may take together."""


# ------------------------------------------------------------------------------------ runs on disk
Status = Literal["new", "partial", "finished"]


@dataclass(frozen=True)
class RunState:
    """Where a run stands: ``new`` (from step 0), ``partial`` (a checkpoint at ``step``) or ``finished``."""

    status: Status
    step: int = 0


def run_state(directory: Path, config: RunConfig) -> RunState:
    """Read a run's folder; refuse (UserError) a run made with other settings than ``config``'s.

    A finished run is one whose ``result.json`` says ``finished`` after all of ``config.steps``; an
    unreadable ``result.json`` counts as none (the checkpoint decides). A run on disk with a smaller budget
    than the grid's is partial: it resumes from its last checkpoint to the grid's budget."""
    run = RunDirectory(directory)
    if run.file(CONFIG).exists():
        check_same_settings(directory, config)
    result = run.result_or_empty()
    if result.get("finished") is True and result.get("steps_done", 0) >= config.steps:
        return RunState("finished", config.steps)
    step = run.checkpoint_step()
    return RunState("new", 0) if step is None else RunState("partial", step)


def check_same_settings(directory: Path, config: RunConfig) -> None:
    """UserError unless the run in ``directory`` was started with ``config``'s settings."""
    differing = differing_settings(RunDirectory(directory).run_config(), config)
    if differing:
        raise UserError(f"{directory} was run with other settings ({', '.join(differing)}) than this grid; "
                        "repeat the options it was started with, or choose another --out")


# ------------------------------------------------------------------------------------------- jobs
@dataclass(frozen=True)
class Job:
    """One process's work: seeds of one (task, row) cell that start from the same checkpoint step."""

    table: str
    task: str
    row: str
    cell: Path
    config: RunConfig
    start_step: int
    log_file: Path

    @property
    def seeds(self) -> tuple[int, ...]:
        return self.config.seeds

    @property
    def out(self) -> Path:
        """Where the trainer writes: the cell for several seeds (it adds ``seed<k>``), else the seed's run."""
        return self.cell if len(self.seeds) > 1 else self.cell / f"seed{self.seeds[0]}"

    @property
    def directories(self) -> list[Path]:
        return [self.cell / f"seed{seed}" for seed in self.seeds]

    @property
    def run_keys(self) -> list[str]:
        """The :attr:`GridRun.key` of each of the job's seeds."""
        return [run_key(self.task, self.row, seed) for seed in self.seeds]

    @property
    def steps_left(self) -> int:
        return (self.config.steps - self.start_step) * len(self.seeds)

    @property
    def name(self) -> str:
        return f"{self.task}/{self.row} seed{'s' if len(self.seeds) > 1 else ''} {format_seeds(self.seeds)}"


def format_seeds(seeds: Iterable[int]) -> str:
    """(0, 1, 2, 5, 7, 8) → '0-2,5,7-8'."""
    ordered = sorted(seeds)
    parts: list[str] = []
    start = previous = None
    for seed in [*ordered, None]:
        if start is not None and (seed is None or seed != previous + 1):
            parts.append(str(start) if start == previous else f"{start}-{previous}")
            start = None
        if seed is not None and start is None:
            start = seed
        previous = seed
    return ",".join(parts)


def job_log_file(root: Path, task: str, row: str, seeds: Iterable[int]) -> Path:
    """``<table>/logs/<task>--<row>--s<seeds>.log``: one log per job, named by its seeds."""
    return root / "logs" / f"{task_folder(task)}--{row}--s{format_seeds(seeds)}.log"


def group_jobs(grid: Grid, states: Mapping[str, RunState]) -> list[Job]:
    """One job per (cell, checkpoint step) of the unfinished runs, in the grid's order."""
    cells: dict[tuple[str, str, int], list[GridRun]] = {}
    for run in grid.runs:
        state = states[run.key]
        if state.status != "finished":
            cells.setdefault((run.task, run.row.slug, state.step), []).append(run)
    return [_cell_job(grid, runs, step) for (_, _, step), runs in cells.items()]


def _cell_job(grid: Grid, runs: Sequence[GridRun], step: int) -> Job:
    first = runs[0]
    seeds = tuple(run.seed for run in runs)
    return Job(grid.spec.name, first.task, first.row.slug, grid.cell(first.task, first.row.slug),
               dataclasses.replace(first.config, seeds=seeds), step,
               job_log_file(grid.root, first.task, first.row.slug, seeds))


def split_job(job: Job, parts: int) -> list[Job]:
    """Cut a job's seeds into ``parts`` nearly equal jobs (same cell, same start step)."""
    seeds = job.seeds
    base, extra = divmod(len(seeds), max(1, min(parts, len(seeds))))
    jobs, start = [], 0
    for index in range(min(parts, len(seeds))):
        size = base + (index < extra)
        chunk, start = seeds[start:start + size], start + size
        log_file = job_log_file(job.log_file.parent.parent, job.task, job.row, chunk)
        jobs.append(dataclasses.replace(job, config=dataclasses.replace(job.config, seeds=chunk), log_file=log_file))
    return jobs


def balance_jobs(jobs: Sequence[Job], slots: int, max_seeds: int | None = None) -> list[Job]:
    """Split jobs so none holds more than ``max_seeds`` seeds and, while possible, there is a job per slot.

    Larger jobs go first (longest first keeps the slots busy to the end).
    """
    balanced: list[Job] = []
    for job in jobs:
        parts = 1 if max_seeds is None else math.ceil(len(job.seeds) / max(1, max_seeds))
        balanced.extend(split_job(job, parts) if parts > 1 else [job])
    while len(balanced) < slots:
        largest = max(balanced, key=lambda job: (len(job.seeds), job.steps_left), default=None)
        if largest is None or len(largest.seeds) < 2:
            break
        index = balanced.index(largest)
        balanced[index:index + 1] = split_job(largest, 2)
    return sorted(balanced, key=lambda job: -job.steps_left)


# ----------------------------------------------------------------------------------------- memory
def seed_replay_bytes(task: str, config: RunConfig) -> int:
    """Memory of one seed's replay buffer when full: capacity × (2N + M + 2) float32 values."""
    spec = TASK_SPECS.get(task)
    if spec is not None:
        state_dim, action_dim = spec.state_dim, spec.action_dim
    else:
        env = make_env(task)
        state_dim, action_dim = int(env.observation_space.shape[0]), int(env.action_space.shape[0])
        env.close()
    return replay_bytes(state_dim, action_dim, min(config.training.replay_size, config.steps))


def max_seeds_per_job(grid: Grid, slots: int, memory: int | None = None) -> int | None:
    """The most seeds one process may hold so that ``slots`` processes fit in memory (None: no limit)."""
    memory = physical_memory() if memory is None else memory
    if not memory:
        return None
    largest = max((seed_replay_bytes(task, grid.runs[0].config) for task in grid.spec.tasks), default=0)
    if largest <= 0:
        return None
    return max(1, int(memory * MEMORY_FRACTION / max(1, slots) // largest))


# ----------------------------------------------------------------------------------- the worker side
@dataclass(frozen=True)
class JobOutcome:
    """What a worker reports back: each seed's result, or why the job failed."""

    results: tuple[dict[str, Any], ...] = ()
    error: str | None = None
    diverged: bool = False
    crashed: bool = False  # the worker process died (the job can be retried from its checkpoint)
    wall_seconds: float = 0.0


def run_job(job: Job) -> JobOutcome:
    """Train a job's seeds to the end, resuming from their checkpoints; runs in a worker process.

    The seeds' states are read again here, so a retried job (Ray, or a replaced local worker) continues
    where the previous attempt stopped, even when that attempt left the seeds at different checkpoints.
    """
    started = time.perf_counter()
    job.log_file.parent.mkdir(parents=True, exist_ok=True)
    with open(job.log_file, "a", encoding="utf-8") as stream:
        def log(message: str) -> None:
            stream.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} {message}\n")
            stream.flush()

        log(f"job {job.name}: {job.config.steps} steps per seed, from step {job.start_step}")
        results: list[dict[str, Any]] = []
        try:
            for seeds in unfinished_seed_groups(job):
                config = dataclasses.replace(job.config, seeds=seeds)
                out = job.cell if len(seeds) > 1 else job.cell / f"seed{seeds[0]}"
                results.extend(train(config, out, resume=True, progress=False, log=log))
        except (UserError, TrainingDiverged) as error:
            log(f"stopped: {error}")
            return JobOutcome(tuple(results), str(error), isinstance(error, TrainingDiverged),
                              wall_seconds=time.perf_counter() - started)
        except Exception as error:  # a bug or a broken environment: keep the traceback in the job's log
            log(traceback.format_exc())
            return JobOutcome(tuple(results), f"{type(error).__name__}: {error} (traceback in {job.log_file})",
                              wall_seconds=time.perf_counter() - started)
        log(f"job {job.name} finished")
    return JobOutcome(tuple(results), wall_seconds=time.perf_counter() - started)


def unfinished_seed_groups(job: Job) -> list[tuple[int, ...]]:
    """The job's unfinished seeds grouped by checkpoint step (normally one group: all of them)."""
    groups: dict[int, list[int]] = {}
    for seed, directory in zip(job.seeds, job.directories, strict=True):
        state = run_state(directory, dataclasses.replace(job.config, seeds=(seed,)))
        if state.status != "finished":
            groups.setdefault(state.step, []).append(seed)
    return [tuple(seeds) for _, seeds in sorted(groups.items())]
