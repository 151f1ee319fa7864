"""A report's tables as text: Markdown, LaTeX (booktabs) and CSV.

Every cell shows our value and, where the paper has one for that (table, row, task), the published
value beside it: ``3583 ± 86 (n=3) · paper 3583 ± 86``; a cell without runs shows ``—``; the best mean
of each column and the best APR are in bold. Under a table, one line per cell whose runs differ in code, precision,
libraries or CPU (their ``provenance.json``, :mod:`ilcsan.runs.provenance`), and one line in plain words per cell
beside a published value (:func:`paper_comparison`); after each table, what the bootstrap can tell its rows apart
(:mod:`.comparison`), also in ``comparison.csv`` (:func:`render_comparison_csv`).
"""

from __future__ import annotations

import csv
import io
import math
import statistics
from collections import Counter
from collections.abc import Sequence

from ..config import CONTACT_FORCE_TASKS
from ..paper.layouts import STEPS
from ..runs.directory import DIAGNOSTICS
from ..runs.provenance import differences
from ..snn.diagnostics import STUCK_EVALUATIONS
from .collect import SkippedRun
from .comparison import Aggregate, Comparison, Interval, TableComparison
from .followups import FOLLOW_UPS, NOT_FOUND
from .reward_tables import Cell, RowResult, TableResult

DIAGNOSTIC_HEADERS = {"saturated_actions": "Saturated", "action_spread": "Action spread",
                      "frozen_output_neurons": "Frozen outputs",
                      "surrogate_active": "Surrogate window", "mean_abs_preaction": "Mean abs(O)"}
REPORT_TITLE = "ILC-SAN reproduction report"
"""The heading of report.md (and first comment of report.tex)."""


def _decimals(value: float) -> int:
    magnitude = abs(value)
    return 0 if magnitude >= 100 else 1 if magnitude >= 10 else 2


def format_stat(mean: float, std: float | None) -> str:
    """``3583 ± 86``: integers as in the paper for |mean| ≥ 100, more decimals for small returns; the mean
    alone where there is no spread (one seed)."""
    places = _decimals(mean)
    return f"{mean:.{places}f}" if std is None else f"{mean:.{places}f} ± {std:.{places}f}"


def _our_stat(cell: Cell) -> str:
    return "" if cell.mean is None else format_stat(cell.mean, cell.std)


def _seed_count(cell: Cell) -> str:
    return f"n={cell.n}, {cell.running} running" if cell.running else f"n={cell.n}"


def _paper_stat(cell: Cell) -> str:
    return format_stat(cell.paper.mean, cell.paper.std) if cell.paper else ""


def _apr_parts(row: RowResult, n_tasks: int) -> tuple[str, str]:
    """(``98.61%``, `` (3/4 tasks)`` when the APR averages fewer tasks than the table has)."""
    if row.apr is None:
        return "", ""
    partial = f" ({row.apr_tasks}/{n_tasks} tasks)" if row.apr_tasks < n_tasks else ""
    return f"{row.apr:.2f}%", partial


def _md_escape(text: str) -> str:
    for char in ("\\", "|", "*", "_"):
        text = text.replace(char, "\\" + char)
    return text


def _md_cell(cell: Cell) -> str:
    ours = _our_stat(cell)
    text = "—" if not ours else (f"**{ours}**" if cell.best else ours) + f" ({_seed_count(cell)})"
    return text + (f" · paper {_paper_stat(cell)}" if cell.paper else "")


def _md_apr(row: RowResult, n_tasks: int) -> str:
    ours, partial = _apr_parts(row, n_tasks)
    text = "—" if not ours else (f"**{ours}**" if row.best_apr else ours) + partial
    return text + (f" · paper {row.paper_apr:.2f}%" if row.paper_apr is not None else "")


