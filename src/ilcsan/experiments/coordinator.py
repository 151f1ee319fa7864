"""Every table of the paper as one command: ``ilcsan reproduce TABLE``, locally or on a Ray cluster.

A table (:data:`ilcsan.paper.layouts.TABLES`, or a user's TOML grid) expands into runs, one per
(task, row, seed), laid out as ``OUT/<table>/<task>/<row-slug>/seed<k>/`` (:mod:`.grid`); each is an
ordinary run folder (:mod:`ilcsan.runs.directory`) whose ``config.json`` carries ``table``, ``row`` and
``label``.

Running the same command again continues the grid: a finished run (``result.json`` says ``finished``)
is skipped and never touched, an interrupted one resumes from its ``checkpoint.pt`` (training resumes
exactly), a run that never wrote a checkpoint (at its first evaluation, or after ``checkpoint_minutes`` of
training) starts again. Runs whose ``config.json`` was written with other settings stop the command before
anything starts: use the same options, or another ``--out``.

The unfinished runs are cut into jobs (:mod:`.jobs`: the seeds of a cell train together in one process)
and handed to a backend (:mod:`.backends`: local worker processes or Ray), which :func:`run_grid` keeps
busy: ``slots`` jobs at a time, a job whose worker process died started again from its checkpoint up to
:data:`CRASH_RETRIES` times. The command prints which job starts, finishes or is skipped, how many runs
are left, and an ETA from the measured throughput (:mod:`.progress`); at the end it writes the report
(:func:`ilcsan.analysis.report.write_report`) into ``OUT/<table>/``. Worker output (one line per
evaluation) goes to ``OUT/<table>/logs/``.
"""

from __future__ import annotations

import collections
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..analysis.report import write_report
from ..analysis.reward_tables import seed_std
from .backends import Backend, LocalBackend, make_backend, termination_as_ctrl_c
from .grid import Grid, GridRun
from .jobs import Job, JobOutcome, RunState, balance_jobs, format_seeds, group_jobs, max_seeds_per_job, run_state
from .progress import Progress, format_duration

CRASH_RETRIES = 2
"""How often a job whose worker process died is started again (it resumes from its last checkpoint)."""
POLL_SECONDS = 10.0
HEARTBEAT_SECONDS = 300.0

Log = Callable[[str], None]
EventHook = Callable[[str, "Job | None"], None]


@dataclass(frozen=True)
class GridSummary:
    """What a call of :func:`run_grid` did."""

    runs: int
    skipped: int  # finished before this call
    finished: int  # finished during this call
    failed: tuple[tuple[str, str], ...]  # (job name, reason)
    interrupted: bool
    diverged: bool
    report: Mapping[str, Path] | None
    wall_seconds: float


def run_grid(grid: Grid, backend: str | Backend = "local", workers: int | None = None, address: str | None = None,
             dashboard: bool = False, log: Log = print, on_event: EventHook | None = None,
             poll_seconds: float = POLL_SECONDS, heartbeat_seconds: float = HEARTBEAT_SECONDS,
             write_report: bool = True) -> GridSummary:
    """Run every unfinished run of ``grid`` on ``backend`` and write the report; see the module docstring.

    ``on_event(kind, job)`` is called on ``start``, ``finish`` and ``fail`` of each job (a hook for
    tests and tools). Ctrl-C or SIGTERM stops the running jobs, each keeping its last checkpoint.
    """
    started = time.monotonic()
    states = {run.key: run_state(run.directory, run.config) for run in grid.runs}
    skipped = sum(state.status == "finished" for state in states.values())
    log(f"ilcsan reproduce {grid.spec.name}: {len(grid.spec.tasks)} task(s) × {len(grid.spec.rows)} row(s) × "
        f"{len(grid.seeds)} seed(s) = {len(grid.runs)} runs of {grid.spec.steps} steps in {grid.root}")
    log_run_states(grid, states, log)
    jobs = group_jobs(grid, states)
    summary = dict(runs=len(grid.runs), skipped=skipped, failed=(), interrupted=False, diverged=False)
    if not jobs:
        log("every run is finished; nothing to train")
        return _summarise(grid, summary, 0, started, write_report, log)
    if isinstance(backend, str) and address:
        log(f"joining the Ray cluster at {address} …")
    executor = make_backend(backend, workers, address, dashboard) if isinstance(backend, str) else backend
    progress = Progress.start(grid, states)
    try:
        with termination_as_ctrl_c():
            outcome = keep_slots_busy(grid, executor, jobs, progress, log, on_event, poll_seconds, heartbeat_seconds)
    finally:
        executor.close()
    summary.update(outcome)
    finished = progress.runs_finished - skipped
    if summary["interrupted"]:
        log(f"interrupted: {finished} run(s) finished in this call, the others keep their last checkpoint; "
            "run the same command again to continue")
        return GridSummary(**summary, finished=finished, report=None, wall_seconds=time.monotonic() - started)
    return _summarise(grid, summary, finished, started, write_report, log)


