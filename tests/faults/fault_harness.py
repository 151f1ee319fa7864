"""Fault injection for training runs: ``kill -9`` a real ``ilcsan train`` process, resume it, compare.

Used by the quick CI subset (``tests/faults/test_kill_resume.py``) and the full script
(``benchmarks/faults.py``). A trial:

1. starts ``python -m ilcsan.cli train ... --out DIR`` (a tiny Pendulum run) in a subprocess;
2. kills it with SIGKILL at a :class:`KillPoint`: after a given time (:class:`At`), or while the n-th
   temporary file of an atomic write matching a pattern exists (:class:`During`; the child runs with
   ``ILCSAN_FAULT_DELAY_WRITE`` so every atomic write pauses halfway through its data, leaving a
   half-written temporary file in place for the kill);
3. inspects what the kill left (:func:`inspect_run`): every ``checkpoint.pt`` / ``policy.pt`` must load
   with :func:`ilcsan.files.safe_torch_load`, and no checkpoint may be older than the last evaluation the
   process reported on stdout (that would be data lost);
4. runs ``train ... --resume`` to the end (possibly killing it again) and compares each seed's
   ``metrics.csv`` column ``eval_return_mean`` with an uninterrupted run of the same seed on the same matmul
   path, as text: exact equality.

A run measures at its start which float32 matmul path is faster and keeps it when resumed; two runs that
measured differently round differently, so the uninterrupted run a trial is compared with is one on the path
the trial recorded in its config.json (``--matmul aten`` or ``onednn``, :class:`References`).
"""

from __future__ import annotations

import csv
import dataclasses
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

PYTHON = sys.executable
EVAL_LINE = re.compile(r"\] step (\d+): eval return")


@dataclass(frozen=True)
class RunSpec:
    """A tiny training run (Pendulum, 16-wide hidden layers, one thread)."""

    steps: int = 450
    eval_every: int = 150
    seeds: str = "0"
    start_steps: int = 100
    update_after: int = 100
    task: str = "Pendulum-v1"
    matmul: str = "float32"

    @property
    def seed_list(self) -> list[int]:
        return [int(seed) for seed in self.seeds.split(",")]

    def argv(self, out: Path, resume: bool = False) -> list[str]:
        argv = [PYTHON, "-m", "ilcsan.cli", "train", "--task", self.task, "--seeds", self.seeds,
                "--steps", str(self.steps), "--eval-every", str(self.eval_every), "--eval-episodes", "1",
                "--start-steps", str(self.start_steps), "--update-after", str(self.update_after),
                "--update-every", "25", "--batch-size", "16", "--hidden-width", "16", "--threads", "1",
                "--matmul", self.matmul, "--no-progress", "--out", str(out)]
        return [*argv, "--resume"] if resume else argv

    def directories(self, out: Path) -> list[Path]:
        seeds = self.seed_list
        return [Path(out)] if len(seeds) == 1 else [Path(out) / f"seed{seed}" for seed in seeds]

    @property
    def evaluation_steps(self) -> list[int]:
        steps = list(range(self.eval_every, self.steps + 1, self.eval_every))
        return steps if steps[-1] == self.steps else [*steps, self.steps]


@dataclass(frozen=True)
class At:
    """Kill after the process has run this many seconds (start-up included)."""

    seconds: float

    def describe(self) -> str:
        return f"at {self.seconds:.2f} s"


@dataclass(frozen=True)
class During:
    """Kill while the ``occurrence``-th temporary file matching ``pattern`` (a glob below OUT) exists."""

    pattern: str
    occurrence: int = 1
    delay: float = 0.4

    def describe(self) -> str:
        return f"during write #{self.occurrence} of {self.pattern}"


@dataclass(frozen=True)
class After:
    """Kill ``seconds`` after a file matching ``pattern`` (a glob below OUT) first appears."""

    pattern: str
    seconds: float

    def describe(self) -> str:
        return f"{self.seconds:.2f} s after {self.pattern} appeared"


KillPoint = At | During | After


