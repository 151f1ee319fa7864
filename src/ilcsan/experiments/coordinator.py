"""Every table of the paper as one command: ``ilcsan reproduce TABLE``, locally or on a Ray cluster.

A table (:data:`ilcsan.grids.TABLES`, or a user's TOML grid) expands into runs, one per
(task, row, seed), laid out as ``OUT/<table>/<task>/<row-slug>/seed<k>/``; each is an ordinary run
directory (see :mod:`ilcsan.training`) whose ``config.json`` carries ``table``, ``row`` and ``label``.

Running the same command again continues the grid: a finished run (``result.json`` says ``finished``)
is skipped and never touched, an interrupted one resumes from its ``checkpoint.pt`` (training resumes
exactly), a run that never reached its first evaluation starts again. Runs whose ``config.json`` was
written with other settings stop the command before anything starts: use the same options, or another
``--out``.

Work is cut into **jobs**: the unfinished seeds of one (task, row) cell that stand at the same
checkpoint step train together in one process, with the seeds' weights stacked
(``RunConfig(seeds=...)``), which is faster in aggregate than one process per seed. Cells are split
into smaller jobs when there are fewer jobs than worker slots, or when the seeds' replay buffers would
not fit in memory (:func:`seed_replay_bytes`).

Backends:

``local`` (default)  a pool of ``--workers`` processes (default: the number of cores), started with
                     ``spawn``, each training one job at a time with **one** torch thread (two
                     processes fighting over the cores are 10-50x slower). A worker process that
                     dies (e.g. killed for memory) is replaced and its job resumed from its checkpoint,
                     up to :data:`LOCAL_RETRIES` times.
``ray``              one Ray task per job with ``num_cpus=1``; Ray retries a task whose worker or node
                     dies (``max_retries``), and the retry resumes from the checkpoint. Without
                     ``--address`` a private single-machine Ray is started, listening on the loopback
                     interface only, dashboard off; ``--address HOST:PORT`` (or ``auto``) joins an
                     existing cluster. On a cluster of several machines, ``OUT`` must be on storage
                     shared by every node under the same path (NFS, a cluster file system) and
                     ``ilcsan`` installed on every node; the driver reads progress and writes the
                     report from that path. Install Ray with ``pip install "ilcsan[ray]"``.

The command prints which job starts, finishes or is skipped, how many runs are left, and an ETA from
the measured throughput; at the end it writes the report (:func:`ilcsan.report.write_report`) into
``OUT/<table>/``. Worker output (one line per evaluation) goes to ``OUT/<table>/logs/``.
"""

from __future__ import annotations

import collections
import concurrent.futures
import contextlib
import dataclasses
import json
import logging
import math
import multiprocessing
import os
import signal
import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

from ..config import RunConfig, TD3Config, actor_config
from ..errors import TrainingDiverged, UserError
from ..rl.memory import physical_memory, replay_bytes
from ..rl.training import load_run_config
from .tables import TABLES, RowSpec, TableSpec, load_grid

DEFAULT_STEPS_PER_SECOND = 110.0
"""Environment steps per second of one ILC-SAN run on Hopper on one core (one torch thread), evaluations
included, used by :func:`estimate_hours` and ``reproduce --list`` unless ``ILCSAN_STEPS_PER_SECOND``
gives a newer measurement. Measured on the 2-core development machine (2026-11, speed work still in
progress): after the 1 000 random steps, 125 training steps per CPU second with ``torch.compile`` (on by
default for runs of 50 000 steps or more; 75 without), and 0.97 ms per evaluation step; the protocol's
evaluations (10 episodes every 10 000 steps) add at most one evaluation step per training step:
1 / (1/125 + 0.00097) ≈ 111 steps/s."""

STEPS_PER_SECOND_ENV = "ILCSAN_STEPS_PER_SECOND"
EXAMPLE_CLUSTER_CORES = 64
"""The cluster size ``reproduce --list`` shows beside this machine."""

MEMORY_FRACTION = 0.7
"""Share of the machine's memory the replay buffers of all worker processes may take together."""

