"""The paper's comparison figures (Fig. 5 and Fig. 6) drawn from a report's runs.

Each figure compares rows of Table ``perf`` on the first four tasks, one panel per task, in the style of
``curves.png`` (:mod:`.curves`): the mean over seeds of each evaluation's average reward, shaded ± half the std
over seeds, smoothed by the same trailing moving average (:func:`~.curves.smooth`, 5 evaluations for curves of 100
evaluations or more, none below 40: :func:`~.curves.smoothing_window`; ``metrics.csv`` keeps the raw values), the
paper's published value of each cell as a dashed line with a ± std band, and the number of seeds of each row in
its legend. A figure is one :class:`ComparisonFigure`: the rows it compares and its tasks; both figures of the
paper are declarations of it, drawn by one function (:func:`draw_comparison`).

``intervals.png`` (:func:`draw_intervals`) draws the report's interval estimates (:mod:`.comparison`) in the style
of rliable's plots (Agarwal et al. 2021): per table, one panel per aggregate (IQM, mean) and normaliser, each row a
bar from its interval's low to high end with a tick at the point estimate, and a panel of the P(improvement)
comparisons with a dashed line at 0.5 (even).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..paper.published import FIRST_FOUR
from .comparison import EVEN, IMPROVEMENT, Interval, Selection, TableComparison
from .curves import draw_rows, mark_no_runs, row_colour, save_figure, style_panel
from .reward_tables import RowResult, TableResult

INTERVALS_FIGURE = "intervals.png"
"""The file of :func:`draw_intervals` in a report's folder."""


@dataclass(frozen=True)
class ComparisonFigure:
    """A figure of the paper that compares rows of one table on some tasks: its file stem (``fig5`` →
    ``fig5.png``), the table, the rows by slug (drawn in this order), the tasks and its title."""

    name: str
    table: str
    rows: tuple[str, ...]
    tasks: tuple[str, ...]
    title: str


