"""Where jobs run: a pool of local worker processes, or a Ray cluster.

``local`` (default)  a pool of ``--workers`` processes (default: the number of cores), started with
                     ``spawn``, each training one job at a time with **one** torch thread (processes
                     whose threads fight over the cores run many times slower). A worker process that
                     dies (e.g. killed for memory) is replaced and its job resumed from its checkpoint,
                     up to :data:`~ilcsan.experiments.coordinator.CRASH_RETRIES` times. On Linux a worker
                     ends with its coordinator, however that dies (even ``kill -9``), instead of training
                     on, orphaned. Stopped (Ctrl-C, ``kill``), each job ends at its last checkpoint; a
                     worker whose job still runs :data:`INTERRUPT_GRACE_SECONDS` later is killed (it
                     resumes from that checkpoint).
``ray``              one Ray task per job with ``num_cpus=1``; Ray retries a task whose worker or node
                     dies (``max_retries``), and the retry resumes from the checkpoint. Without
                     ``--address`` a private single-machine Ray is started, listening on the loopback
                     interface only, dashboard off; ``--address HOST:PORT`` (or ``auto``) joins an
                     existing cluster, with Ray's token when this machine has one (:mod:`.ray_cluster`).
                     On a cluster of several machines, ``OUT`` must be on storage shared by every node
                     under the same path (NFS, a cluster file system) and ``ilcsan`` installed on every
                     node. Install Ray with ``pip install "ilcsan[ray]"``.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Protocol

from ..config import BACKENDS as BACKEND_CHOICES
from ..errors import UserError
from .jobs import Job, JobOutcome, run_job
from .ray_cluster import import_ray, join_ray_cluster, start_local_ray

RAY_MAX_RETRIES = 3
INTERRUPT_GRACE_SECONDS = 30.0
"""How long a local job has, after Ctrl-C, to stop at its last checkpoint before its worker process is killed."""
INTERRUPT_REPEAT_SECONDS = 10.0
"""How often Ctrl-C is sent again, within the grace, to a worker whose job still runs."""


PR_SET_PDEATHSIG = 1
"""Linux ``prctl`` option: the signal this process gets when the thread that started it ends."""


def _prepare_worker(coordinator_pid: int) -> None:
    """Local workers ignore Ctrl-C between jobs (the coordinator interrupts running jobs itself) and, on Linux,
    get SIGTERM when the coordinator dies, even by SIGKILL where no handler of its own runs. Checkpoints are
    written atomically, so a job ended this way resumes from its last one."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if not sys.platform.startswith("linux"):
        return
    ctypes.CDLL(None).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() != coordinator_pid:  # the coordinator died before the request took effect
        os.kill(os.getpid(), signal.SIGTERM)