LOCAL_RETRIES = 2
RAY_MAX_RETRIES = 3
POLL_SECONDS = 10.0
HEARTBEAT_SECONDS = 300.0
RAY_INSTALL_HINT = 'pip install "ilcsan[ray]"'
SETTINGS_COMPARED = ("task", "actor", "td3", "steps", "eval_every", "eval_episodes")
"""The settings a run on disk must share with the grid to be skipped or resumed (as the trainer checks)."""


# ----------------------------------------------------------------------------------------- the grid
@dataclass(frozen=True)
class GridOptions:
    """How to shrink or place a table's grid (every None keeps the table's own protocol)."""

    seeds: tuple[int, ...] | None = None  # seed numbers (table: 0 .. seeds-1)
    steps: int | None = None  # environment steps per run
    tasks: tuple[str, ...] | None = None  # a subset of the table's tasks
    rows: tuple[str, ...] | None = None  # a subset of the table's row slugs
    eval_every: int | None = None
    eval_episodes: int | None = None
    td3: Mapping[str, Any] = field(default_factory=dict)  # TD3Config overrides, e.g. start_steps
    device: str = "cpu"
    matmul: str = "float32"  # float32 | bf16 (RunConfig.matmul)


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
        return f"{self.task}/{self.row.slug}/seed{self.seed}"


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


def resolve_table(name: str) -> tuple[TableSpec, str | TableSpec]:
    """A paper table by name or a TOML grid by path → (its grid, the layout its report uses)."""
    if name in TABLES:
        return TABLES[name], name
    if name.endswith(".toml") or Path(name).is_file():
        spec = load_grid(name)
        return spec, spec
    raise UserError(f"no table {name!r}: use one of {', '.join(TABLES)} or a grid file (.toml); "
                    "see `ilcsan reproduce --list`")


def expand_grid(spec: TableSpec, out: str | Path, options: GridOptions | None = None,
                report_table: str | TableSpec | None = None) -> Grid:
    """Every run of ``spec`` as shrunk by ``options``, placed below ``out/<table>``."""
    from ..rl.tasks import resolve_task

    options = options or GridOptions()

    tasks = _pick(options.tasks, spec.tasks, "task", spec.name, case_insensitive=True)
    slugs = _pick(options.rows, tuple(row.slug for row in spec.rows), "row", spec.name)
    rows = [spec.row(slug) for slug in slugs]
    not_runnable = [row.slug for row in rows if not row.runnable]
    if options.rows and not_runnable:
        raise UserError(f"row {not_runnable[0]!r} of table {spec.name!r} carries the paper's numbers only "
                        "(no code exists for it); leave it out of --rows")
    rows = [row for row in rows if row.runnable]
    seeds = tuple(range(spec.seeds)) if options.seeds is None else tuple(options.seeds)
    if not seeds:
        raise UserError("give at least one seed")
    for task in tasks:
        resolve_task(task)
    shrunk = dataclasses.replace(
        spec, tasks=tasks, rows=tuple(rows), seeds=len(seeds),
        steps=options.steps or spec.steps, eval_every=options.eval_every or spec.eval_every,
        eval_episodes=options.eval_episodes or spec.eval_episodes)
    try:
        td3 = TD3Config(**dict(options.td3))
    except TypeError as error:
        raise UserError(f"unknown TD3 setting: {error}") from None
    out = Path(out).expanduser().absolute()
    runs = []
    for task in tasks:
        for row in rows:
            base = RunConfig(task=task, seeds=(seeds[0],), steps=shrunk.steps, eval_every=shrunk.eval_every,
                             eval_episodes=shrunk.eval_episodes, actor=actor_config(row.preset, **row.overrides),
                             td3=td3, device=options.device, matmul=options.matmul, threads=1, label=row.label,
                             table=spec.name, row=row.slug)
            for seed in seeds:
                directory = out / spec.name / task_folder(task) / row.slug / f"seed{seed}"
                runs.append(GridRun(task, row, seed, directory, dataclasses.replace(base, seeds=(seed,))))
    return Grid(shrunk, out, tuple(runs), seeds, report_table if report_table is not None else spec)


def _pick(wanted: Sequence[str] | None, available: tuple[str, ...], what: str, table: str,
          case_insensitive: bool = False) -> tuple[str, ...]:
    if not wanted:
        return available
    lookup = {(name.lower() if case_insensitive else name): name for name in available}
    picked = []
    for name in wanted:
        found = lookup.get(name.lower() if case_insensitive else name)
        if found is None:
            raise UserError(f"table {table!r} has no {what} {name!r}; its {what}s are {', '.join(available)}")
        if found not in picked:
            picked.append(found)
    return tuple(picked)


