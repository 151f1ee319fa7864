"""How long a table takes: the run count, the speed of one run (a setting), and ``reproduce --list``."""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable

from .. import methods
from ..config import actor_config, training_config_class
from ..errors import UserError
from ..paper.layouts import TABLES, RowSpec, TableSpec

STEPS_PER_SECOND_ENV = "ILCSAN_STEPS_PER_SECOND"
"""Set it to the steps/s of one ILC-SAN run on Hopper with one torch thread, evaluations included, to use that figure
for the estimates instead of this machine's measured one (:mod:`ilcsan.experiments.machine_speed`)."""

ACTOR_STEP_COST: dict[str, dict[str, float]] = {
    "ilc-san": {"Hopper": 1.0, "HalfCheetah": 1.1, "Walker2d": 1.2, "InvertedDoublePendulum": 1.1,
                "BipedalWalker": 1.4, "Ant": 2.5, "Humanoid": 6.3, "HumanoidStandup": 7.2},
    "dan": {"Hopper": 0.55, "HalfCheetah": 0.52, "Walker2d": 0.59, "InvertedDoublePendulum": 0.57,
            "BipedalWalker": 0.68, "Ant": 0.81, "Humanoid": 1.1, "HumanoidStandup": 1.2},
    "popsan": {"Hopper": 1.0, "HalfCheetah": 1.1, "Walker2d": 1.1, "InvertedDoublePendulum": 0.95,
               "BipedalWalker": 1.2, "Ant": 2.4, "Humanoid": 6.0, "HumanoidStandup": 5.9},
}
"""Time per environment step of one seed of an actor preset on a task, relative to one ILC-SAN seed on Hopper, at the
paper's protocol (TD3, float32, one torch thread, compiled, evaluations included with episodes at their full length),
as ``benchmarks/task_cost.py`` measured it (``benchmarks/RESULTS.md``: ILC-SAN the median of three runs, DAN and
PopSAN one run beside ILC-SAN's, rounded). Ratios hold
across machines far better than steps/s do. The spiking actors' wide input populations (Ant 1 110 neurons, Humanoid
3 760) make their products the dearest; DAN's cost follows its critic's. A preset not listed costs what ILC-SAN does
on the same task; a task not listed (a user's own) what Hopper does for that preset."""

EXAMPLE_CLUSTER_CORES = 64
"""The cluster size ``reproduce --list`` shows beside this machine."""


def cpu_field(name: str, path: str = "/proc/cpuinfo") -> str | None:
    """The value of the first ``name`` line of /proc/cpuinfo (``model name``, ``vendor_id``); None where the file
    is unreadable or has no such line. The benchmarks name the CPU they measured with it; estimates do not use it."""
    try:
        with open(path, encoding="utf-8") as stream:
            for line in stream:
                key, _, value = line.partition(":")
                if key.strip() == name:
                    return value.strip()
    except OSError:
        pass
    return None


def set_steps_per_second() -> float | None:
    """``ILCSAN_STEPS_PER_SECOND`` as a number (None when not set); a :class:`UserError` when it is not a positive
    number."""
    text = os.environ.get(STEPS_PER_SECOND_ENV)
    if not text:
        return None
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (math.isfinite(value) and value > 0):
        raise UserError(f"{STEPS_PER_SECOND_ENV}={text!r} must be a positive number of steps per second")
    return value


def base_speed(log: Callable[[str], None] | None = None) -> tuple[float, str]:
    """The steps/s of one ILC-SAN seed on Hopper that the estimates scale, and where it comes from, in words:
    ``ILCSAN_STEPS_PER_SECOND`` if set, else this machine's measured speed
    (:func:`~ilcsan.experiments.machine_speed.this_machine_speed`, measured once and kept)."""
    value = set_steps_per_second()
    if value is not None:
        return value, f"the setting {STEPS_PER_SECOND_ENV}"
    from .machine_speed import cache_path, this_machine_speed

    speed = this_machine_speed(log)
    return speed.steps_per_second, (f"measured on this machine on {speed.measured[:10]} (kept in {cache_path()}: "
                                    f"delete it to measure again, or set {STEPS_PER_SECOND_ENV})")


def method_step_cost(row: RowSpec) -> float:
    """What a row's training adds to its actor's time per step: the product of its algorithm's, its actor's
    normalisation's and its training methods' declared :meth:`~ilcsan.methods.Declared.relative_cost` (1 for plain
    TD3). DAN has no spiking normalisation or spiking-only method to pay for: only its algorithm counts."""
    training = training_config_class()(**row.training)
    algorithm = methods.declared("algorithm", row.algorithm).relative_cost(training)
    if row.preset == "dan":
        return algorithm
    normalization = methods.declared("normalization", actor_config(row.preset, **row.overrides).normalization)
    return algorithm * normalization.relative_cost(training) * methods.relative_cost(training)


def actor_step_cost(preset: str | None, task: str) -> float:
    """One seed's time per step of ``preset`` on ``task``, relative to ILC-SAN's on Hopper (:data:`ACTOR_STEP_COST`:
    a preset not measured costs ILC-SAN's, a task not measured the preset's Hopper)."""
    costs = ACTOR_STEP_COST.get(preset or "", ACTOR_STEP_COST["ilc-san"])
    return costs.get(task, costs["Hopper"])


def run_step_cost(task: str, row: RowSpec) -> float:
    """A run's time per step relative to one ILC-SAN seed on Hopper: its actor's on its task times its training's."""
    return actor_step_cost(row.preset, task) * method_step_cost(row)