@dataclass
class Attempt:
    """One process run: was it killed, how it ended, what it printed."""

    killed: bool
    returncode: int
    elapsed: float
    stdout: str
    stderr: str

    @property
    def reported_steps(self) -> list[int]:
        """Evaluations the process reported (each is printed after its checkpoint is written)."""
        return [int(match) for match in EVAL_LINE.findall(self.stdout)]


def child_environment(delay: float | None = None) -> dict[str, str]:
    env = dict(os.environ)
    env.update(PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", MPLBACKEND="Agg")
    env.pop("ILCSAN_FAULT_DELAY_WRITE", None)
    if delay:
        env["ILCSAN_FAULT_DELAY_WRITE"] = str(delay)
    return env


def run(argv: list[str], point: KillPoint | None = None, out: Path | None = None,
        timeout: float = 300.0, kill_group: bool = False) -> Attempt:
    """Run ``argv``; with a kill point, SIGKILL it there (if it has not finished by then): the process, or
    with ``kill_group`` its whole process group (the process started here and the workers it started)."""
    delay = point.delay if isinstance(point, During) else None
    start = time.monotonic()
    process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env=child_environment(delay), start_new_session=True)
    killed, seen, appeared = False, set(), None
    try:
        while process.poll() is None:
            elapsed = time.monotonic() - start
            if elapsed > timeout:
                raise TimeoutError(f"{argv} did not finish in {timeout} s")
            if isinstance(point, At) and elapsed >= point.seconds:
                killed = _kill(process, kill_group)
            elif isinstance(point, During):
                seen.update(path.name for path in Path(out).glob(point.pattern))
                if len(seen) >= point.occurrence:
                    killed = _kill(process, kill_group)
            elif isinstance(point, After):
                if appeared is None and any(Path(out).glob(point.pattern)):
                    appeared = time.monotonic()
                if appeared is not None and time.monotonic() - appeared >= point.seconds:
                    killed = _kill(process, kill_group)
            time.sleep(0.002 if isinstance(point, During) else 0.005)
        stdout, stderr = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            _kill(process, kill_group)
            process.communicate()
    return Attempt(killed, process.returncode, time.monotonic() - start, stdout, stderr)


def _run_in_process(argv: list[str]) -> Attempt:
    import contextlib
    import io

    from ilcsan.cli import main

    stdout, stderr = io.StringIO(), io.StringIO()
    start = time.monotonic()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(argv[3:])
    return Attempt(False, code, time.monotonic() - start, stdout.getvalue(), stderr.getvalue())


def _kill(process: subprocess.Popen, group: bool = False) -> bool:
    """SIGKILL the process we started (by its id), or the process group it leads (it was started in a new
    session, so the group holds only it and its children); True if it was still running."""
    if process.poll() is not None:
        return False
    if group:
        os.killpg(process.pid, signal.SIGKILL)
    else:
        os.kill(process.pid, signal.SIGKILL)
    process.wait()
    return True


def curve(directory: Path) -> list[str]:
    """The ``eval_return_mean`` column of a run's metrics.csv, as written (text, for exact comparison)."""
    path = Path(directory) / "metrics.csv"
    if not path.is_file():
        return []
    with open(path, newline="") as stream:
        return [row["eval_return_mean"] for row in csv.DictReader(stream)]


def curves(spec: RunSpec, out: Path) -> dict[int, list[str]]:
    return {seed: curve(directory) for seed, directory in zip(spec.seed_list, spec.directories(out), strict=True)}


def matmul_path_of(directory: Path) -> str:
    """The matmul path a run computed on (``matmul_path`` in its config.json: ``aten``, ``onednn`` or ``bf16``)."""
    from ilcsan.runs.directory import RunDirectory

    return RunDirectory(directory).matmul_choice()["path"]