def _run_job_stopped_by_ctrl_c(job: Job) -> JobOutcome:
    """:func:`run_job` with Ctrl-C (SIGINT) stopping the training, as in a terminal."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return run_job(job)
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def termination_as_ctrl_c():
    """Within the block, SIGTERM (``kill``, a cluster scheduler's preemption) raises KeyboardInterrupt as Ctrl-C does,
    so the coordinator stops its running jobs at their last checkpoint instead of dying and leaving its workers to
    train on, orphaned. Outside the main thread (where no handler can be set) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


# ------------------------------------------------------------------------------------------ backends
class Backend(Protocol):
    """Where jobs run. ``slots`` jobs run at once; handles are hashable."""

    slots: int

    def describe(self) -> str: ...

    def submit(self, job: Job) -> Any: ...

    def wait(self, handles: Sequence[Any], timeout: float) -> list[Any]: ...

    def outcome(self, handle: Any) -> JobOutcome: ...

    def interrupt(self, handles: Sequence[Any]) -> list[str]:
        """Stop the running jobs at their last checkpoints and close; returns what the coordinator should log."""
        ...

    def close(self) -> None: ...


class LocalBackend:
    """A pool of spawned worker processes on this machine, one torch thread each. ``target(job)`` is what a worker
    runs for a job (a test can give one that ignores Ctrl-C); ``grace_seconds``: see :meth:`interrupt`."""

    def __init__(self, workers: int | None = None, grace_seconds: float = INTERRUPT_GRACE_SECONDS,
                 target: Callable[[Any], JobOutcome] | None = None):
        self.slots = workers or os.cpu_count() or 1
        self.grace_seconds = grace_seconds
        self.target = target or _run_job_stopped_by_ctrl_c
        self.executor: concurrent.futures.ProcessPoolExecutor | None = None
        self.broken = False

    def describe(self) -> str:
        return f"local backend: {self.slots} worker process(es), one torch thread each"

    def _pool(self) -> concurrent.futures.ProcessPoolExecutor:
        if self.executor is None or self.broken:
            if self.executor is not None:
                self.executor.shutdown(wait=True, cancel_futures=True)
            self.executor = concurrent.futures.ProcessPoolExecutor(
                self.slots, mp_context=multiprocessing.get_context("spawn"), initializer=_prepare_worker,
                initargs=(os.getpid(),))
            self.broken = False
        return self.executor

    def submit(self, job: Job) -> concurrent.futures.Future:
        return self._pool().submit(self.target, job)

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

    def interrupt(self, handles: Sequence[Any]) -> list[str]:
        """Stop the running jobs as Ctrl-C would (each keeps its last checkpoint), then close the pool.

        Ctrl-C (SIGINT) goes to every worker, again every :data:`INTERRUPT_REPEAT_SECONDS` while a job runs; a job
        still running ``grace_seconds`` after the first has its worker killed (SIGKILL), so that no worker ever trains
        on after its coordinator has stopped. Nothing more is lost that way than with Ctrl-C: checkpoints are written
        atomically, and the job resumes from its last one. Idle workers ignore Ctrl-C."""
        if self.executor is None:
            return []
        pending, notes = set(handles), []
        deadline = time.monotonic() + self.grace_seconds
        while pending and (left := deadline - time.monotonic()) > 0:
            self._signal_workers(signal.SIGINT)
            _, pending = concurrent.futures.wait(pending, timeout=min(left, INTERRUPT_REPEAT_SECONDS))
        if pending:
            killed = self._signal_workers(signal.SIGKILL)
            notes.append(f"{len(pending)} job(s) still running {self.grace_seconds:g} s after Ctrl-C: killed worker "
                         f"process(es) {', '.join(map(str, killed))}; each job resumes from its last checkpoint")
        self.close()
        return notes

    def _signal_workers(self, number: int) -> list[int]:
        """Send signal ``number`` to every live worker process of the pool; returns their process ids."""
        processes = getattr(self.executor, "_processes", None) or {}  # no public way to reach the workers
        signalled = []
        for process in list(processes.values()):
            with contextlib.suppress(OSError, ValueError):
                if process.pid is not None and process.is_alive():
                    os.kill(process.pid, number)
                    signalled.append(process.pid)
        return signalled

    def close(self) -> None:
        if self.executor is not None:
            self.executor.shutdown(wait=True, cancel_futures=True)
            self.executor = None


class RayBackend:
    """One Ray task per job (``num_cpus=1``), retried by Ray when its worker or node dies."""

    def __init__(self, workers: int | None = None, address: str | None = None, dashboard: bool = False):
        ray = self.ray = import_ray()
        self.started_here = address is None
        if self.started_here:
            start_local_ray(workers or os.cpu_count() or 1, dashboard)
            self.where = "a local Ray (loopback only)"
        else:
            self.where = join_ray_cluster(address)
        cpus = int(ray.cluster_resources().get("CPU", 0))
        self.slots = workers or max(1, cpus)
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

    def interrupt(self, handles: Sequence[Any]) -> list[str]:
        """Cancel the running tasks (a KeyboardInterrupt in each: they keep their last checkpoint)."""
        for handle in handles:
            with contextlib.suppress(Exception):
                self.ray.cancel(handle)
        if handles and not self.started_here:
            with contextlib.suppress(Exception):
                self.ray.wait(list(handles), num_returns=len(handles), timeout=30)
        self.close()
        return []

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.ray.shutdown()


BACKENDS: tuple[str, ...] = tuple(BACKEND_CHOICES)


def check_backend_options(name: str, address: str | None = None) -> None:
    """One line for a backend that cannot start: an unknown name, ``--address`` without Ray, Ray missing."""
    if name not in BACKENDS:
        raise UserError(f"--backend {name!r} is not one of: {', '.join(BACKENDS)}")
    if name == "ray":
        import_ray()
    elif address:
        raise UserError("--address is for --backend ray; the local backend runs on this machine")


def make_backend(name: str, workers: int | None = None, address: str | None = None,
                 dashboard: bool = False) -> Backend:
    """The backend of ``--backend NAME`` (:data:`BACKENDS`), or a UserError (:func:`check_backend_options`)."""
    check_backend_options(name, address)
    if name == "local":
        return LocalBackend(workers)
    return RayBackend(workers, address, dashboard)
