"""The paper's reward tables and learning curves, built from whatever runs exist on disk.

``ilcsan report DIR`` (and the end of ``ilcsan reproduce``) writes ``report.md``, ``report.tex``,
``report.csv``, ``comparison.csv`` and ``curves.png``. The work is done in five steps, one module each:

* :mod:`.collect`: find the runs below a folder and read them (damaged runs and duplicates are listed
  with the reason, never fatal);
* :mod:`.reward_tables`: group them into a table's cells (mean ± std over seeds of each run's max average
  reward) and rows (APR against DAN), with the paper's numbers beside ours;
* :mod:`.comparison`: what a stratified bootstrap can tell the rows apart (IQM, P(improvement), APR with
  intervals; rliable);
* :mod:`.render`: the tables as Markdown, LaTeX and CSV;
* :mod:`.curves`: the learning curves as a PNG.

This module ties them together and names the public API of the report.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass
from pathlib import Path

from ..files import atomic_write_text
from ..paper.layouts import TableSpec
from .collapse import COLLAPSE_RETURN, collapse_markdown, collapse_rows, plot_diagnostics
from .collect import RunFolders, RunRecord, RunScan, SkippedRun, collect_runs, folders_of, read_run, scan_runs
from .comparison import DEFAULT_BOOTSTRAP, Bootstrap, TableComparison, compare_table
from .curves import curve, draw_curves, plot_curves, smooth, smoothing_window
from .figures import INTERVALS_FIGURE, PAPER_FIGURES, write_interval_figure, write_paper_figures
from .render import (
    REPORT_TITLE,
    comparison_lines,
    format_stat,
    latex_escape,
    render_comparison_csv,
    render_csv,
    render_latex,
    render_markdown,
)
from .reward_tables import Cell, RowResult, TableResult, build_table, report_tables

DIAGNOSTICS_FIGURE = "diagnostics.png"
"""The figure of the actors' diagnostics that ``--collapse`` adds."""
REPORT_FILES: dict[str, str] = {
    "markdown": "report.md",
    "latex": "report.tex",
    "csv": "report.csv",
    "comparison": "comparison.csv",
    "curves": "curves.png",
}
"""The files of a report by kind, as :func:`write_report` returns them."""
OPTIONAL_FIGURES: tuple[str, ...] = (DIAGNOSTICS_FIGURE, INTERVALS_FIGURE,
                                     *(f"{figure.name}.png" for figure in PAPER_FIGURES))
"""The figures a report draws only when it has what they show; one left by an earlier report of the folder is
removed when this one does not draw it, so that every file of a report folder describes the same runs."""


def write_report(directories: RunFolders, out_dir: str | Path | None = None,
                 table: str | TableSpec | None = None, collapse_steps: Sequence[int] = (),
                 collapse_return: float = COLLAPSE_RETURN, seeds: Collection[int] | None = None,
                 bootstrap: Bootstrap = DEFAULT_BOOTSTRAP) -> dict[str, Path]:
    """Scan ``directories`` (one folder or several) for runs and write ``report.md``, ``report.tex``, ``report.csv``,
    ``comparison.csv`` and ``curves.png`` into ``out_dir`` (default: the folder, when it is one), each atomically.
    With ``seeds``, only the runs of those seeds count (rows compared on the same seeds), and the title says so. With
    ``collapse_steps``, report.md also counts each row's seeds below ``collapse_return`` at those steps
    (:mod:`.collapse`) and ``diagnostics.png`` draws their actors' diagnostics up to the last of them. ``bootstrap``:
    the replicates and seed of the intervals that tell rows apart (:mod:`.comparison`; report.md and comparison.csv).

    Returns the paths by kind: ``{"markdown", "latex", "csv", "comparison", "curves"}`` (and ``"diagnostics"``;
    ``"fig5"``, ``"fig6"``: the paper's figures, when Table perf has runs of both their rows, :mod:`.figures`;
    ``"intervals"``: ``intervals.png``, when an interval was computed).
    """
    roots = folders_of(directories)
    if out_dir is None and len(roots) != 1:
        raise ValueError("a report of several folders needs out_dir")
    out = Path(out_dir) if out_dir is not None else roots[0]
    return write_scanned_report(scan_runs(roots), out, table, collapse_steps, collapse_return, seeds, bootstrap).paths


