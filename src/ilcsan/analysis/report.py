"""The paper's reward tables and learning curves, built from whatever runs exist on disk.

``ilcsan report DIR`` (and the end of ``ilcsan reproduce``) writes ``report.md``, ``report.tex``,
``report.csv`` and ``curves.png``. The work is done in four steps, one module each:

* :mod:`.collect`: find the runs below a folder and read them (damaged runs and duplicates are listed
  with the reason, never fatal);
* :mod:`.reward_tables`: group them into a table's cells (mean ± std over seeds of each run's max average
  reward) and rows (APR against DAN), with the paper's numbers beside ours;
* :mod:`.render`: the tables as Markdown, LaTeX and CSV;
* :mod:`.curves`: the learning curves as a PNG.

This module ties them together and names the public API of the report.
"""

from __future__ import annotations

from pathlib import Path

from ..files import atomic_write_text
from ..paper.layouts import TableSpec
from .collect import RunRecord, RunScan, SkippedRun, collect_runs, read_run, scan_runs
from .curves import curve, draw_curves, plot_curves, smooth, smoothing_window
from .render import format_stat, latex_escape, render_csv, render_latex, render_markdown
from .reward_tables import Cell, RowResult, TableResult, build_table, report_tables

REPORT_FILES: dict[str, str] = {
    "markdown": "report.md",
    "latex": "report.tex",
    "csv": "report.csv",
    "curves": "curves.png",
}
"""The files of a report by kind, as :func:`write_report` returns them."""


def write_report(directory: str | Path, out_dir: str | Path | None = None,
                 table: str | TableSpec | None = None) -> dict[str, Path]:
    """Scan ``directory`` for runs and write ``report.md``, ``report.tex``, ``report.csv`` and
    ``curves.png`` into ``out_dir`` (default: ``directory``), each atomically.

    Returns the paths by kind: ``{"markdown", "latex", "csv", "curves"}``.
    """
    scan = scan_runs(directory)
    out = Path(out_dir) if out_dir is not None else Path(directory)
    results = report_tables(scan.runs, table)
    paths = {kind: out / name for kind, name in REPORT_FILES.items()}
    atomic_write_text(paths["markdown"], render_markdown(results, scan.skipped))
    atomic_write_text(paths["latex"], render_latex(results, scan.skipped))
    atomic_write_text(paths["csv"], render_csv(results))
    draw_curves(results, paths["curves"])
    return paths


__all__ = [
    "write_report", "REPORT_FILES",
    "RunRecord", "RunScan", "SkippedRun", "scan_runs", "collect_runs", "read_run",
    "Cell", "RowResult", "TableResult", "build_table", "report_tables",
    "format_stat", "latex_escape", "render_markdown", "render_latex", "render_csv",
    "smooth", "smoothing_window", "curve", "plot_curves", "draw_curves",
]