def log_run_states(grid: Grid, states: Mapping[str, RunState], log: Log) -> None:
    """One line per cell with finished or partial runs."""
    cells: dict[tuple[str, str], list[GridRun]] = {}
    for run in grid.runs:
        cells.setdefault((run.task, run.row.slug), []).append(run)
    for (task, row), runs in cells.items():
        finished = [run.seed for run in runs if states[run.key].status == "finished"]
        partial = [f"{run.seed}@{states[run.key].step}" for run in runs if states[run.key].status == "partial"]
        if finished:
            log(f"  skip   {task}/{row} seed(s) {format_seeds(finished)}: finished")
        if partial:
            log(f"  resume {task}/{row} seed@step {', '.join(partial)}")


def keep_slots_busy(grid: Grid, backend: Backend, jobs: list[Job], progress: Progress, log: Log,
                    on_event: EventHook | None, poll_seconds: float, heartbeat_seconds: float) -> dict[str, Any]:
    """Keep ``backend.slots`` jobs running until all are done; returns the summary's failure fields."""
    limit = max_seeds_per_job(grid, backend.slots)
    queue = collections.deque(balance_jobs(jobs, backend.slots, limit))
    total_jobs = len(queue)
    _log_plan(grid, backend, total_jobs, limit, log)
    log(progress.line())
    running: dict[Any, Job] = {}
    attempts: collections.Counter[Job] = collections.Counter()
    failed: list[tuple[str, str]] = []
    diverged, started_jobs, last_line = False, 0, time.monotonic()
    runs_by_key = {run.key: run for run in grid.runs}
    try:
        while queue or running:
            while queue and len(running) < backend.slots:
                job = queue.popleft()
                running[backend.submit(job)] = job
                started_jobs += attempts[job] == 0
                log(f"[start] {job.name} from step {job.start_step}"
                    + (f" (retry {attempts[job]})" if attempts[job] else f" · job {started_jobs}/{total_jobs}"))
                _emit(on_event, "start", job)
            for handle in backend.wait(list(running), poll_seconds):
                job = running.pop(handle)
                outcome = backend.outcome(handle)
                progress.update(runs_by_key[key] for key in job.run_keys)
                if outcome.crashed and attempts[job] < CRASH_RETRIES:
                    attempts[job] += 1
                    log(f"[retry] {job.name}: {outcome.error}; it resumes from its last checkpoint")
                    queue.appendleft(job)
                elif outcome.error is not None:
                    failed.append((job.name, outcome.error))
                    diverged = diverged or outcome.diverged
                    log(f"[FAIL ] {job.name}: {outcome.error}")
                    _emit(on_event, "fail", job)
                else:
                    log(f"[done ] {job.name} in {format_duration(outcome.wall_seconds)} · {_scores(outcome)}")
                    _emit(on_event, "finish", job)
                log(progress.line())
                last_line = time.monotonic()
            progress.update(runs_by_key[key] for job in running.values() for key in job.run_keys)
            if time.monotonic() - last_line >= heartbeat_seconds:
                log(progress.line())
                last_line = time.monotonic()
    except KeyboardInterrupt:
        try:
            log(f"stopping {len(running)} running job(s); each keeps its last checkpoint ...")
        finally:  # the workers stop even when the log cannot be written (its reader gone)
            notes = backend.interrupt(list(running))
        for note in notes:
            log(note)
        return {"failed": tuple(failed), "interrupted": True, "diverged": diverged}
    return {"failed": tuple(failed), "interrupted": False, "diverged": diverged}


def _log_plan(grid: Grid, backend: Backend, total_jobs: int, limit: int | None, log: Log) -> None:
    """Where the jobs run, how many there are, where their logs go; a warning for more workers than cores."""
    log(f"{backend.describe()}; {total_jobs} job(s): the seeds of a (task, row) train together in one process"
        + (f" (at most {limit} per process, for memory)" if limit is not None and limit < len(grid.seeds) else ""))
    log(f"worker logs: {grid.root / 'logs'}")
    if isinstance(backend, LocalBackend) and backend.slots > (os.cpu_count() or 1):
        log(f"warning: {backend.slots} workers on {os.cpu_count()} cores; the processes will slow each other down")


def _emit(on_event: EventHook | None, kind: str, job: Job | None) -> None:
    if on_event is not None:
        on_event(kind, job)


def _scores(outcome: JobOutcome) -> str:
    """The seeds' best evaluations: ``best 812.3 ± 40.1 over 3 seeds (sample std)``, as the report gives them
    (:func:`~ilcsan.analysis.reward_tables.seed_std`, ddof = 1)."""
    bests = [result["best_return"] for result in outcome.results if result.get("best_return") is not None]
    if not bests:
        return "no evaluation"
    mean, std = sum(bests) / len(bests), seed_std(bests)
    return f"best {mean:.1f}" + (f" ± {std:.1f} over {len(bests)} seeds (sample std)" if std is not None else "")


def _summarise(grid: Grid, summary: dict[str, Any], finished: int, started: float, write: bool,
               log: Log) -> GridSummary:
    """Write the report (unless told not to), list the failed jobs, and return the summary."""
    report = None
    if write:
        report = write_report(grid.out, grid.root, grid.report_table)
        log(f"report: {report['markdown']} (also .tex, .csv) · learning curves: {report['curves']}")
    for name, reason in summary["failed"]:
        log(f"failed: {name}: {reason}")
    return GridSummary(**summary, finished=finished, report=report, wall_seconds=time.monotonic() - started)


__all__ = ["GridSummary", "run_grid", "keep_slots_busy", "log_run_states", "CRASH_RETRIES"]
