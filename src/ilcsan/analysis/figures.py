"""The paper's comparison figures (Fig. 5 and Fig. 6) drawn from a report's runs.

Each figure compares rows of Table ``perf`` on the first four tasks, one panel per task, in the style of
``curves.png`` (:mod:`.curves`): the mean over seeds of each evaluation's average reward, shaded ± half the std
over seeds, smoothed by the same trailing moving average (:func:`~.curves.smooth`, 5 evaluations for curves of 100
evaluations or more, none below 40: :func:`~.curves.smoothing_window`; ``metrics.csv`` keeps the raw values), the
paper's published value of each cell as a dashed line with a ± std band, and the number of seeds of each row in
its legend. A figure is one :class:`ComparisonFigure`: the rows it compares and its tasks; both figures of the
paper are declarations of it, drawn by one function (:func:`draw_comparison`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..paper.published import FIRST_FOUR
from .curves import draw_rows, mark_no_runs, save_figure, style_panel
from .reward_tables import RowResult, TableResult


@dataclass(frozen=True)
class ComparisonFigure:
    """A figure of the paper that compares rows of one table on some tasks: its file stem (``fig5`` →
    ``fig5.png``), the paper's LaTeX label, the table, the rows by slug (drawn in this order) and the tasks."""

    name: str
    label: str
    table: str
    rows: tuple[str, ...]
    tasks: tuple[str, ...]
    title: str


PAPER_FIGURES: tuple[ComparisonFigure, ...] = (
    ComparisonFigure("fig5", "fig:pop-det", "perf", ("popsan", "ilc-san-pop-det"), FIRST_FOUR,
                     "PopSAN and ILC-SAN using E_pop_det (the paper's Fig. 5)"),
    ComparisonFigure("fig6", "fig:pop", "perf", ("mdc-san", "ilc-san-pop"), FIRST_FOUR,
                     "MDC-SAN and ILC-SAN using E_pop (the paper's Fig. 6)"),
)
"""The paper's learning-curve figures: Fig. 5 (``fig:pop-det``) and Fig. 6 (``fig:pop``)."""


def figure_rows(result: TableResult, figure: ComparisonFigure) -> list[RowResult] | None:
    """The table's rows that ``figure`` compares, or None when the table is not the figure's or lacks one of them."""
    if result.name != figure.table:
        return None
    try:
        return [result.row(slug) for slug in figure.rows]
    except KeyError:
        return None


def figure_applies(result: TableResult, figure: ComparisonFigure) -> bool:
    """Whether ``result`` has runs of every row of ``figure`` on at least one of its tasks (the same task)."""
    rows = figure_rows(result, figure)
    return rows is not None and any(
        task in result.tasks and all(row.cell(task).runs for row in rows) for task in figure.tasks)


def draw_comparison(result: TableResult, figure: ComparisonFigure, path: str | Path):
    """Draw ``figure`` from the table ``result`` into ``path`` (a PNG, written atomically); returns the Figure.

    One panel per task of the figure, side by side; a row without runs on a task is named on its panel ("no runs of
    PopSAN"), a panel without any "no runs".
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rows = figure_rows(result, figure)
    if rows is None:
        raise ValueError(f"table {result.name!r} has not the rows {figure.rows} of {figure.name}")
    drawing = Figure(figsize=(3.6 * len(figure.tasks), 3.1), layout="constrained")
    FigureCanvasAgg(drawing)
    drawing.suptitle(f"{figure.title}: mean over seeds, shaded ± half the std, smoothed; dashed: the paper's value",
                     fontsize=10)
    for index, task in enumerate(figure.tasks, start=1):
        axes = drawing.add_subplot(1, len(figure.tasks), index)
        cells = [row.cell(task) for row in rows] if task in result.tasks else []
        drawn = draw_rows(axes, result, rows, task, seeds_in_label=True) if cells else 0
        style_panel(axes, task)
        missing = [row.label for row, cell in zip(rows, cells, strict=True) if not cell.runs]
        if not drawn:
            mark_no_runs(axes)
        elif missing:
            axes.text(0.5, 0.03, "no runs of " + ", ".join(missing), ha="center", va="bottom",
                      transform=axes.transAxes, color="0.4", fontsize=7)
    save_figure(drawing, Path(path))
    return drawing


def write_paper_figures(results: Sequence[TableResult], out: Path) -> dict[str, Path]:
    """Draw every figure of :data:`PAPER_FIGURES` that a table of ``results`` has runs for (:func:`figure_applies`)
    into ``out`` as ``<name>.png``; returns the paths by figure name."""
    paths: dict[str, Path] = {}
    for figure in PAPER_FIGURES:
        for result in results:
            if figure.name not in paths and figure_applies(result, figure):
                paths[figure.name] = out / f"{figure.name}.png"
                draw_comparison(result, figure, paths[figure.name])
    return paths