PAPER_FIGURES: tuple[ComparisonFigure, ...] = (
    ComparisonFigure("fig5", "perf", ("popsan", "ilc-san-pop-det"), FIRST_FOUR,
                     "PopSAN and ILC-SAN using E_pop_det (the paper's Fig. 5)"),
    ComparisonFigure("fig6", "perf", ("mdc-san", "ilc-san-pop"), FIRST_FOUR,
                     "MDC-SAN and ILC-SAN using E_pop (the paper's Fig. 6)"),
)
"""The paper's learning-curve figures: Fig. 5 (LaTeX label ``fig:pop-det``) and Fig. 6 (``fig:pop``)."""


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
            axes.text(0.03, 0.97, "no runs of " + ", ".join(missing), ha="left", va="top",  # clear of the legend
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


def _selection_label(selection: Selection) -> str:
    return f"{len(selection.tasks)} tasks × {selection.k} seeds"


def interval_panels(comparison: TableComparison) -> list[tuple[str, list[tuple[str, str, Interval]]]]:
    """The panels of ``comparison`` that have numbers: (title, [(row, label, interval), …]), aggregates first (IQM
    then mean, per normaliser), then P(improvement); rows not computed are left out, so are panels left empty."""
    panels = []
    for normaliser in dict.fromkeys(item.normaliser for item in comparison.aggregates):
        for name, title in (("iqm", "IQM"), ("mean", "Mean")):
            bars = [(item.row, f"{item.row}\n{_selection_label(item.selection)}", getattr(item, name))
                    for item in comparison.aggregates
                    if item.normaliser == normaliser and getattr(item, name) is not None]
            panels.append((f"{title} of score / {normaliser}", bars))
    panels.append((IMPROVEMENT_TITLE,
                   [(item.row, f"{item.row} over {item.against}\n{_selection_label(item.selection)}", item.interval)
                    for item in comparison.comparisons if item.statistic == IMPROVEMENT and item.interval]))
    return [(title, bars) for title, bars in panels if bars]


IMPROVEMENT_TITLE = "P(improvement): a run of X above a run of Y"
PANEL_COLUMNS = 3
"""Panels side by side in ``intervals.png``; a table with more continues on the next line."""


def draw_intervals(comparisons: Sequence[TableComparison], path: str | Path):
    """Draw the interval estimates of ``comparisons`` into ``path`` (a PNG, written atomically), each table's panels
    in lines of :data:`PANEL_COLUMNS`; returns the Figure, or None (nothing written) when no interval was computed.
    A row has the colour it has in the table's curves (:func:`~.curves.row_colour`)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    tables = [(item, panels) for item in comparisons if (panels := interval_panels(item))]
    if not tables:
        return None
    columns = min(PANEL_COLUMNS, max(len(panels) for _, panels in tables))
    lines = sum(-(-len(panels) // columns) for _, panels in tables)
    height = max(len(bars) for _, panels in tables for _, bars in panels)
    drawing = Figure(figsize=(4.6 * columns, (1.0 + 0.5 * height) * lines + 0.5), layout="constrained")
    FigureCanvasAgg(drawing)
    confidence = tables[0][0].bootstrap.confidence
    drawing.suptitle(f"Interval estimates: point estimate (black tick) and {100 * confidence:g} % stratified "
                     f"bootstrap interval (bar); dotted: the DAN mean divided by (1), dashed: even (0.5);\n"
                     f"under each row: the tasks × seeds used", fontsize=10)
    index = 0
    for comparison, panels in tables:
        drawn = dict.fromkeys(row for _, bars in panels for row, _, _ in bars)
        order = [*comparison.rows, *(row for row in drawn if row not in comparison.rows)]
        colours = {row: row_colour(order.index(row)) for row in drawn}
        for title, bars in panels:
            index += 1
            axes = drawing.add_subplot(lines, columns, index)
            _draw_bars(axes, bars, colours, f"{comparison.table}: {title}" if len(tables) > 1 else title,
                       title == IMPROVEMENT_TITLE)
        index += -index % columns  # the next table starts a new line
    save_figure(drawing, Path(path))
    return drawing


def _draw_bars(axes, bars: Sequence[tuple[str, str, Interval]], colours: dict[str, str], title: str,
               improvement: bool) -> None:
    """One panel: a bar per row from its interval's low to high end, top to bottom, a tick at the estimate; on the
    P(improvement) panel the x axis spans 0 to 1 with a dashed line at even (0.5)."""
    for position, (row, _, interval) in enumerate(bars):
        y = len(bars) - 1 - position
        axes.barh(y, interval.high - interval.low, left=interval.low, height=0.5, color=colours[row], alpha=0.6)
        axes.plot([interval.estimate] * 2, [y - 0.32, y + 0.32], color="black", linewidth=1.6)
    if improvement:
        axes.axvline(EVEN[IMPROVEMENT], color="0.3", linestyle="--", linewidth=1)
        axes.set_xlim(-0.03, 1.03)
    else:
        axes.axvline(1.0, color="0.5", linestyle=":", linewidth=1)  # 1: the DAN mean the scores are divided by
        axes.margins(x=0.08)
    axes.set_yticks(range(len(bars)), [label for _, label, _ in reversed(bars)], fontsize=7)
    axes.set_ylim(-0.6, len(bars) - 0.4)
    axes.set_title(title, fontsize=9)
    axes.tick_params(axis="x", labelsize=7)
    axes.grid(axis="x", alpha=0.3)


def write_interval_figure(comparisons: Sequence[TableComparison], out: Path) -> dict[str, Path]:
    """Draw ``intervals.png`` into ``out`` when a comparison has an interval; returns ``{"intervals": path}`` or
    nothing."""
    path = out / INTERVALS_FIGURE
    return {"intervals": path} if draw_intervals(comparisons, path) is not None else {}
