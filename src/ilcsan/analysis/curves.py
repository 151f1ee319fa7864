"""Learning curves: smoothed mean ± std over seeds, drawn per task in the style of the paper's figures."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..files import atomic_write_file
from ..paper.layouts import TableSpec
from .collect import RunRecord
from .reward_tables import TableResult, build_table

SMOOTHING_WINDOW = 5
"""Learning curves are smoothed by a trailing moving average over this many evaluations."""

PANELS_PER_LINE = 4
"""Learning-curve panels per line of the figure (the paper's figures show four tasks side by side)."""


def smooth(values: np.ndarray, window: int = SMOOTHING_WINDOW) -> np.ndarray:
    """Trailing moving average over ``window`` evaluations along the last axis.

    Point i is the mean of evaluations max(0, i − window + 1) … i, so the first points average fewer
    evaluations; the curve keeps its length and never looks ahead.
    """
    values = np.asarray(values, dtype=float)
    cumulative = np.cumsum(values, axis=-1)
    shifted = np.zeros_like(cumulative)
    shifted[..., window:] = cumulative[..., :-window]
    counts = np.minimum(np.arange(1, values.shape[-1] + 1), window)
    return (cumulative - shifted) / counts


def smoothing_window(points: int) -> int:
    """Smooth long curves only: 5 evaluations for the paper's 100-point curves, none below 20 points
    (a short run's few evaluations would lag far behind what it reached)."""
    return max(1, min(SMOOTHING_WINDOW, points // 20))


def curve(runs: Sequence[RunRecord], window: int | None = None) -> tuple[np.ndarray, ...] | None:
    """(steps, mean, std) over seeds at the steps every run evaluated, each run smoothed first; the std is the sample
    std (ddof = 1) as in every table of ours, 0 for one seed.

    Curves are aligned on the common steps (the intersection of the runs' evaluation steps), so a
    seed that is still running shortens the curve. None when there are no common steps. ``window``
    defaults to :func:`smoothing_window` of the curve's length.
    """
    with_curves = [run for run in runs if run.steps]
    if not with_curves:
        return None
    common = sorted(set.intersection(*(set(run.steps) for run in with_curves)))
    if not common:
        return None
    values = np.array([[dict(zip(run.steps, run.returns, strict=True))[step] for step in common]
                       for run in with_curves])
    smoothed = smooth(values, smoothing_window(len(common)) if window is None else window)
    return np.array(common, dtype=float), smoothed.mean(axis=0), smoothed.std(axis=0, ddof=min(1, len(values) - 1))


def plot_curves(runs: Sequence[RunRecord], path: str | Path, table: str | TableSpec | None = None):
    """Learning curves as a PNG, in the style of the paper's figures; returns the matplotlib Figure.

    One panel per task of :func:`build_table` ``(runs, table)``, one line per row with runs: the mean
    over seeds of ``eval_return_mean`` against the step, shaded ± half the std (as the paper's
    figures), smoothed by :func:`smooth` (trailing moving average over 5 evaluations for curves of 100
    or more evaluations, fewer for shorter curves, none below 20: :func:`smoothing_window`) and aligned on
    the steps common to the row's seeds (:func:`curve`). Written atomically.
    """
    return draw_curves([build_table(runs, table)], path)


def draw_curves(results: Sequence[TableResult], path: str | Path):
    """Draw the curves of several tables in one figure (each table its own panels) and save it."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    tasks = [_plotted_tasks(result) for result in results]
    panels = [(result, task) for result, shown in zip(results, tasks, strict=True) for task in shown]
    lines_per = [math.ceil(len(shown) / PANELS_PER_LINE) for shown in tasks]
    n_lines, n_cols = max(1, sum(lines_per)), max(1, min(PANELS_PER_LINE, max(map(len, tasks), default=1)))
    single = len(panels) == 1  # one task (e.g. a grid shrunk with --tasks): a larger panel for its many rows
    figure = Figure(figsize=(6.4, 4.0) if single else (3.6 * n_cols, 2.9 * n_lines), layout="constrained")
    FigureCanvasAgg(figure)
    if not panels:
        axes = figure.add_subplot(1, 1, 1)
        axes.text(0.5, 0.5, "no runs found", ha="center", va="center", transform=axes.transAxes)
        axes.set_axis_off()
    first_line = 0
    for result, lines, shown in zip(results, lines_per, tasks, strict=True):
        for index, task in enumerate(shown):
            position = (first_line + index // PANELS_PER_LINE) * n_cols + index % PANELS_PER_LINE + 1
            _draw_panel(figure.add_subplot(n_lines, n_cols, position), result, task, len(results) > 1)
        first_line += lines
    _save_figure(figure, Path(path))
    return figure


def _plotted_tasks(result: TableResult) -> tuple[str, ...]:
    """The tasks that have runs (a shrunk reproduction shows only its own); all of them when none has."""
    with_runs = tuple(task for task in result.tasks if any(row.cell(task).runs for row in result.rows))
    return with_runs or result.tasks


def _draw_panel(axes, result: TableResult, task: str, prefix: bool) -> None:
    drawn = 0
    for index, row in enumerate(result.rows):
        data = curve(row.cell(task).runs)
        if data is None:
            continue
        steps, mean, std = data
        color = f"C{index % 10}"
        axes.plot(steps, mean, color=color, linewidth=1.2, label=row.label)
        axes.fill_between(steps, mean - std / 2, mean + std / 2, color=color, alpha=0.2, linewidth=0)
        drawn += 1
    title = f"{result.name}: {task}" if prefix and result.name else task
    axes.set_title(title, fontsize=10)
    axes.set_xlabel("steps", fontsize=8)
    axes.set_ylabel("average reward", fontsize=8)
    axes.tick_params(labelsize=7)
    axes.grid(alpha=0.3)
    if drawn:
        axes.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
        axes.legend(fontsize=6, loc="best")
    else:
        axes.text(0.5, 0.5, "no runs", ha="center", va="center", transform=axes.transAxes, color="0.5")


def _save_figure(figure, path: Path) -> None:
    """Write the figure as a PNG, atomically (:func:`ilcsan.files.atomic_write_file`)."""
    atomic_write_file(path, lambda temporary: figure.savefig(temporary, format="png", dpi=110))
