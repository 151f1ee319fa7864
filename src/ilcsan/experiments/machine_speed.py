"""This machine's speed at the paper's protocol, measured: the base of ``reproduce --list``'s estimates.

The estimates multiply each run's relative cost (:data:`ilcsan.experiments.estimate.ACTOR_STEP_COST`, ratios that hold
across machines) by the time of one step of one ILC-SAN seed on Hopper, which does not hold across machines. That
time is measured here, on the machine at hand, as ``benchmarks/task_cost.py`` measures every task: a fresh run of the
protocol's configuration (ILC-SAN, TD3, float32 on the matmul path the run itself chooses, one torch thread,
compiled), timed over training steps after a warm-up in which its update program compiles, plus one evaluation of
the protocol (:data:`PROTOCOL`: 10 deterministic episodes in lockstep every 10 000 steps) taken with every episode at
the task's time limit:

    protocol steps/s = E / (E × s_train + s_evaluation),   E = the steps between evaluations.

The random-action phase (cheaper) and episodes an untrained actor ends early are left out, so a real run is
somewhat faster; one run alone is measured, and with every core busy runs go somewhat slower (they share caches and
memory). The time is the process's CPU time, so that time spent waiting for a core another process holds does not
count; sharing the cores' caches still does, so a machine busy with other work measures lower (and the listing says
when the machine is busy): measure on an idle machine. The figure is kept in
a small JSON file (:func:`cache_path`) under a key naming the CPU, its cores and the versions of torch and ilcsan,
so that it is measured once per machine and software, not at every listing.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..files import atomic_write_text
from ..paper.layouts import TABLES

if TYPE_CHECKING:  # torch and the trainer are imported only when a measurement runs
    from ..config import RunConfig
    from ..rl.training import Trainer

PROTOCOL = TABLES["perf"]
"""The table whose protocol is measured (its evaluation interval and episodes)."""
BASE_PRESET, BASE_TASK = "ilc-san", "Hopper"
"""The run whose time per step the estimates' relative costs are measured against."""
WARMUP_STEPS, MEASURED_STEPS = 250, 500
"""Training steps untimed (the update program compiles in them) and timed."""
CACHE_FILE = "machine_speed.json"


Clock = Callable[[], float]
"""Seconds since some start: ``time.perf_counter`` (wall time, for a benchmark on an idle machine) or
``time.process_time`` (this process's CPU time, what a free core would take, on a machine that others share)."""


def seconds_per_call(function: Callable[[], Any], calls: int, warmup: int, clock: Clock = time.perf_counter) -> float:
    """Mean seconds of ``calls`` calls of ``function`` after ``warmup`` untimed ones, on ``clock``."""
    for _ in range(warmup):
        function()
    start = clock()
    for _ in range(calls):
        function()
    return (clock() - start) / calls


def seconds_per_training_step(config: RunConfig, warmup: int, steps: int,
                              then: Callable[[Trainer], Any] | None = None,
                              clock: Clock = time.perf_counter) -> tuple[float, Any]:
    """Seconds per training step of ``config`` (a fresh run in a temporary folder) over ``steps`` steps after
    ``warmup`` untimed ones, on ``clock``, and what ``then(trainer)`` returns after them (None without it)."""
    from ..rl.training import Trainer

    with tempfile.TemporaryDirectory() as folder:
        trainer = Trainer(config, Path(folder) / "run", progress=False, log=lambda *_: None)
        try:
            seconds = seconds_per_call(trainer.train_step, steps, warmup, clock)
            return seconds, then(trainer) if then is not None else None
        finally:
            trainer.close()


def evaluation_seconds(trainer: Trainer, lockstep_steps: int = 100, warmup: int = 20,
                       clock: Clock = time.perf_counter) -> tuple[float, int]:
    """Seconds of one evaluation with every episode at the task's time limit, and that limit: the time of
    ``lockstep_steps`` lockstep steps (one batched action, then each episode's environment step; an ended episode
    restarts so that every step steps all of them), scaled to the limit, plus one pass of the actor diagnostics;
    each after ``warmup`` untimed calls (the acting pass compiles for the evaluation's shape on its first), on
    ``clock``."""
    import numpy as np

    from ..rl.evaluation import replay_diagnostics

    envs = trainer.eval_envs[0]
    limit = envs[0].spec.max_episode_steps
    observations = np.stack([env.reset(seed=index)[0] for index, env in enumerate(envs)])[None]

    def lockstep() -> None:
        actions = trainer._act(observations)
        for index, env in enumerate(envs):
            observation, _, terminated, truncated, _ = env.step(actions[0, index])
            observations[0, index] = env.reset()[0] if terminated or truncated else observation

    def diagnostics() -> None:
        replay_diagnostics(trainer.agent, trainer.replay, trainer.normalizer, trainer.config.seeds, trainer.step)

    per_step = seconds_per_call(lockstep, lockstep_steps, warmup, clock)
    return limit * per_step + seconds_per_call(diagnostics, 3, 1, clock), limit


