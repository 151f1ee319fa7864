"""Progress of a grid: steps done (read from each run's ``result.json``), throughput and ETA."""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from ..runs.directory import RunDirectory
from .grid import Grid, GridRun
from .jobs import RunState


@dataclass
class Progress:
    """Steps done over the whole grid, measured throughput and ETA."""

    grid: Grid
    done: dict[str, int]
    started: float = field(default_factory=time.monotonic)
    start_done: int = 0

    @classmethod
    def start(cls, grid: Grid, states: Mapping[str, RunState]) -> Progress:
        done = {run.key: states[run.key].step for run in grid.runs}
        return cls(grid, done, start_done=sum(done.values()))

    def update(self, runs: Iterable[GridRun]) -> None:
        """Read the steps done of these runs from their ``result.json`` (a file being written counts as none)."""
        for run in runs:
            steps = RunDirectory(run.directory).result_or_empty().get("steps_done")
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
                f"{format_steps(done)}/{format_steps(total)} steps")
        rate = self.rate()
        if rate is None:
            return text + " · ETA after the first evaluations"
        return text + f" · {rate:.0f} steps/s · ETA {format_duration((total - done) / rate)}"


def format_steps(steps: int) -> str:
    """1_500 → '1.5k'; 2_000_000 → '2M'."""
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
