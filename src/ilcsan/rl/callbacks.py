"""What a training run reports around the loop: a progress bar, one line per evaluation, TensorBoard.

Each reporter is a :class:`TrainingCallback`; the trainer calls ``start`` before its first step,
``step`` after every step, ``evaluated`` after each evaluation has been saved and ``close`` at the end.
They read the trainer (``step``, ``config``, ``evaluations``) and never change it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..runs.directory import DIAGNOSTICS
from ..snn.diagnostics import STUCK_EVALUATIONS, is_stuck, stuck_reason

STATUS_EVERY = 200
"""Steps between two updates of the progress bar's status text."""


class TrainingCallback(Protocol):
    def start(self, trainer: Any) -> None: ...

    def step(self, trainer: Any) -> None: ...

    def evaluated(self, trainer: Any, rows: list[dict[str, float]], speed: float, losses: dict[str, float]) -> None:
        ...

    def close(self) -> None: ...


class Callbacks:
    """Several callbacks called as one, in order."""

    def __init__(self, *callbacks: TrainingCallback):
        self.callbacks = list(callbacks)

    def start(self, trainer: Any) -> None:
        for callback in self.callbacks:
            callback.start(trainer)

    def step(self, trainer: Any) -> None:
        for callback in self.callbacks:
            callback.step(trainer)

    def evaluated(self, trainer: Any, rows: list[dict[str, float]], speed: float, losses: dict[str, float]) -> None:
        for callback in self.callbacks:
            callback.evaluated(trainer, rows, speed, losses)

    def close(self) -> None:
        for callback in self.callbacks:
            callback.close()
        self.callbacks = []


def best_so_far(evaluations: list[list[dict[str, float]]]) -> str:
    """The seeds' mean best evaluation return, as the progress bar and the evaluation line show it."""
    if not evaluations[0]:
        return "no evaluation yet"
    bests = [max((row["eval_return_mean"] for row in rows), default=float("nan")) for rows in evaluations]
    return f"best {np.nanmean(bests):.1f}"


def stuck_seeds(trainer: Any) -> list[int]:
    """Indices of the seeds that are stuck (:func:`~ilcsan.snn.diagnostics.is_stuck`) at their last evaluation."""
    start = trainer.config.training.start_steps
    return [index for index, rows in enumerate(trainer.evaluations) if is_stuck(rows, start)]


class ProgressReport:
    """A tqdm bar over the run's steps (when ``progress``), one line per evaluation (through the bar, or
    ``log`` without one), and once per seed a line when it is stuck (:func:`stuck_seeds`)."""

    def __init__(self, progress: bool, log: Callable[[str], Any] = print):
        self.progress, self.log = progress, log
        self.bar = None
        self.reported_stuck: set[int] = set()

    def start(self, trainer: Any) -> None:
        from tqdm import tqdm

        config = trainer.config
        self.bar = tqdm(total=config.steps, initial=trainer.step, disable=not self.progress, unit="step",
                        dynamic_ncols=True, desc=f"{config.task} {config.actor.preset}")

    def step(self, trainer: Any) -> None:
        if self.bar is None:
            return
        self.bar.update(1)
        if trainer.step % STATUS_EVERY == 0 and self.progress:
            self.bar.set_postfix_str(best_so_far(trainer.evaluations))

    def evaluated(self, trainer: Any, rows: list[dict[str, float]], speed: float, losses: dict[str, float]) -> None:
        config = trainer.config
        returns = " ".join(f"{row['eval_return_mean']:.1f}" for row in rows)
        message = (f"[{config.task} {config.label or config.actor.preset}] step {trainer.step}: eval return "
                   f"{returns} · best {best_so_far(trainer.evaluations).removeprefix('best ')} · {speed:.0f} steps/s "
                   f"({trainer.agent.execution})")
        self._write(message)
        for index in stuck_seeds(trainer):
            if index not in self.reported_stuck:
                self.reported_stuck.add(index)
                self._write(
                    f"[{config.task} {config.label or config.actor.preset}] seed {config.seeds[index]} is stuck: at "
                    f"its last {STUCK_EVALUATIONS} evaluations it acted with "
                    f"{stuck_reason(trainer.evaluations[index][-1])}, so almost no gradient reaches the actor; such a "
                    "seed rarely recovers (see metrics.csv's diagnostics)")

    def _write(self, message: str) -> None:
        if self.progress:
            from tqdm import tqdm

            tqdm.write(message)
        else:
            self.log(message)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


class TensorBoardLog:
    """Evaluation returns, speed and losses of each seed as TensorBoard scalars in its ``tensorboard/``.

    Event files written after ``first_step`` by an interrupted process are purged on resume."""

    def __init__(self, folders: list[Path], first_step: int):
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:  # tensorboard is a dependency, but keep training without it
            self.writers = []
            return
        self.writers = [SummaryWriter(str(folder), purge_step=first_step or None) for folder in folders]

    def start(self, trainer: Any) -> None:
        pass

    def step(self, trainer: Any) -> None:
        pass

    def evaluated(self, trainer: Any, rows: list[dict[str, float]], speed: float, losses: dict[str, float]) -> None:
        for writer, row in zip(self.writers, rows, strict=False):
            writer.add_scalar("eval/return_mean", row["eval_return_mean"], trainer.step)
            writer.add_scalar("eval/return_std", row["eval_return_std"], trainer.step)
            writer.add_scalar("train/steps_per_second", speed, trainer.step)
            for name in DIAGNOSTICS:
                if name in row and np.isfinite(row[name]):
                    writer.add_scalar(f"diagnostics/{name}", row[name], trainer.step)
            for name, value in losses.items():
                writer.add_scalar(f"train/{name}", value, trainer.step)
            writer.flush()

    def close(self) -> None:
        for writer in self.writers:
            writer.close()
        self.writers = []