class References:
    """Uninterrupted runs of one spec, one per matmul path, each made when a trial first needs it: ``references(path)``
    is each seed's curve of ``spec`` run with ``--matmul path``, in this process (:func:`reference_in_process`) or
    with ``processes`` as a separate one (:func:`reference_run`)."""

    def __init__(self, spec: RunSpec, folder: Path, processes: bool = False):
        self.spec, self.folder, self.processes = spec, Path(folder), processes
        self.curves: dict[str, dict[int, list[str]]] = {}

    def measured(self) -> tuple[str, float]:
        """Run the spec as a user would (the path measured at the start, a separate process); its path and wall time."""
        out = self.folder / "measured"
        result, seconds = reference_run(self.spec, out)
        path = matmul_path_of(self.spec.directories(out)[0])
        self.curves[path] = result
        return path, seconds

    def __call__(self, path: str) -> dict[int, list[str]]:
        if path not in self.curves:
            spec, out = dataclasses.replace(self.spec, matmul=path), self.folder / path
            self.curves[path] = reference_run(spec, out)[0] if self.processes else reference_in_process(spec, out)
        return self.curves[path]


@dataclass
class Inspection:
    """What a killed run left on disk."""

    checkpoint_steps: list[int | None] = field(default_factory=list)  # per seed; None: no checkpoint yet
    corrupt: list[str] = field(default_factory=list)  # files that exist but do not load
    lost: list[str] = field(default_factory=list)  # evaluations reported but not on disk
    temporary_files: int = 0


def inspect_run(spec: RunSpec, out: Path, attempt: Attempt) -> Inspection:
    """Every checkpoint.pt / policy.pt loads; no checkpoint is older than the last reported evaluation."""
    from ilcsan.errors import UserError
    from ilcsan.files import safe_torch_load

    report = Inspection()
    reported = max(attempt.reported_steps, default=0)
    for directory in spec.directories(out):
        step = None
        for name in ("checkpoint.pt", "checkpoint.next.pt", "policy.pt"):
            path = directory / name
            if not path.exists():
                continue
            try:
                data = safe_torch_load(path)
            except UserError as error:
                report.corrupt.append(f"{path}: {error}")
                continue
            if name == "checkpoint.pt":
                step = int(data["step"])
        report.checkpoint_steps.append(step)
        if reported and (step is None or step < reported) and not _pending_covers(directory, reported):
            report.lost.append(f"{directory}: evaluation at step {reported} was reported, checkpoint is at {step}")
        report.temporary_files += len(list(directory.rglob("*.tmp")))
    return report


def _pending_covers(directory: Path, step: int) -> bool:
    """A complete pending checkpoint (two-phase commit of multi-seed runs) at ``step`` is not lost."""
    from ilcsan.errors import UserError
    from ilcsan.files import safe_torch_load

    path = directory / "checkpoint.next.pt"
    try:
        return path.exists() and int(safe_torch_load(path)["step"]) >= step
    except UserError:
        return False


def leftovers(spec: RunSpec, out: Path) -> list[str]:
    """After a finished resume: temporary files, or replay segments no checkpoint refers to."""
    from ilcsan.files import safe_torch_load

    found = []
    for directory in spec.directories(out):
        found += [str(path) for path in directory.rglob("*.tmp")]
        found += [str(path) for path in directory.glob("checkpoint.next.pt")]
        referenced = set(safe_torch_load(directory / "checkpoint.pt")["replay"]["segments"])
        found += [str(path) for path in (directory / "replay").glob("*.npz") if path.name not in referenced]
    return found


@dataclass
class TrialResult:
    """One kill trial: the kills made, what they left, and whether resume reproduced the straight run."""

    name: str
    kills: int = 0
    kill_points: list[str] = field(default_factory=list)
    checkpoint_steps: list[list[int | None]] = field(default_factory=list)
    corrupt: list[str] = field(default_factory=list)
    lost: list[str] = field(default_factory=list)
    resume_codes: list[int] = field(default_factory=list)
    resume_errors: list[str] = field(default_factory=list)
    curves_equal: bool = False
    leftovers: list[str] = field(default_factory=list)
    matmul_path: str | None = None
    seconds: float = 0.0

    @property
    def survived(self) -> bool:
        """Every resume succeeded and the final curve equals the straight run's."""
        return all(code == 0 for code in self.resume_codes) and self.curves_equal