# ------------------------------------------------------------------------------------ runs on disk
Status = Literal["new", "partial", "finished"]


@dataclass(frozen=True)
class RunState:
    """Where a run stands: ``new`` (from step 0), ``partial`` (a checkpoint at ``step``) or ``finished``."""

    status: Status
    step: int = 0


def run_state(directory: Path, config: RunConfig) -> RunState:
    """Read a run's directory; refuse (UserError) a run made with other settings than ``config``'s."""
    if (directory / "config.json").exists():
        check_same_settings(directory, config)
    result = read_result(directory)
    if result.get("finished") is True and result.get("steps_done", 0) >= config.steps:
        return RunState("finished", config.steps)
    checkpoint = directory / "checkpoint.pt"
    if checkpoint.exists():
        from ..files import safe_torch_load

        return RunState("partial", int(safe_torch_load(checkpoint)["step"]))
    return RunState("new", 0)


def check_same_settings(directory: Path, config: RunConfig) -> None:
    """UserError unless the run in ``directory`` was started with ``config``'s settings."""
    saved = load_run_config(directory)
    differing = [name for name in SETTINGS_COMPARED if getattr(saved, name) != getattr(config, name)]
    if differing:
        raise UserError(f"{directory} was run with other settings ({', '.join(differing)}) than this grid; "
                        "repeat the options it was started with, or choose another --out")