@dataclass(frozen=True)
class WrittenReport:
    """What :func:`write_scanned_report` wrote (``paths`` by kind), the tables it wrote them from and what tells their
    rows apart (one per table)."""

    paths: dict[str, Path]
    results: list[TableResult]
    comparisons: list[TableComparison]


def write_scanned_report(scan: RunScan, out: Path, table: str | TableSpec | None = None,
                         collapse_steps: Sequence[int] = (), collapse_return: float = COLLAPSE_RETURN,
                         seeds: Collection[int] | None = None,
                         bootstrap: Bootstrap = DEFAULT_BOOTSTRAP) -> WrittenReport:
    """:func:`write_report` of runs already scanned, into the folder ``out``."""
    results = report_tables(runs_of_seeds(scan.runs, seeds), table)
    paths = {kind: out / name for kind, name in REPORT_FILES.items()}
    title = REPORT_TITLE + ("" if seeds is None else f": seeds {seed_text(seeds)} only")
    comparisons = [compare_table(result, bootstrap) for result in results]
    markdown = render_markdown(results, scan.skipped, title, comparisons)
    if collapse_steps:
        groups = collapse_groups(results)
        steps = sorted(collapse_steps)
        rows = collapse_rows(groups, steps, collapse_return, until=steps[-1])
        markdown += (f"\n## Collapsed start\n\nSeeds whose evaluation returned less than {collapse_return:g} at each "
                     f"step (best and last: up to step {steps[-1]:,}).\n\n".replace(",", " ")
                     + collapse_markdown(rows, steps, collapse_return))
        paths["diagnostics"] = plot_diagnostics(groups, out / DIAGNOSTICS_FIGURE, steps[-1], steps[-1],
                                                collapse_return)
    atomic_write_text(paths["markdown"], markdown)
    atomic_write_text(paths["latex"], render_latex(results, scan.skipped, title))
    atomic_write_text(paths["csv"], render_csv(results))
    atomic_write_text(paths["comparison"], render_comparison_csv(comparisons))
    draw_curves(results, paths["curves"])
    paths.update(write_paper_figures(results, out))
    paths.update(write_interval_figure(comparisons, out))
    remove_stale_figures(out, paths.values())
    return WrittenReport(paths, results, comparisons)


def remove_stale_figures(out: Path, written: Collection[Path]) -> list[Path]:
    """Remove from ``out`` each of :data:`OPTIONAL_FIGURES` that this report did not write (``written``); returns
    the removed paths."""
    stale = [out / name for name in OPTIONAL_FIGURES if out / name not in set(written) and (out / name).exists()]
    for path in stale:
        path.unlink()
    return stale


def runs_of_seeds(runs: Sequence[RunRecord], seeds: Collection[int] | None) -> list[RunRecord]:
    """The runs of ``seeds`` (all of them when None), in their order."""
    return list(runs) if seeds is None else [run for run in runs if run.seed in seeds]


def seed_text(seeds: Collection[int]) -> str:
    """Seeds in words, runs of consecutive ones as ranges: {0, 1, 2, 5} → ``0–2, 5``."""
    parts: list[tuple[int, int]] = []
    for seed in sorted(set(seeds)):
        if parts and parts[-1][1] == seed - 1:
            parts[-1] = (parts[-1][0], seed)
        else:
            parts.append((seed, seed))
    return ", ".join(str(low) if low == high else f"{low}–{high}" for low, high in parts)


def collapse_groups(results: Sequence[TableResult]) -> dict[str, list[RunRecord]]:
    """Each row's seed runs, per task when a table has several: the groups the collapse statistics compare."""
    groups: dict[str, list[RunRecord]] = {}
    for result in results:
        for row in result.rows:
            for cell in row.cells:
                if cell.runs:
                    label = row.label if len(result.tasks) == 1 else f"{row.label} ({cell.task})"
                    groups.setdefault(label, []).extend(cell.runs)
    return groups


__all__ = [
    "write_report", "write_scanned_report", "WrittenReport", "REPORT_FILES", "runs_of_seeds",
    "RunRecord", "RunScan", "SkippedRun", "scan_runs", "collect_runs", "read_run",
    "Cell", "RowResult", "TableResult", "build_table", "report_tables",
    "Bootstrap", "TableComparison", "compare_table", "render_comparison_csv",
    "format_stat", "latex_escape", "render_markdown", "render_latex", "render_csv", "comparison_lines",
    "smooth", "smoothing_window", "curve", "plot_curves", "draw_curves",
]