def protocol_speed(train_seconds: float, evaluation: float, eval_every: int = PROTOCOL.eval_every) -> float:
    """Steps/s of the protocol after the random phase, evaluations included (the module docstring's formula)."""
    return eval_every / (eval_every * train_seconds + evaluation)


def protocol_config(preset: str, task: str, matmul: str = "float32", steps: int = MEASURED_STEPS,
                    warmup: int = WARMUP_STEPS, compile: str = "on") -> RunConfig:
    """The protocol's run of ``preset`` on ``task`` as a measurement runs it: updates from step 100 (no
    random-action phase to wait through), no evaluation inside the timed steps."""
    from ..config import RunConfig, TrainingConfig, actor_config

    return RunConfig(task=task, seeds=(0,), steps=warmup + steps + 1, eval_every=PROTOCOL.eval_every,
                     eval_episodes=PROTOCOL.eval_episodes, actor=actor_config(preset),
                     training=TrainingConfig(start_steps=0, update_after=100), threads=1, compile=compile,
                     matmul=matmul)


def measure_protocol_speed(preset: str = BASE_PRESET, task: str = BASE_TASK, steps: int = MEASURED_STEPS,
                           warmup: int = WARMUP_STEPS, compile: str = "on") -> float:
    """Protocol steps/s of one seed of ``preset`` on ``task`` on this machine, one torch thread (the module
    docstring), timed in this process's CPU time: waiting for a core that other work holds does not count."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        config = protocol_config(preset, task, steps=steps, warmup=warmup, compile=compile)
        train, (evaluation, _) = seconds_per_training_step(
            config, warmup, steps, lambda trainer: evaluation_seconds(trainer, clock=time.process_time),
            clock=time.process_time)
    finally:
        torch.set_num_threads(threads)
    return protocol_speed(train, evaluation)


@dataclass(frozen=True)
class MachineSpeed:
    """A measured protocol speed: steps/s, when (UTC, ISO 8601) and on what (:func:`machine_key`)."""

    steps_per_second: float
    measured: str
    machine: str


def machine_key() -> str:
    """What the speed depends on besides load: the CPU's model and cores, torch's and ilcsan's versions."""
    import torch

    from ..version import __version__
    from .estimate import cpu_field

    return (f"{cpu_field('model name') or 'unknown CPU'}, {os.cpu_count()} cores, torch {torch.__version__}, "
            f"ilcsan {__version__}")


def cache_path() -> Path:
    """``$XDG_CACHE_HOME/ilcsan/machine_speed.json`` (``~/.cache`` without the variable)."""
    root = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(root) / "ilcsan" / CACHE_FILE


def cached_speed(key: str, path: Path | None = None) -> MachineSpeed | None:
    """The speed kept for ``key``; None when there is none, or the file is unreadable (it is then measured anew)."""
    try:
        entry = json.loads((path or cache_path()).read_text(encoding="utf-8"))[key]
        return MachineSpeed(float(entry["steps_per_second"]), str(entry["measured"]), key)
    except (OSError, ValueError, KeyError, TypeError):
        return None


def keep_speed(speed: MachineSpeed, path: Path | None = None) -> None:
    """Add ``speed`` to the cache file under its machine key (written atomically; other keys kept)."""
    path = path or cache_path()
    try:
        entries = json.loads(path.read_text(encoding="utf-8"))
        entries = entries if isinstance(entries, dict) else {}
    except (OSError, ValueError):
        entries = {}
    entries[speed.machine] = {"steps_per_second": speed.steps_per_second, "measured": speed.measured}
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(entries, indent=2, sort_keys=True) + "\n")


def busy_cores(threshold: float = 0.5) -> float | None:
    """The one-minute load average when it reaches ``threshold`` of a core (other work running), else None (also
    where the system does not report it)."""
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):
        return None
    return load if load >= threshold else None


def to_stderr(line: str) -> None:
    """Progress for a command whose standard output is its result."""
    print(line, file=sys.stderr, flush=True)


def this_machine_speed(log: Callable[[str], None] | None = None,
                       measure: Callable[[], float] = measure_protocol_speed) -> MachineSpeed:
    """The kept speed of this machine and software, else ``measure()``'s, kept for next time (``log``, standard
    error when None, says that it measures, as it takes about a minute)."""
    log = log or to_stderr
    key = machine_key()
    kept = cached_speed(key)
    if kept is not None:
        return kept
    log(f"measuring this machine's speed for the estimates: one {BASE_PRESET} seed on {BASE_TASK} at the protocol, "
        f"one thread (once per machine and software, about a minute on a free core; kept in {cache_path()})")
    busy = busy_cores()
    if busy is not None:
        log(f"this machine is busy (load {busy:.1f} on {os.cpu_count()} cores): the figure will be low; delete "
            f"{cache_path()} to measure again when it is idle, or set ILCSAN_STEPS_PER_SECOND")
    speed = MachineSpeed(measure(), time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), key)
    keep_speed(speed)
    return speed