def kill_and_resume(spec: RunSpec, out: Path, points: list[KillPoint],
                    reference: Callable[[str], dict[int, list[str]]], name: str = "trial",
                    final_in_process: bool = False) -> TrialResult:
    """Start a run, kill it at ``points[0]``, resume and kill at the next point, ..., then resume to the end
    (in a new process, or with ``final_in_process`` through :func:`ilcsan.cli.main` here, which is faster), and
    compare its curves with ``reference(path)`` (:class:`References`) for the matmul path the run recorded."""
    result = TrialResult(name)
    start = time.monotonic()
    for index, point in enumerate(points):
        attempt = run(spec.argv(out, resume=index > 0), point, out)
        if index > 0:
            result.resume_codes.append(attempt.returncode if not attempt.killed else 0)
            if not attempt.killed and attempt.returncode != 0:
                result.resume_errors.append(attempt.stderr.strip()[-500:])
        if not attempt.killed:
            result.kill_points.append(f"{point.describe()} (finished first)")
            continue
        result.kills += 1
        result.kill_points.append(point.describe())
        inspection = inspect_run(spec, out, attempt)
        result.checkpoint_steps.append(inspection.checkpoint_steps)
        result.corrupt += inspection.corrupt
        result.lost += inspection.lost
    final = _run_in_process(spec.argv(out, resume=True)) if final_in_process else run(spec.argv(out, resume=True))
    result.resume_codes.append(final.returncode)
    if final.returncode != 0:
        result.resume_errors.append(final.stderr.strip()[-500:])
    else:
        result.leftovers = leftovers(spec, out)
        result.matmul_path = matmul_path_of(spec.directories(out)[0])
        result.curves_equal = curves(spec, out) == reference(result.matmul_path)
    result.seconds = time.monotonic() - start
    return result


def reference_run(spec: RunSpec, out: Path) -> tuple[dict[int, list[str]], float]:
    """An uninterrupted run of ``spec``: each seed's curve and the wall time of the whole process."""
    attempt = run(spec.argv(out))
    if attempt.returncode != 0:
        raise RuntimeError(f"the reference run failed: {attempt.stderr[-2000:]}")
    result = curves(spec, out)
    expected = len(spec.evaluation_steps)
    if any(len(values) != expected for values in result.values()):
        raise RuntimeError(f"the reference run has {result} evaluations, expected {expected} per seed")
    return result, attempt.elapsed


def reference_in_process(spec: RunSpec, out: Path) -> dict[int, list[str]]:
    """The uninterrupted run through :func:`ilcsan.cli.main` in this process (saves a start-up)."""
    import contextlib
    import io

    from ilcsan.cli import main

    with contextlib.redirect_stdout(io.StringIO()):
        code = main(spec.argv(out)[3:])
    if code != 0:
        raise RuntimeError(f"the reference run failed with exit code {code}")
    return curves(spec, out)


# ------------------------------------------------------------------------------------------------
# Grids: `ilcsan reproduce GRID.toml` killed with its worker processes, then run again

GRID_TOML = """\
name = "faults"
caption = "fault injection"
tasks = ["Pendulum-v1"]
seeds = {seeds}
steps = {steps}
eval_every = {eval_every}
eval_episodes = 1

[[rows]]
slug = "ilc"
preset = "ilc-san"
overrides = {{ hidden_width = 16 }}
{extra_rows}"""
EXTRA_ROW = """
[[rows]]
slug = "pop"
preset = "popsan"
overrides = { hidden_width = 16 }
"""


