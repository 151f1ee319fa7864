"""Learning curves: smoothed mean ± std over seeds, drawn per task in the style of the paper's figures.

Beside a row's curve, a panel draws the paper's value for its (table, row, task) cell where the paper has one:
a dashed line in the row's colour at the published mean, a light band of ± the published std. That value is the
paper's *max average reward* (each seed's best evaluation, averaged over seeds), so a curve of the mean over seeds
at each step lies below it even when the runs match the paper's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..files import atomic_write_file
from ..paper.layouts import TableSpec
from .collect import RunRecord
from .reward_tables import RowResult, TableResult, build_table

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
    """Smooth long curves only: 5 evaluations for the paper's 100-point curves, none below 40 points
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
    or more evaluations, fewer for shorter curves, none below 40: :func:`smoothing_window`) and aligned on
    the steps common to the row's seeds (:func:`curve`); the paper's value of a row's cell, where it has one, as a
    dashed line in the row's colour with a light ± std band (:func:`draw_rows`). Written atomically.
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
    save_figure(figure, Path(path))
    return figure


def _plotted_tasks(result: TableResult) -> tuple[str, ...]:
    """The tasks that have runs (a shrunk reproduction shows only its own); all of them when none has."""
    with_runs = tuple(task for task in result.tasks if any(row.cell(task).runs for row in result.rows))
    return with_runs or result.tasks


def row_colour(position: int) -> str:
    """The colour of the table's row at ``position``: a row has the same colour in every figure of its table."""
    return f"C{position % 10}"


def row_colors(result: TableResult) -> dict[str, str]:
    """Each row's colour (:func:`row_colour`) by its key."""
    return {row.key: row_colour(index) for index, row in enumerate(result.rows)}


PAPER_LABEL = "paper (max avg. reward ± std)"
"""Legend entry of the paper's published values (dashed lines): the max average reward, not a point of a curve."""
PAPER_GID = "paper"
"""``gid`` of a dashed line (and its band) at a published value, to tell it from the curves."""


def draw_rows(axes, result: TableResult, rows: Sequence[RowResult], task: str, seeds_in_label: bool = False) -> int:
    """Draw the curve of each row with runs on ``task`` (mean over seeds, shaded ± half the std, :func:`curve`)
    and, where the row's cell has a published value, the paper's dashed line and ± std band in the row's colour;
    add a legend (one "paper" entry for all dashed lines; with ``seeds_in_label`` each row's label says its number
    of seeds, n). Returns the number of curves drawn."""
    colors = row_colors(result)
    drawn, paper_colors = 0, []
    for row in rows:
        cell = row.cell(task)
        data = curve(cell.runs)
        if data is None:
            continue
        steps, mean, std = data
        color = colors[row.key]
        seeds = sum(bool(run.steps) for run in cell.runs)
        label = f"{row.label} (n={seeds})" if seeds_in_label else row.label
        axes.plot(steps, mean, color=color, linewidth=1.2, label=label)
        axes.fill_between(steps, mean - std / 2, mean + std / 2, color=color, alpha=0.2, linewidth=0)
        drawn += 1
        if cell.paper is not None:
            paper = cell.paper
            axes.axhline(paper.mean, color=color, linestyle="--", linewidth=1.0, gid=PAPER_GID, label="_paper")
            axes.axhspan(paper.mean - paper.std, paper.mean + paper.std, color=color, alpha=0.07, linewidth=0,
                         gid=PAPER_GID)
            paper_colors.append(color)
    if drawn:
        axes.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
        handles, labels = axes.get_legend_handles_labels()
        handler_map = {}
        if paper_colors:  # one entry: a dash in each row's colour, for up to two rows (more would be too short)
            from matplotlib.legend_handler import HandlerTuple
            from matplotlib.lines import Line2D

            handles.append(tuple(Line2D([], [], color=color, linestyle="--", linewidth=1.0)
                                 for color in (paper_colors if len(paper_colors) <= 2 else ["0.15"])))
            labels.append(PAPER_LABEL)
            handler_map = {tuple: HandlerTuple(ndivide=None, pad=0.0)}
        axes.legend(handles, labels, fontsize=6, loc="best", handler_map=handler_map)
    return drawn


def style_panel(axes, title: str) -> None:
    """Title, axis labels, ticks and grid of a learning-curve panel."""
    axes.set_title(title, fontsize=10)
    axes.set_xlabel("steps", fontsize=8)
    axes.set_ylabel("average reward", fontsize=8)
    axes.tick_params(labelsize=7)
    axes.grid(alpha=0.3)


def _draw_panel(axes, result: TableResult, task: str, prefix: bool) -> None:
    drawn = draw_rows(axes, result, result.rows, task)
    style_panel(axes, f"{result.name}: {task}" if prefix and result.name else task)
    if not drawn:
        mark_no_runs(axes)


def mark_no_runs(axes) -> None:
    """Say "no runs" on an empty panel, without the meaningless 0–1 ticks of its empty axes."""
    axes.text(0.5, 0.5, "no runs", ha="center", va="center", transform=axes.transAxes, color="0.5")
    axes.set_xticks([])
    axes.set_yticks([])


def save_figure(figure, path: Path) -> None:
    """Write the figure as a PNG, atomically (:func:`ilcsan.files.atomic_write_file`)."""
    atomic_write_file(path, lambda temporary: figure.savefig(temporary, format="png", dpi=110))