def render_markdown(results: TableResult | Sequence[TableResult], skipped: Sequence[SkippedRun] = (),
                    title: str = REPORT_TITLE, comparisons: Sequence[TableComparison] = ()) -> str:
    """The tables as Markdown, with the statistics explained, missing cells and skipped runs listed; ``comparisons``
    (one per table, in the same order, or none) after their tables."""
    results = [results] if isinstance(results, TableResult) else list(results)
    lines = [f"# {title}", ""]
    if not results:
        lines += ["No runs found.", ""]
    for result, comparison in zip(results, comparisons or [None] * len(results), strict=True):
        lines += _md_table(result, comparison)
    lines += [
        "Cell: max average reward, i.e. each seed run's best evaluation (mean return over its evaluation "
        "episodes), as mean ± std over seeds (sample std, ddof=1), n = number of seeds; bold = best of "
        "the column; `—` = no runs (missing). APR = mean over tasks of (cell / DAN cell), only over tasks "
        "where both exist. \"paper\" = the published value for the same table, row and task (in a grid of our "
        "own, of the paper's table and row that ran the same actor and method).",
        "",
    ]
    if skipped:
        lines += ["## Skipped runs", ""]
        lines += [f"- `{run.path}`: {run.reason}" for run in skipped]
        lines.append("")
    return "\n".join(lines)