@dataclass(frozen=True)
class GridSpec:
    """A tiny grid: Pendulum, ILC-SAN (and PopSAN) 16 wide, a few seeds; TD3 updates start at step 1000."""

    seeds: int = 2
    steps: int = 1100
    eval_every: int = 550
    rows: int = 1
    workers: int = 1
    start_steps: int = 100

    def write(self, folder: Path) -> Path:
        path = Path(folder) / "faults.toml"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(GRID_TOML.format(seeds=self.seeds, steps=self.steps, eval_every=self.eval_every,
                                         extra_rows=EXTRA_ROW if self.rows > 1 else ""))
        return path

    def argv(self, grid_file: Path, out: Path) -> list[str]:
        return [PYTHON, "-m", "ilcsan.cli", "reproduce", str(grid_file), "--out", str(out), "--workers",
                str(self.workers), "--start-steps", str(self.start_steps)]


def grid_curves(out: Path) -> dict[str, list[str]]:
    """Every run of a grid folder (found by its config.json): its curve, by path relative to ``out``."""
    return {str(path.parent.relative_to(out)): curve(path.parent) for path in sorted(Path(out).rglob("config.json"))}


def grid_paths(out: Path) -> dict[str, str]:
    """Every run of a grid folder: the matmul path it computed on, by path relative to ``out``."""
    return {str(path.parent.relative_to(out)): matmul_path_of(path.parent)
            for path in sorted(Path(out).rglob("config.json"))}


def grid_reference_in_process(out: Path, workers: int = 1) -> dict[str, list[str]]:
    """The straight run of every cell of a finished grid, trained here as the local backend does with one
    worker: all seeds of a cell stacked in one process, on the matmul path they recorded (from the runs' own
    config.json)."""
    from ilcsan.config import RunConfig
    from ilcsan.rl.training import load_run_config, train

    if workers != 1:
        raise ValueError("the in-process reference mirrors one worker (one job per cell, all seeds stacked)")
    reference: dict[str, list[str]] = {}
    cells: dict[tuple[Path, str], list[int]] = {}
    for path in sorted(Path(out).rglob("config.json")):
        cell = (path.parent.parent, matmul_path_of(path.parent))
        cells.setdefault(cell, []).append(load_run_config(path.parent).seeds[0])
    for index, ((cell, matmul), seeds) in enumerate(sorted(cells.items())):
        config = load_run_config(cell / f"seed{seeds[0]}")
        target = Path(out).parent / f"{Path(out).name}-reference" / str(index)
        stacked = RunConfig(task=config.task, seeds=tuple(seeds), steps=config.steps, eval_every=config.eval_every,
                            eval_episodes=config.eval_episodes, actor=config.actor, training=config.training,
                            matmul=matmul, threads=1)
        train(stacked, target, progress=False, log=lambda *_: None)
        for seed in seeds:
            reference[str((cell / f"seed{seed}").relative_to(out))] = curve(target / f"seed{seed}")
    return reference


def kill_grid_and_rerun(spec: GridSpec, folder: Path, points: list[KillPoint],
                        final_in_process: bool = False) -> dict:
    """Run the grid, SIGKILL it (with its workers: the whole process group) at each point, then run it again
    to the end. Returns the kills made, what they left, and the last run's exit code and curves."""
    from ilcsan.errors import UserError
    from ilcsan.files import safe_torch_load

    grid_file, out = spec.write(folder), Path(folder) / "out"
    report = {"kills": 0, "kill_points": [], "corrupt": [], "codes": [], "errors": []}
    for point in points:
        attempt = run(spec.argv(grid_file, out), point, out, kill_group=True)
        if not attempt.killed:
            report["kill_points"].append(f"{point.describe()} (finished first)")
            continue
        report["kills"] += 1
        report["kill_points"].append(point.describe())
        for path in list(out.rglob("checkpoint.pt")) + list(out.rglob("policy.pt")):
            try:
                safe_torch_load(path)
            except UserError as error:
                report["corrupt"].append(str(error))
    argv = spec.argv(grid_file, out)
    final = _run_in_process(argv) if final_in_process else run(argv)
    report["codes"].append(final.returncode)
    if final.returncode != 0:
        report["errors"].append((final.stderr or final.stdout)[-1000:])
    report["curves"] = grid_curves(out)
    report["leftovers"] = [str(path) for path in out.rglob("*.tmp")]
    return report