def estimate_hours(table: str | TableSpec, steps_per_second: float, cores: int) -> float:
    """Wall-clock hours to run a whole table on ``cores`` cores, one run per core at a time.

    A run takes ``steps × cost / steps_per_second`` seconds (``steps_per_second`` the speed of one ILC-SAN run on
    Hopper on one core, evaluations included; ``cost`` its :func:`run_step_cost`); the runs are dealt longest first
    to the least busy core, and the estimate is the busiest core's total (with equal runs: ceil(runs / cores) waves).
    Training the seeds of a cell together (as ``reproduce`` does) is faster in aggregate, so this is an upper estimate
    for that part.
    """
    spec = TABLES[table] if isinstance(table, str) else table
    if steps_per_second <= 0 or cores < 1:
        raise ValueError("steps_per_second must be positive and cores at least 1")
    costs = sorted((run_step_cost(task, row) for task, row, _ in spec.runs()), reverse=True)
    loads = [0.0] * min(cores, max(1, len(costs)))
    for cost in costs:
        index = loads.index(min(loads))
        loads[index] += cost
    return max(loads) * spec.steps / steps_per_second / 3600


def _row_switches(row: RowSpec) -> str:
    if not row.runnable:
        return "(the paper's numbers only; no code exists)"
    chosen = {} if row.algorithm == methods.default("algorithm") else {"algorithm": row.algorithm}
    return " ".join(f"{key}={value}" for key, value in {**row.actor(), **chosen, **row.training}.items())


def describe_table(spec: TableSpec, steps_per_second: float, cores: int) -> str:
    """Caption, tasks, rows with their actor switches, protocol, run count and time estimates."""
    runs = len(spec.runs())
    width = max(len(row.slug) for row in spec.rows)
    label_width = max(len(row.label) for row in spec.rows)
    lines = [f"{spec.name}: {spec.caption}",
             f"  tasks ({len(spec.tasks)}): {', '.join(spec.tasks)}",
             *_actor_cost_lines(spec),
             f"  rows ({len(spec.runnable_rows)} to run):"]
    lines += [f"    {row.slug:<{width}}  {row.label:<{label_width}}  {_row_switches(row)}" for row in spec.rows]
    lines.append(f"  protocol: {spec.seeds} seeds × {spec.steps:,} steps, {spec.eval_episodes} deterministic "
                 f"episodes every {spec.eval_every:,} steps; a run's score is its best evaluation")
    lines.append(f"  runs: {len(spec.tasks)} tasks × {len(spec.runnable_rows)} rows × {spec.seeds} seeds = {runs} "
                 f"({runs * spec.steps:,} steps)")
    here = estimate_hours(spec, steps_per_second, cores)
    cluster = estimate_hours(spec, steps_per_second, EXAMPLE_CLUSTER_CORES)
    lines.append(f"  estimate: {_format_hours(here)} on this machine ({cores} run{'s' * (cores != 1)} at a time), "
                 f"{_format_hours(cluster)} on {EXAMPLE_CLUSTER_CORES} cores")
    return "\n".join(lines)


def _actor_cost_lines(spec: TableSpec) -> list[str]:
    """One line per measured actor preset the table runs (its time per step on each task, × ILC-SAN's on Hopper),
    and one naming those not measured (costed as ILC-SAN)."""
    presets = dict.fromkeys(row.preset for row in spec.runnable_rows)
    lines = [f"  {preset} time per step (× ILC-SAN's on Hopper): "
             + ", ".join(f"{task} {actor_step_cost(preset, task):.2g}" for task in spec.tasks)
             for preset in presets if preset in ACTOR_STEP_COST]
    unmeasured = [preset for preset in presets if preset not in ACTOR_STEP_COST]
    if unmeasured:
        lines.append(f"  {', '.join(unmeasured)}: not measured, estimated as ilc-san")
    return lines


def _format_hours(hours: float) -> str:
    return f"≈ {hours:,.0f} h ({hours / 24:,.1f} days)" if hours >= 48 else f"≈ {hours:,.1f} h"


def _method_costs() -> str:
    """Each registered method that costs more than a plain step, with its declared cost: 'Title note, ...'."""
    return ", ".join(f"{method.title} {method.cost_note}" for method in methods.every() if method.cost_note)


def list_tables(specs: Iterable[TableSpec] | None = None, steps_per_second: float | None = None,
                cores: int | None = None, log: Callable[[str], None] | None = None) -> str:
    """The text of ``ilcsan reproduce --list``; ``steps_per_second`` the base speed (:func:`base_speed`'s when
    None, which ``log`` (standard error when None) tells about when it measures)."""
    speed, source = base_speed(log) if steps_per_second is None else (steps_per_second, "as given")
    cores = cores or os.cpu_count() or 1
    blocks = [describe_table(spec, speed, cores) for spec in (specs or TABLES.values())]
    footer = (f"Estimates assume {speed:.0f} steps/s per run on one core (ILC-SAN on Hopper, one torch thread, "
              f"evaluations included; {source}) and one run per core; "
              "a run's hours = steps × its actor's cost on its task × its training's cost / (steps/s) / 3600 (each "
              "actor preset's time per step on each task relative to ILC-SAN's on Hopper, float32, as "
              f"benchmarks/task_cost.py measured them; training: {_method_costs()}; the algorithm's and methods' "
              "costs multiply), "
              "dealt longest first to the cores. Shrink a table with --seeds, --steps, --tasks, --rows; run it on a "
              "cluster with --backend ray --address HOST:PORT.")
    return "\n\n".join([*blocks, footer])