def _md_table(result: TableResult, comparison: TableComparison | None = None) -> list[str]:
    heading = f"## Table `{result.name}`: {result.caption}" if result.name else f"## {result.caption}"
    header = ["Row", *result.tasks, "APR"]
    lines = [heading, "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in result.rows:
        label = _md_escape(row.label) + ("" if row.runnable else " (paper only)")
        cells = [_md_cell(cell) for cell in row.cells]
        lines.append("| " + " | ".join([label, *cells, _md_apr(row, len(result.tasks))]) + " |")
    lines += ["", f"APR reference (DAN): {result.reference}."]
    budget = budget_text(result)
    if budget:
        lines.append(budget)
    missing = result.missing
    if missing:
        total = sum(len(row.cells) for row in result.rows if row.runnable)
        lines.append(f"Missing cells (no runs): {len(missing)} of {total}: {_missing_text(result)}.")
    comparisons = comparison_lines(result, _md_escape)
    if comparisons:
        lines += ["", "Beside the paper (a cell's mean against the published mean ± std; seeds: how many of ours "
                  "scored within that range):", "", *(f"- {line}" for line in comparisons)]
    lines.append("")
    lines += _md_comparison(comparison) if comparison else []
    notes = provenance_notes(result)
    if notes:
        lines += ["Provenance (each run's `provenance.json` and contact forces; ×k: how many runs have a segment so):",
                  "", *(f"- {_md_escape(note)}" for note in notes), ""]
    return lines + _md_follow_ups(result) + _md_seeds(result)


def _md_comparison(comparison: TableComparison) -> list[str]:
    """The section on telling the table's rows apart (:mod:`.comparison`): what the statistics are, then one
    sentence each."""
    sentences = comparison.sentences(_md_escape)
    if not sentences:
        return []
    return ["### Telling the rows apart", "",
            f"{comparison.bootstrap.text}. Per row: the IQM and the mean over runs × tasks of its scores divided "
            "by our DAN's mean on each task (the ratio the APR averages) or by the paper's published DAN mean, "
            "each mean taken as exact: the interval holds the row's seed noise, not DAN's. Per "
            "pair: P(improvement), the chance that a run of one row scores above a run of the other on the same task, "
            "averaged over tasks (0.5: even), and the APR on the same runs (100 %: even); *better*/*worse*: the "
            "interval lies entirely above/below even; then each task's value, which the whole averages (every "
            "margin counts alike in P(improvement): a task where both rows sit at its ceiling can give 0 or 1). Runs "
            "are paired by seed: each task offers the seeds both rows ran; every task with ≥ 2 of them is kept, "
            "each giving its first k, k the fewest among those tasks.", "",
            *(f"- {sentence}" for sentence in sentences), ""]


def comparison_lines(result: TableResult, escape=lambda text: text) -> list[str]:
    """One line per cell with runs and a published value: ``Hopper · ILC-SAN: 3104 ± 1086 (n=10) against
    3583 ± 86: below …`` (:func:`paper_comparison`); ``escape`` the row labels for the output's format."""
    return [f"{cell.task} · {escape(row.label)}: {_our_stat(cell)} (n={cell.n}) against {_paper_stat(cell)}: {words}"
            for row in result.rows for cell in row.cells if (words := paper_comparison(cell))]


def paper_comparison(cell: Cell) -> str | None:
    """A cell beside its published value in plain words: *not comparable* when a run trained fewer steps than the
    paper's protocol (:data:`STEPS`) or is still training; else *within the paper's std* when
    |ours − paper| ≤ the published std, or *above*/*below* its mean by how much (also in units of that std); and
    on how many seeds ours scored within the published mean ± std. None without runs or a published value."""
    if cell.mean is None or cell.paper is None:
        return None
    fewest = min(run.steps_done for run in cell.runs)
    if fewest < STEPS:
        return f"not comparable: a run trained {_steps(fewest)} steps, the paper's protocol {_steps(STEPS)}"
    if cell.running:
        return f"not comparable yet: {cell.running} of {cell.n} runs still training"
    paper, difference = cell.paper, cell.mean - cell.paper.mean
    amount = f"{abs(difference):.{_decimals(paper.mean)}f}"  # as precise as the published mean
    ratio = abs(difference) / paper.std if paper.std else None
    units = [] if ratio is None else [f"{ratio:.{2 if ratio < 0.1 else 1}f} of its std"]
    if abs(difference) <= paper.std:
        words = f"within the paper's std ({', '.join([('+' if difference >= 0 else '−') + amount, *units])})"
    else:
        words = " ".join([f"{'above' if difference > 0 else 'below'} the paper's mean by {amount}",
                          *(f"({unit})" for unit in units)])
    inside = sum(abs(score - paper.mean) <= paper.std for score in cell.scores)
    return f"{words}; {inside} of {cell.n} seed{'s' * (cell.n != 1)} within the paper's mean ± std"


def provenance_notes(result: TableResult) -> list[str]:
    """One line per cell whose runs differ in code, precision, libraries or CPU, or recorded them only in part
    (:func:`~ilcsan.runs.provenance.differences`): ``Hopper · I_intra: runs differ in CPU (...)``; and per cell whose
    contact forces differ between its runs or are not the paper's (:func:`contact_forces_note`)."""
    notes = []
    for row in result.rows:
        for cell in row.cells:
            for text in (differences([run.provenance for run in cell.runs]), contact_forces_note(cell.task, cell.runs)):
                if text:
                    notes.append(f"{cell.task} · {row.label}: {text}.")
    return notes


def contact_forces_note(task: str, runs: Sequence) -> str | None:
    """Whether a cell's runs read their task's contact forces in more than one way, or all as MuJoCo simulates them
    on a paper task whose simulator read zeros (:data:`~ilcsan.config.CONTACT_FORCE_TASKS`); None otherwise."""
    counts = Counter(run.contact_forces for run in runs)
    if len(counts) > 1:
        return "runs differ in contact forces (" + ", ".join(f"{name} ×{count}" for name, count in
                                                             sorted(counts.items())) + ")"
    if task in CONTACT_FORCE_TASKS and set(counts) == {"simulated"}:
        return ("contact forces simulated: not the paper's states, whose contact forces read zero "
                "(--contact-forces zeroed)")
    return None


def _diagnostic(run, name: str) -> str:
    values = run.diagnostics.get(name, ())
    return f"{values[-1]:.2f}" if values and math.isfinite(values[-1]) else "—"


def _md_seeds(result: TableResult) -> list[str]:
    """Every seed run of the table: its best and last evaluation and the actor's diagnostics at its last evaluation
    (:mod:`ilcsan.snn.diagnostics`), with the seeds stuck in one constant saturated action marked."""
    runs = [(row, cell, run) for row in result.rows for cell in row.cells for run in cell.runs]
    if not runs:
        return []
    stuck = sum(run.stuck for _, _, run in runs)
    header = ["Row", "Task", "Seed", "Best (step)", "Last", "Steps", "Wall time", "Steps/s, median (range)",
              *(DIAGNOSTIC_HEADERS[name] for name in DIAGNOSTICS), "Stuck"]
    lines = [f"Seed runs of `{result.name or result.caption}` ({len(runs)}; stuck at their last evaluations: {stuck}). "
             "Diagnostics at the last evaluation: share of saturated actions, of output neurons with the same spike "
             "train for every replayed state, of output-neuron steps inside the surrogate window, mean |pre-tanh "
             "output|, and the action spread (the largest range of an action component over the evaluation, in units "
             "of its full range); stuck = one constant action, saturated or decoded from frozen output neurons, at the "
             f"last {STUCK_EVALUATIONS} evaluations after the random phase. Wall time: the training process's to the "
             "steps done, resumes included (seeds stacked in one process share it). Steps/s: the training speed "
             "between evaluations after the first (which holds the start and compilation), median and range; a "
             "range reaching far below the median shows time the process did not train (stopped, restarting to "
             "resume, or sharing its core).", "",
             "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row, cell, run in runs:
        values = [_md_escape(row.label), cell.task, str(run.seed), f"{run.best_return:.1f} ({_steps(run.best_step)})",
                  f"{run.returns[-1]:.1f}" if run.returns else "—", _steps(run.steps_done), _hours(run.wall_seconds),
                  _speed(run.steps_per_second), *(_diagnostic(run, name) for name in DIAGNOSTICS),
                  "**stuck**" if run.stuck else ""]
        lines.append("| " + " | ".join(values) + " |")
    return [*lines, ""]


def _speed(steps_per_second: Sequence[float]) -> str:
    """Median (min–max) of the speeds after the first evaluation; "—" when none was recorded."""
    speeds = [value for value in steps_per_second[1:] if math.isfinite(value)]
    if not speeds:
        return "—"
    return f"{statistics.median(speeds):.0f} ({min(speeds):.0f}–{max(speeds):.0f})"


def _hours(seconds: float | None) -> str:
    return "—" if seconds is None else f"{seconds / 3600:.1f} h"


def _steps(count: int) -> str:
    return f"{count:,}".replace(",", " ")


def _step_range(cell: Cell) -> tuple[int | str, int | str]:
    steps = [run.steps_done for run in cell.runs]
    return (min(steps), max(steps)) if steps else ("", "")


def budget_text(result: TableResult) -> str | None:
    """The steps the table's seed runs trained (one figure, or the range when cells differ), and a warning when a
    cell shown beside the paper's value trained fewer steps than the paper's protocol (:data:`STEPS`): such a
    cell is not the paper's protocol and its value is not comparable with the published one."""
    cells = [cell for row in result.rows for cell in row.cells]
    budgets = sorted({run.steps_done for cell in cells for run in cell.runs})
    if not budgets:
        return None
    text = (f"Steps per seed run: {_steps(budgets[0])}" if len(budgets) == 1 else
            f"Steps per seed run: {_steps(budgets[0])} to {_steps(budgets[-1])} (they differ between runs)")
    short = sum(1 for cell in cells if cell.paper and any(run.steps_done < STEPS for run in cell.runs))
    if short:
        text += (f"; {short} cell(s) beside a published value trained fewer than the paper's {_steps(STEPS)} steps: "
                 "not its protocol, not comparable with the published number")
    return text + "."


def _md_follow_ups(result: TableResult) -> list[str]:
    """The numbers later papers published for this table's tasks (:mod:`ilcsan.analysis.followups`), as their
    own small tables under ours: other runs, other protocols."""
    lines = []
    for published in FOLLOW_UPS.get(result.name or "", ()):
        tasks = [task for task in result.tasks if any(task in cells for cells in published.rows.values())]
        if not tasks:
            continue
        lines += [f"Published by {published.source} ({published.protocol}; not our runs):", "",
                  "| Row | " + " | ".join(tasks) + " |", "|" + "---|" * (len(tasks) + 1)]
        for label, cells in published.rows.items():
            values = [format_stat(cells[task].mean, cells[task].std) if task in cells else "—" for task in tasks]
            lines.append("| " + " | ".join([_md_escape(label), *values]) + " |")
        lines.append("")
    notes = NOT_FOUND.get(result.name or "", ())
    return [*lines, *notes, ""] if notes else lines


def _missing_text(result: TableResult) -> str:
    """Missing cells grouped by row: ``PopSAN: all tasks; I_self: Walker2d``."""
    parts = []
    for row in result.rows:
        tasks = [cell.task for cell in row.cells if not cell.n]
        if row.runnable and tasks:
            listed = "all tasks" if len(tasks) == len(row.cells) else ", ".join(tasks)
            parts.append(f"{_md_escape(row.label)}: {listed}")
    return "; ".join(parts)


_LATEX_SPECIAL = {
    "\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
    "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
    "α": r"$\alpha$", "±": r"$\pm$", "—": "--", "·": r"$\cdot$",
}


def latex_escape(text: str) -> str:
    """Escape LaTeX's special characters (and map α, ±, —, · to math or ASCII)."""
    return "".join(_LATEX_SPECIAL.get(char, char) for char in text)


def _tex_cell(cell: Cell) -> str:
    ours = _our_stat(cell)
    value = "--" if not ours else latex_escape(ours)
    value = rf"\textbf{{{value}}}" if cell.best else value
    notes = [_seed_count(cell)] if ours else []
    if cell.paper:
        notes.append("paper " + latex_escape(_paper_stat(cell)))
    return value + (rf" {{\scriptsize ({'; '.join(notes)})}}" if notes else "")


def _tex_apr(row: RowResult, n_tasks: int) -> str:
    ours, partial = _apr_parts(row, n_tasks)
    value = "--" if not ours else latex_escape(ours)
    value = (rf"\textbf{{{value}}}" if row.best_apr else value) + partial
    if row.paper_apr is not None:
        value += rf" {{\scriptsize (paper {row.paper_apr:.2f}\%)}}"
    return value


def render_latex(results: TableResult | Sequence[TableResult], skipped: Sequence[SkippedRun] = (),
                 title: str = REPORT_TITLE) -> str:
    """The tables as LaTeX ``table*`` environments with booktabs rules (needs ``\\usepackage{booktabs}``)."""
    results = [results] if isinstance(results, TableResult) else list(results)
    lines = [f"% {title}; requires \\usepackage{{booktabs}}",
             "% Cells: mean $\\pm$ std over seeds (ddof=1) of each run's max average reward; -- = no runs."]
    for result in results:
        label = f"tab:ours-{result.name}" if result.name else "tab:ours"
        lines += [
            r"\begin{table*}[t]",
            rf"\caption{{{latex_escape(result.caption)} (this reproduction)}}",
            rf"\label{{{latex_escape(label)}}}",
            r"\centering",
            r"\resizebox{\textwidth}{!}{",
            rf"\begin{{tabular}}{{l{'c' * (len(result.tasks) + 1)}}}",
            r"\toprule",
            " & ".join(["Row", *map(latex_escape, result.tasks), "APR"]) + r" \\",
            r"\midrule",
        ]
        for row in result.rows:
            cells = [_tex_cell(cell) for cell in row.cells]
            apr = _tex_apr(row, len(result.tasks))
            lines.append(" & ".join([latex_escape(row.label), *cells, apr]) + r" \\")
        lines += [r"\bottomrule", r"\end{tabular}}", r"\end{table*}"]
        budget = budget_text(result)
        lines += ([f"% {budget}"] if budget else []) + [f"% {note}" for note in provenance_notes(result)] + [""]
    lines += [f"% skipped {run.path}: {run.reason}".replace("\n", " ") for run in skipped]
    return "\n".join(lines) + "\n"


CSV_COLUMNS: tuple[str, ...] = (
    "table", "row", "label", "task", "kind", "status", "n", "running", "mean", "std", "best",
    "paper_mean", "paper_std", "steps_min", "steps_max",
)
"""Long format: one line per (row, task) cell (``kind`` = reward; ``steps_min``/``steps_max``: the fewest and most
steps its seed runs trained) and one per row for its APR (``kind`` = apr, ``task`` = APR, ``n`` = number of tasks
averaged, ``mean`` = APR in percent)."""


def render_csv(results: TableResult | Sequence[TableResult]) -> str:
    """The tables in long format (:data:`CSV_COLUMNS`); ``status`` is ok, running or missing."""
    results = [results] if isinstance(results, TableResult) else list(results)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for result in results:
        for row in result.rows:
            for cell in row.cells:
                status = "missing" if not cell.n else "running" if cell.running else "ok"
                writer.writerow([
                    result.name or "", row.key, row.label, cell.task, "reward", status, cell.n, cell.running,
                    _csv_number(cell.mean), _csv_number(cell.std), int(cell.best),
                    _csv_number(cell.paper.mean if cell.paper else None),
                    _csv_number(cell.paper.std if cell.paper else None),
                    *_step_range(cell),
                ])
            status = "ok" if row.apr is not None else "missing"
            writer.writerow([
                result.name or "", row.key, row.label, "APR", "apr", status, row.apr_tasks, "",
                _csv_number(row.apr), "", int(row.best_apr), _csv_number(row.paper_apr), "", "", "",
            ])
    return buffer.getvalue()


COMPARISON_COLUMNS: tuple[str, ...] = (
    "table", "statistic", "row", "against", "estimate", "ci_low", "ci_high", "confidence", "verdict", "tasks",
    "seeds_per_task", "seeds", "left_out", "note", "per_task", "reps", "bootstrap_seed",
)
"""``comparison.csv``: one line per statistic of :mod:`.comparison` (``statistic`` iqm, mean,
probability_of_improvement, apr or note; ``against`` the other row or the normaliser; ``seeds`` per task, e.g.
``Ant:0 1 2;Hopper:0 1 2``; ``note`` why a statistic was not computed, or a note on the whole table; ``per_task`` a
comparison's statistic on each task, e.g. ``Ant:0.7777777777777778;Hopper:0.6666666666666666``)."""


def render_comparison_csv(comparisons: Sequence[TableComparison]) -> str:
    """Every table's :class:`~.comparison.TableComparison` in :data:`COMPARISON_COLUMNS`."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(COMPARISON_COLUMNS)
    for comparison in comparisons:
        settings = [comparison.bootstrap.reps, comparison.bootstrap.seed]
        for item in comparison.aggregates:
            for statistic, interval in (("iqm", item.iqm), ("mean", item.mean)):
                writer.writerow([comparison.table, statistic, item.row, item.normaliser,
                                 *_csv_interval(interval, None), *_csv_selection(item), "", *settings])
        for item in comparison.comparisons:
            per_task = ";".join(f"{task}:{_csv_number(value)}" for task, value in
                                zip(item.selection.tasks, item.per_task, strict=True)) if item.per_task else ""
            writer.writerow([comparison.table, item.statistic, item.row, item.against,
                             *_csv_interval(item.interval, item.verdict), *_csv_selection(item), per_task, *settings])
        for note in comparison.notes:
            blank = [""] * (COMPARISON_COLUMNS.index("note") - 2)  # no row, interval or selection
            writer.writerow([comparison.table, "note", *blank, note, "", *settings])
    return buffer.getvalue()


def _csv_interval(interval: Interval | None, verdict: str | None) -> list[str]:
    """estimate, ci_low, ci_high, confidence, verdict."""
    if interval is None:
        return [""] * 5
    return [*map(_csv_number, (interval.estimate, interval.low, interval.high, interval.confidence)), verdict or ""]


def _csv_selection(item: Aggregate | Comparison) -> list[str | int]:
    """tasks, seeds_per_task, seeds, left_out, note."""
    selection = item.selection
    seeds = ";".join(f"{task}:{' '.join(map(str, chosen))}"
                     for task, chosen in zip(selection.tasks, selection.seeds, strict=True))
    note = "" if selection.k else f"not computed: {selection.too_few}"
    return [";".join(selection.tasks), selection.k, seeds, selection.left_out_text, note]


def _csv_number(value: float | None) -> str:
    return "" if value is None else repr(float(value))