def read_result(directory: Path) -> dict[str, Any]:
    """``result.json`` as a dict; empty when absent or unreadable (a run still before its first evaluation)."""
    try:
        data = json.loads((directory / "result.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


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


def group_jobs(grid: Grid, states: Mapping[str, RunState]) -> list[Job]:
    """One job per (cell, checkpoint step) of the unfinished runs, in the grid's order."""
    cells: dict[tuple[str, str, int], list[GridRun]] = {}
    for run in grid.runs:
        state = states[run.key]
        if state.status != "finished":
            cells.setdefault((run.task, run.row.slug, state.step), []).append(run)
    return [_job(grid, runs, step) for (_, _, step), runs in cells.items()]


def _job(grid: Grid, runs: Sequence[GridRun], step: int) -> Job:
    first = runs[0]
    seeds = tuple(run.seed for run in runs)
    log_file = grid.root / "logs" / f"{task_folder(first.task)}--{first.row.slug}--s{format_seeds(seeds)}.log"
    return Job(grid.spec.name, first.task, first.row.slug, grid.cell(first.task, first.row.slug),
               dataclasses.replace(first.config, seeds=seeds), step, log_file)


def split_job(job: Job, parts: int) -> list[Job]:
    """Cut a job's seeds into ``parts`` nearly equal jobs (same cell, same start step)."""
    seeds = job.seeds
    base, extra = divmod(len(seeds), max(1, min(parts, len(seeds))))
    jobs, start = [], 0
    for index in range(min(parts, len(seeds))):
        size = base + (index < extra)
        chunk, start = seeds[start:start + size], start + size
        log_file = job.log_file.with_name(f"{task_folder(job.task)}--{job.row}--s{format_seeds(chunk)}.log")
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


def seed_replay_bytes(task: str, config: RunConfig) -> int:
    """Memory of one seed's replay buffer when full: capacity × (2N + M + 2) float32 values."""
    from ..rl.tasks import PAPER_TASKS, make_env

    spec = PAPER_TASKS.get(task)
    if spec is not None:
        state_dim, action_dim = spec.state_dim, spec.action_dim
    else:
        env = make_env(task)
        state_dim, action_dim = int(env.observation_space.shape[0]), int(env.action_space.shape[0])
        env.close()
    return replay_bytes(state_dim, action_dim, min(config.td3.replay_size, config.steps))


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
    from ..rl.training import train

    started = time.perf_counter()
    job.log_file.parent.mkdir(parents=True, exist_ok=True)
    with open(job.log_file, "a", encoding="utf-8") as stream:
        def log(message: str) -> None:
            stream.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} {message}\n")
            stream.flush()

        log(f"job {job.name}: {job.config.steps} steps per seed, from step {job.start_step}")
        results: list[dict[str, Any]] = []
        try:
            for seeds in _seed_groups(job):
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


def _seed_groups(job: Job) -> list[tuple[int, ...]]:
    """The job's unfinished seeds grouped by checkpoint step (normally one group: all of them)."""
    groups: dict[int, list[int]] = {}
    for seed, directory in zip(job.seeds, job.directories, strict=True):
        state = run_state(directory, dataclasses.replace(job.config, seeds=(seed,)))
        if state.status != "finished":
            groups.setdefault(state.step, []).append(seed)
    return [tuple(seeds) for _, seeds in sorted(groups.items())]


def _local_worker_init() -> None:
    """Local workers ignore Ctrl-C between jobs; the coordinator interrupts running jobs itself."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _run_local_job(job: Job) -> JobOutcome:
    """:func:`run_job` with Ctrl-C (SIGINT) stopping the training, as in a terminal."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return run_job(job)
    finally:
        signal.signal(signal.SIGINT, previous)


# ------------------------------------------------------------------------------------------ backends
class Backend(Protocol):
    """Where jobs run. ``slots`` jobs run at once; handles are hashable."""

    slots: int

    def describe(self) -> str: ...

    def submit(self, job: Job) -> Any: ...

    def wait(self, handles: Sequence[Any], timeout: float) -> list[Any]: ...

    def outcome(self, handle: Any) -> JobOutcome: ...

    def interrupt(self, handles: Sequence[Any]) -> None: ...

    def close(self) -> None: ...


class LocalBackend:
    """A pool of spawned worker processes on this machine, one torch thread each."""

    def __init__(self, workers: int | None = None):
        self.slots = workers or os.cpu_count() or 1
        self.executor: concurrent.futures.ProcessPoolExecutor | None = None
        self.broken = False

    def describe(self) -> str:
        return f"local backend: {self.slots} worker process(es), one torch thread each"

    def _pool(self) -> concurrent.futures.ProcessPoolExecutor:
        if self.executor is None or self.broken:
            if self.executor is not None:
                self.executor.shutdown(wait=True, cancel_futures=True)
            self.executor = concurrent.futures.ProcessPoolExecutor(
                self.slots, mp_context=multiprocessing.get_context("spawn"), initializer=_local_worker_init)
            self.broken = False
        return self.executor

    def submit(self, job: Job) -> concurrent.futures.Future:
        return self._pool().submit(_run_local_job, job)

    def wait(self, handles: Sequence[Any], timeout: float) -> list[Any]:
        done, _ = concurrent.futures.wait(handles, timeout=timeout, return_when=concurrent.futures.FIRST_COMPLETED)
        return list(done)

    def outcome(self, handle: concurrent.futures.Future) -> JobOutcome:
        try:
            return handle.result()
        except BrokenProcessPool:
            self.broken = True
            return JobOutcome(error="the worker process died (killed, or out of memory)", crashed=True)
        except KeyboardInterrupt:
            return JobOutcome(error="interrupted")

    def interrupt(self, handles: Sequence[Any]) -> None:
        """Stop the running jobs as Ctrl-C would (each keeps its last checkpoint), then close the pool."""
        if self.executor is None:
            return
        processes = getattr(self.executor, "_processes", None) or {}  # no public way to reach the workers
        for process in list(processes.values()):
            with contextlib.suppress(OSError, ValueError):
                if process.pid is not None and process.is_alive():
                    os.kill(process.pid, signal.SIGINT)
        self.close()

    def close(self) -> None:
        if self.executor is not None:
            self.executor.shutdown(wait=True, cancel_futures=True)
            self.executor = None


def import_ray():
    """Ray, or a UserError saying how to install it."""
    try:
        import ray
    except ImportError:
        raise UserError(f"--backend ray needs Ray, which is not installed; install it with {RAY_INSTALL_HINT}") \
            from None
    return ray


class RayBackend:
    """One Ray task per job (``num_cpus=1``), retried by Ray when its worker or node dies."""

    def __init__(self, workers: int | None = None, address: str | None = None, dashboard: bool = False):
        ray = self.ray = import_ray()
        self.started_here = address is None
        if self.started_here:
            start_local_ray(workers or os.cpu_count() or 1, dashboard)
        else:
            try:
                ray.init(address=address, log_to_driver=False, logging_level=logging.WARNING)
            except (ConnectionError, ValueError, RuntimeError) as error:
                raise UserError(f"cannot join the Ray cluster at {address!r}: {error}") from None
        cpus = int(ray.cluster_resources().get("CPU", 0))
        self.slots = workers or max(1, cpus)
        self.where = "a local Ray (loopback only)" if self.started_here else f"the Ray cluster at {address}"
        self.cpus = cpus
        self.task = ray.remote(num_cpus=1, max_retries=RAY_MAX_RETRIES)(run_job)

    def describe(self) -> str:
        return (f"ray backend: {self.where}, {self.cpus} CPU(s), up to {self.slots} job(s) at once, "
                f"one CPU and one torch thread each, {RAY_MAX_RETRIES} retries")

    def submit(self, job: Job) -> Any:
        return self.task.remote(job)

    def wait(self, handles: Sequence[Any], timeout: float) -> list[Any]:
        ready, _ = self.ray.wait(list(handles), num_returns=1, timeout=timeout)
        if ready:
            ready, _ = self.ray.wait(list(handles), num_returns=len(handles), timeout=0)
        return ready

    def outcome(self, handle: Any) -> JobOutcome:
        try:
            return self.ray.get(handle)
        except self.ray.exceptions.RayError as error:
            first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
            return JobOutcome(error=f"Ray gave up on the job after {RAY_MAX_RETRIES} retries: {first[:300]}")

    def interrupt(self, handles: Sequence[Any]) -> None:
        """Cancel the running tasks (a KeyboardInterrupt in each: they keep their last checkpoint)."""
        for handle in handles:
            with contextlib.suppress(Exception):
                self.ray.cancel(handle)
        if handles and not self.started_here:
            with contextlib.suppress(Exception):
                self.ray.wait(list(handles), num_returns=len(handles), timeout=30)
        self.close()

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.ray.shutdown()


def start_local_ray(num_cpus: int, dashboard: bool = False) -> None:
    """Start a private single-machine Ray that listens on 127.0.0.1 only (never joins another cluster).

    In Ray 2.60 on Linux ``_node_ip_address="127.0.0.1"`` alone is turned into the machine's outward
    address and the servers listen there; Ray keeps a node on the loopback address only when its cluster
    mode is off (``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0``, the default on macOS and Windows), which is
    set here for the processes Ray starts and restored afterwards. ``address="local"`` makes sure a new
    instance is started, whatever ``RAY_ADDRESS`` says.
    """
    ray = import_ray()
    variable = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
    saved_env = os.environ.get(variable)
    constants = _ray_constants()
    saved_flag = getattr(constants, "ENABLE_RAY_CLUSTER", None)
    os.environ[variable] = "0"
    if saved_flag is not None:
        constants.ENABLE_RAY_CLUSTER = False  # read at import time; Ray may already be imported
    try:
        ray.init(address="local", num_cpus=num_cpus, include_dashboard=dashboard, dashboard_host="127.0.0.1",
                 _node_ip_address="127.0.0.1", log_to_driver=False, logging_level=logging.WARNING)
    finally:
        if saved_env is None:
            os.environ.pop(variable, None)
        else:
            os.environ[variable] = saved_env
        if saved_flag is not None:
            constants.ENABLE_RAY_CLUSTER = saved_flag


def _ray_constants():
    try:
        from ray._private import ray_constants
    except ImportError:  # a future Ray without this module: the node address is checked by the caller
        return None
    return ray_constants


def ray_node_address() -> str:
    """The address the connected Ray node listens on (127.0.0.1 for :func:`start_local_ray`)."""
    import ray

    return str(ray.util.get_node_ip_address())


def make_backend(name: str, workers: int | None = None, address: str | None = None,
                 dashboard: bool = False) -> Backend:
    if name == "local":
        if address:
            raise UserError("--address is for --backend ray; the local backend runs on this machine")
        return LocalBackend(workers)
    if name == "ray":
        return RayBackend(workers, address, dashboard)
    raise UserError(f"--backend {name!r} is not one of: local, ray")


# --------------------------------------------------------------------------------------- progress
@dataclass
class Progress:
    """Steps done over the whole grid, measured throughput and ETA (from ``result.json`` files)."""

    grid: Grid
    done: dict[str, int]
    started: float = field(default_factory=time.monotonic)
    start_done: int = 0

    @classmethod
    def start(cls, grid: Grid, states: Mapping[str, RunState]) -> Progress:
        done = {run.key: states[run.key].step for run in grid.runs}
        return cls(grid, done, start_done=sum(done.values()))

    def update(self, runs: Iterable[GridRun]) -> None:
        """Read the steps done of these runs from their ``result.json``."""
        for run in runs:
            steps = read_result(run.directory).get("steps_done")
            if isinstance(steps, int) and steps > self.done[run.key]:
                self.done[run.key] = min(steps, run.config.steps)

    @property
    def steps_done(self) -> int:
        return sum(self.done.values())

    @property
    def runs_finished(self) -> int:
        return sum(self.done[run.key] >= run.config.steps for run in self.grid.runs)

    def rate(self) -> float | None:
        """Seed-steps per second over the grid since this command started (None before a measurement)."""
        gained, elapsed = self.steps_done - self.start_done, time.monotonic() - self.started
        return gained / elapsed if gained > 0 and elapsed > 0 else None

    def line(self) -> str:
        total, done = self.grid.total_steps, self.steps_done
        runs = len(self.grid.runs)
        text = (f"progress: {self.runs_finished}/{runs} runs finished, {runs - self.runs_finished} left · "
                f"{_count(done)}/{_count(total)} steps")
        rate = self.rate()
        if rate is None:
            return text + " · ETA after the first evaluations"
        return text + f" · {rate:.0f} steps/s · ETA {format_duration((total - done) / rate)}"


def _count(steps: int) -> str:
    for size, unit in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if steps >= size:
            return f"{steps / size:.3g}{unit}"
    return str(steps)


def format_duration(seconds: float) -> str:
    """3725 → '1h 02m'; 200000 → '2d 07h'."""
    seconds = max(0, int(round(seconds)))
    days, rest = divmod(seconds, 86_400)
    hours, rest = divmod(rest, 3600)
    minutes, secs = divmod(rest, 60)
    if days:
        return f"{days}d {hours:02d}h"
    if hours:
        return f"{hours}h {minutes:02d}m"
    if minutes:
        return f"{minutes}m {secs:02d}s"
    return f"{secs}s"


# ------------------------------------------------------------------------------------ the coordinator
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


EventHook = Callable[[str, "Job | None"], None]


def run_grid(grid: Grid, backend: str | Backend = "local", workers: int | None = None, address: str | None = None,
             dashboard: bool = False, log: Callable[[str], None] = print, on_event: EventHook | None = None,
             poll_seconds: float = POLL_SECONDS, heartbeat_seconds: float = HEARTBEAT_SECONDS,
             write_report: bool = True) -> GridSummary:
    """Run every unfinished run of ``grid`` on ``backend`` and write the report; see the module docstring.

    ``on_event(kind, job)`` is called on ``start``, ``finish`` and ``fail`` of each job (a hook for
    tests and tools). Ctrl-C stops the running jobs, each keeping its last checkpoint.
    """
    started = time.monotonic()
    states = {run.key: run_state(run.directory, run.config) for run in grid.runs}
    skipped = sum(state.status == "finished" for state in states.values())
    log(f"ilcsan reproduce {grid.spec.name}: {len(grid.spec.tasks)} task(s) × {len(grid.spec.rows)} row(s) × "
        f"{len(grid.seeds)} seed(s) = {len(grid.runs)} runs of {grid.spec.steps} steps in {grid.root}")
    _log_states(grid, states, log)
    jobs = group_jobs(grid, states)
    summary = dict(runs=len(grid.runs), skipped=skipped, failed=(), interrupted=False, diverged=False)
    if not jobs:
        log("every run is finished; nothing to train")
        return _finish(grid, summary, 0, started, write_report, log)
    executor = make_backend(backend, workers, address, dashboard) if isinstance(backend, str) else backend
    progress = Progress.start(grid, states)
    try:
        outcome = _drive(grid, executor, jobs, progress, log, on_event, poll_seconds, heartbeat_seconds)
    finally:
        executor.close()
    summary.update(outcome)
    finished = progress.runs_finished - skipped
    if summary["interrupted"]:
        log(f"interrupted: {finished} run(s) finished in this call, the others keep their last checkpoint; "
            "run the same command again to continue")
        return GridSummary(**summary, finished=finished, report=None, wall_seconds=time.monotonic() - started)
    return _finish(grid, summary, finished, started, write_report, log)


def _log_states(grid: Grid, states: Mapping[str, RunState], log: Callable[[str], None]) -> None:
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


def _drive(grid: Grid, backend: Backend, jobs: list[Job], progress: Progress, log: Callable[[str], None],
           on_event: EventHook | None, poll_seconds: float, heartbeat_seconds: float) -> dict[str, Any]:
    """Keep ``backend.slots`` jobs running until all are done; returns the summary's failure fields."""
    limit = max_seeds_per_job(grid, backend.slots)
    queue = collections.deque(balance_jobs(jobs, backend.slots, limit))
    total_jobs = len(queue)
    log(f"{backend.describe()}; {total_jobs} job(s): the seeds of a (task, row) train together in one process"
        + (f" (at most {limit} per process, for memory)" if limit is not None and limit < len(grid.seeds) else ""))
    log(f"worker logs: {grid.root / 'logs'}")
    if isinstance(backend, LocalBackend) and backend.slots > (os.cpu_count() or 1):
        log(f"warning: {backend.slots} workers on {os.cpu_count()} cores; the processes will slow each other down")
    log(progress.line())
    running: dict[Any, Job] = {}
    attempts: collections.Counter[Job] = collections.Counter()
    failed: list[tuple[str, str]] = []
    diverged, started_jobs, last_line = False, 0, time.monotonic()
    runs_of = {run.key: run for run in grid.runs}
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
                progress.update(runs_of[_key(job, seed)] for seed in job.seeds)
                if outcome.crashed and attempts[job] < LOCAL_RETRIES:
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
            progress.update(runs_of[_key(job, seed)] for job in running.values() for seed in job.seeds)
            if time.monotonic() - last_line >= heartbeat_seconds:
                log(progress.line())
                last_line = time.monotonic()
    except KeyboardInterrupt:
        log(f"stopping {len(running)} running job(s); each keeps its last checkpoint ...")
        backend.interrupt(list(running))
        return {"failed": tuple(failed), "interrupted": True, "diverged": diverged}
    return {"failed": tuple(failed), "interrupted": False, "diverged": diverged}


def _key(job: Job, seed: int) -> str:
    return f"{job.task}/{job.row}/seed{seed}"


def _emit(on_event: EventHook | None, kind: str, job: Job | None) -> None:
    if on_event is not None:
        on_event(kind, job)


def _scores(outcome: JobOutcome) -> str:
    bests = [result["best_return"] for result in outcome.results if result.get("best_return") is not None]
    if not bests:
        return "no evaluation"
    mean = sum(bests) / len(bests)
    std = math.sqrt(sum((value - mean) ** 2 for value in bests) / len(bests))
    return f"best {mean:.1f}" + (f" ± {std:.1f} over {len(bests)} seeds" if len(bests) > 1 else "")


def _finish(grid: Grid, summary: dict[str, Any], finished: int, started: float, write: bool,
            log: Callable[[str], None]) -> GridSummary:
    report = None
    if write:
        from ..analysis.report import write_report

        report = write_report(grid.out, grid.root, grid.report_table)
        log(f"report: {report['markdown']} (also .tex, .csv) · learning curves: {report['curves']}")
    for name, reason in summary["failed"]:
        log(f"failed: {name}: {reason}")
    return GridSummary(**summary, finished=finished, report=report, wall_seconds=time.monotonic() - started)


# ----------------------------------------------------------------------------- estimates and listing
def steps_per_second_default() -> float:
    """The steps/s figure for estimates: ``ILCSAN_STEPS_PER_SECOND`` if set, else the documented default."""
    text = os.environ.get(STEPS_PER_SECOND_ENV)
    if not text:
        return DEFAULT_STEPS_PER_SECOND
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (math.isfinite(value) and value > 0):
        raise UserError(f"{STEPS_PER_SECOND_ENV}={text!r} must be a positive number of steps per second")
    return value


def estimate_hours(table: str | TableSpec, steps_per_second: float, cores: int) -> float:
    """Wall-clock hours to run a whole table on ``cores`` cores, one run per core at a time.

    Each run takes ``steps / steps_per_second`` seconds (``steps_per_second`` measured for one run on one
    core, evaluations included); the runs go in waves of ``cores``: ceil(runs / cores) waves. Training the
    seeds of a cell together (as ``reproduce`` does) is faster in aggregate, so this is an upper estimate
    for that part, while the tasks larger than Hopper (Ant, Humanoid) are slower than the measured run.
    """
    spec = TABLES[table] if isinstance(table, str) else table
    if steps_per_second <= 0 or cores < 1:
        raise ValueError("steps_per_second must be positive and cores at least 1")
    runs = len(spec.runs())
    waves = math.ceil(runs / cores)
    return waves * spec.steps / steps_per_second / 3600


def _switches(row: RowSpec) -> str:
    if not row.runnable:
        return "(the paper's numbers only; no code exists)"
    return " ".join(f"{key}={value}" for key, value in row.actor().items())


def describe_table(spec: TableSpec, steps_per_second: float, cores: int) -> str:
    """Caption, tasks, rows with their actor switches, protocol, run count and time estimates."""
    runs = len(spec.runs())
    width = max(len(row.slug) for row in spec.rows)
    label_width = max(len(row.label) for row in spec.rows)
    lines = [f"{spec.name}: {spec.caption}",
             f"  tasks ({len(spec.tasks)}): {', '.join(spec.tasks)}",
             f"  rows ({len(spec.runnable_rows)} to run):"]
    lines += [f"    {row.slug:<{width}}  {row.label:<{label_width}}  {_switches(row)}" for row in spec.rows]
    lines.append(f"  protocol: {spec.seeds} seeds × {spec.steps:,} steps, {spec.eval_episodes} deterministic "
                 f"episodes every {spec.eval_every:,} steps; a run's score is its best evaluation")
    lines.append(f"  runs: {len(spec.tasks)} tasks × {len(spec.runnable_rows)} rows × {spec.seeds} seeds = {runs} "
                 f"({runs * spec.steps:,} steps)")
    here = estimate_hours(spec, steps_per_second, cores)
    cluster = estimate_hours(spec, steps_per_second, EXAMPLE_CLUSTER_CORES)
    lines.append(f"  estimate: {_hours(here)} on this machine ({cores} cores), {_hours(cluster)} on "
                 f"{EXAMPLE_CLUSTER_CORES} cores")
    return "\n".join(lines)


def _hours(hours: float) -> str:
    return f"≈ {hours:,.0f} h ({hours / 24:,.1f} days)" if hours >= 48 else f"≈ {hours:,.1f} h"


def list_tables(specs: Iterable[TableSpec] | None = None, steps_per_second: float | None = None,
                cores: int | None = None) -> str:
    """The text of ``ilcsan reproduce --list``."""
    speed = steps_per_second_default() if steps_per_second is None else steps_per_second
    cores = cores or os.cpu_count() or 1
    blocks = [describe_table(spec, speed, cores) for spec in (specs or TABLES.values())]
    footer = (f"Estimates assume {speed:g} steps/s per run on one core (ILC-SAN on Hopper, one torch thread, "
              f"evaluations included; set {STEPS_PER_SECOND_ENV} to your own measurement) and one run per core; "
              "hours = ceil(runs / cores) × steps / (steps/s) / 3600. Shrink a table with --seeds, --steps, "
              "--tasks, --rows; run it on a cluster with --backend ray --address HOST:PORT.")
    return "\n\n".join([*blocks, footer])


__all__ = [
    "GridOptions", "GridRun", "Grid", "RunState", "Job", "JobOutcome", "GridSummary", "LocalBackend", "RayBackend",
    "resolve_table", "expand_grid", "run_state", "group_jobs", "balance_jobs", "split_job", "run_job", "run_grid",
    "make_backend", "start_local_ray", "estimate_hours", "describe_table", "list_tables",
    "DEFAULT_STEPS_PER_SECOND",
]
