"""The report built from synthetic run directories written by hand (ilcsan.analysis.report)."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from ilcsan.analysis.collect import collect_runs, scan_runs
from ilcsan.analysis.curves import curve, plot_curves, smooth, smoothing_window
from ilcsan.analysis.render import format_stat, render_csv, render_latex, render_markdown
from ilcsan.analysis.report import write_report
from ilcsan.analysis.reward_tables import build_table, report_tables
from ilcsan.cli import build_parser
from ilcsan.cli.grid_commands import cmd_report
from ilcsan.config import actor_config
from ilcsan.experiments.grid import report_layout
from ilcsan.paper.layouts import TABLES

HEADER = "step,eval_return_mean,eval_return_std,eval_length_mean,wall_seconds,steps_per_second"


def make_run(root: Path, task: str, seed: int, label: str, returns: list[float], *,
             table: str | None = None, row: str | None = None, preset: str = "ilc-san",
             result: bool = True, finished: bool = True, every: int = 10_000, subdir: str | None = None,
             wall_seconds: float | None = None) -> Path:
    """Write config.json, metrics.csv and (optionally) result.json the way the trainer does."""
    name = subdir or f"{table or 'free'}/{task}/{row or label}/seed{seed}"
    run = root / name
    run.mkdir(parents=True)
    config = {"task": task, "seed": seed, "label": label, "actor": {"preset": preset}}
    if table:
        config |= {"table": table, "row": row}
    (run / "config.json").write_text(json.dumps(config))
    lines = [HEADER] + [f"{(i + 1) * every},{value},1.0,1000,{i + 1.0},100.0" for i, value in enumerate(returns)]
    (run / "metrics.csv").write_text("\n".join(lines) + "\n")
    if result:
        best = int(np.argmax(returns))
        (run / "result.json").write_text(json.dumps({
            "best_return": returns[best], "best_step": (best + 1) * every, "steps_done": len(returns) * every,
            "steps_total": 1_000_000, "finished": finished}
            | ({} if wall_seconds is None else {"wall_seconds": wall_seconds})))
    return run


def intra_run(root: Path, task: str, row: str, seed: int, returns: list[float], **kwargs) -> Path:
    labels = {"intra": "I_intra", "none": "No I_intra", "self": "I_self"}
    return make_run(root, task, seed, labels[row], returns, table="intra", row=row, **kwargs)


# ------------------------------------------------------------------------------------------------
# Cells: max average reward, mean ± std over seeds


def test_cell_is_mean_and_sample_std_of_each_seeds_best_evaluation(tmp_path: Path) -> None:
    intra_run(tmp_path, "Hopper", "intra", 0, [1000, 3500, 3200])
    intra_run(tmp_path, "Hopper", "intra", 1, [3600, 2000, 3000])
    intra_run(tmp_path, "Hopper", "intra", 2, [10, 20, 3650], result=False)  # still running: metrics.csv
    cell = build_table(collect_runs(tmp_path), "intra").cell("intra", "Hopper")
    assert cell.scores == (3500, 3600, 3650)
    assert cell.n == 3 and cell.running == 1
    assert cell.mean == pytest.approx(10750 / 3)
    # deviations −250/3, 50/3, 200/3 → variance (62500 + 2500 + 40000) / 9 / (3 − 1) (ddof=1)
    assert cell.std == pytest.approx(math.sqrt(35000 / 6))
    assert cell.std != pytest.approx(np.std([3500, 3600, 3650], ddof=0))


def test_each_seed_run_shows_its_training_wall_time_when_recorded(tmp_path: Path) -> None:
    intra_run(tmp_path, "Hopper", "intra", 0, [1000, 3500], wall_seconds=5.25 * 3600)
    intra_run(tmp_path, "Hopper", "intra", 1, [900, 3400])  # a run written before wall_seconds was recorded
    lines = render_markdown(build_table(collect_runs(tmp_path), "intra")).splitlines()
    header = next(line for line in lines if line.startswith("| Row | Task | Seed |")).split(" | ")
    rows = {line.split(" | ")[2]: line.split(" | ") for line in lines if line.startswith("| I\\_intra | Hopper |")}
    column = header.index("Wall time")
    assert (rows["0"][column], rows["1"][column]) == ("5.2 h", "—")


def test_each_seed_run_shows_its_training_speed_after_the_first_evaluation(tmp_path: Path) -> None:
    """Median and range of steps/s over the evaluations after the first (which holds the start); a run whose
    metrics.csv has no speed column shows —."""
    run = intra_run(tmp_path, "Hopper", "intra", 0, [1000, 3500, 3400, 3300, 3200])
    speeds = [3.0, 400.0, 300.0, 5.0, 350.0]  # started (3), trained, stopped (5)
    (run / "metrics.csv").write_text("\n".join(
        [HEADER] + [f"{(i + 1) * 10_000},{value},1.0,1000,{i + 1.0},{speed}"
                    for i, (value, speed) in enumerate(zip([1000, 3500, 3400, 3300, 3200], speeds, strict=True))]))
    bare = intra_run(tmp_path, "Hopper", "intra", 1, [900, 3400])
    (bare / "metrics.csv").write_text("step,eval_return_mean\n10000,900\n20000,3400\n")
    lines = render_markdown(build_table(collect_runs(tmp_path), "intra")).splitlines()
    header = next(line for line in lines if line.startswith("| Row | Task | Seed |")).split(" | ")
    rows = {line.split(" | ")[2]: line.split(" | ") for line in lines if line.startswith("| I\\_intra | Hopper |")}
    column = header.index("Steps/s, median (range)")
    assert (rows["0"][column], rows["1"][column]) == ("325 (5–400)", "—")


def test_a_one_seed_cell_shows_its_mean_without_a_spread(tmp_path: Path) -> None:
    intra_run(tmp_path, "Hopper", "intra", 0, [1000, 3500, 3200])
    cell = build_table(collect_runs(tmp_path), "intra").cell("intra", "Hopper")
    assert (cell.n, cell.mean, cell.std) == (1, 3500, None)
    markdown = (write_report(tmp_path)["markdown"]).read_text()
    assert re.search(r"\| (\*\*)?3500(\*\*)? \(n=1\) ·", markdown), "one seed: its mean, no ± and no crash"


def test_the_report_states_the_budget_and_flags_short_cells_beside_the_papers_values(tmp_path: Path) -> None:
    intra_run(tmp_path / "short", "Hopper", "intra", 0, [1000, 3500, 3200])  # 30 000 steps
    short = render_markdown(build_table(collect_runs(tmp_path / "short"), "intra"))
    assert "Steps per seed run: 30 000; 1 cell(s) beside a published value trained fewer than the paper's " \
           "1 000 000 steps: not its protocol" in short
    intra_run(tmp_path / "full", "Hopper", "intra", 0, [3000.0] * 100)  # 100 evaluations every 10 000 steps
    intra_run(tmp_path / "full", "Hopper", "none", 0, [2000.0] * 100)
    full = render_markdown(build_table(collect_runs(tmp_path / "full"), "intra"))
    assert "Steps per seed run: 1 000 000." in full and "not comparable" not in full
    intra_run(tmp_path / "full", "Ant", "intra", 0, [900.0, 950.0])  # a second budget in the same table
    mixed = render_markdown(build_table(collect_runs(tmp_path / "full"), "intra"))
    assert "Steps per seed run: 20 000 to 1 000 000 (they differ between runs); 1 cell(s)" in mixed


def test_result_json_is_the_score_when_present(tmp_path: Path) -> None:
    run = intra_run(tmp_path, "Ant", "intra", 0, [100, 200])
    result = json.loads((run / "result.json").read_text())
    result["best_return"] = 250.0  # e.g. an evaluation the trainer did not log to metrics.csv
    (run / "result.json").write_text(json.dumps(result))
    (record,) = collect_runs(tmp_path)
    assert record.best_return == 250.0 and record.finished
    assert record.steps == (10_000, 20_000) and record.returns == (100, 200)


def test_paper_value_appears_beside_ours_for_a_known_cell(tmp_path: Path) -> None:
    intra_run(tmp_path, "Hopper", "intra", 0, [3500])
    intra_run(tmp_path, "Hopper", "intra", 1, [3600])
    intra_run(tmp_path, "Hopper", "intra", 2, [3650])
    result = build_table(collect_runs(tmp_path), "intra")
    cell = result.cell("intra", "Hopper")
    assert (cell.paper.mean, cell.paper.std) == (3583, 86)
    markdown = render_markdown(result)
    assert "**3583 ± 76** (n=3) · paper 3583 ± 86" in markdown
    assert "paper 98.61%" in markdown  # the published APR of I_intra
    latex = render_latex(result)
    assert r"\textbf{3583 $\pm$ 76} {\scriptsize (n=3; paper 3583 $\pm$ 86)}" in latex
    lines = list(csv.DictReader(io.StringIO(render_csv(result))))
    (line,) = [line for line in lines if line["row"] == "intra" and line["task"] == "Hopper"]
    assert float(line["mean"]) == pytest.approx(10750 / 3)
    assert (line["n"], line["status"], line["paper_mean"], line["paper_std"]) == ("3", "ok", "3583.0", "86.0")
    assert (line["steps_min"], line["steps_max"]) == ("10000", "10000")  # one evaluation each, at 10 000 steps
    assert "% Steps per seed run: 10 000; 1 cell(s) beside a published value" in latex


def test_the_beyond_table_prints_what_later_papers_published_under_ours_for_its_tasks(tmp_path: Path) -> None:
    make_run(tmp_path, "Hopper", 0, "ILC-SAN", [1500.0], table="beyond", row="ilc-san")
    markdown = render_markdown(build_table(collect_runs(tmp_path), "beyond"))
    ours, published = markdown.split("Published by Xu et al., Proxy Target")
    assert "**1500** (n=1)" in ours and "3526" not in ours, "published numbers stay out of our cells"
    assert "| PT-CLIF (pop-SAN-style CLIF actor + Proxy Target) | 3526 ± 112 |" in published
    assert "| ILC-SAN | 3403 ± 148 |" in published and "Walker2d" not in published  # only this table's tasks
    assert "NoisySAN (Chen et al., arXiv 2403.04162): no results table" in published
    intra = render_markdown(build_table(collect_runs(tmp_path), "intra"))
    assert "Published by" not in intra
    assert "CaRe-BN" not in markdown, "each table names only its own rows' papers"
    algorithms = render_markdown(build_table(collect_runs(tmp_path), "algorithms"))
    assert "CaRe-BN (Xu et al., ICLR 2026, arXiv 2509.23791): its results table was in none" in algorithms
    assert "unverified" in algorithms and "NoisySAN" not in algorithms


def test_the_beyond_rows_that_ran_the_papers_actors_show_its_table_perf_cells_but_not_its_apr(tmp_path: Path) -> None:
    make_run(tmp_path, "Hopper", 0, "ILC-SAN", [3000.0] * 100, table="beyond", row="ilc-san")  # 1 000 000 steps
    make_run(tmp_path, "Hopper", 0, "DAN", [3400.0] * 100, table="beyond", row="dan", preset="dan")
    make_run(tmp_path, "Hopper", 0, "ILC-SAN + Proxy Target", [3100.0] * 100, table="beyond", row="ilc-san+proxy")
    result = build_table(collect_runs(tmp_path), "beyond")
    perf = build_table([], "perf")
    assert result.cell("ilc-san", "Hopper").paper == perf.cell("ilc-san-pop-det", "Hopper").paper
    assert result.cell("dan", "Hopper").paper == perf.cell("dan", "Hopper").paper
    assert result.cell("ilc-san+proxy", "Hopper").paper is None  # the paper never ran Proxy Target
    markdown = render_markdown(result)
    ilc = next(line for line in markdown.splitlines() if line.startswith("| ILC-SAN |"))
    assert ilc == "| ILC-SAN | 3000 (n=1) · paper 3583 ± 86 | 88.24% |"  # APR 3000/3400, no published APR
    assert "Steps per seed run: 1 000 000." in markdown


def test_the_transcribed_follow_up_numbers_reproduce_their_printed_average_gains() -> None:
    """Each row's printed gain is the mean over tasks of cell / reference − 1 (Proxy Target's APG): recomputing it
    from the transcribed cells catches a mistyped cell."""
    from ilcsan.analysis.followups import FOLLOW_UPS

    for published in (s for sets in FOLLOW_UPS.values() for s in sets):
        reference = published.rows[published.reference]
        assert set(published.gains) == set(published.rows)
        for label, cells in published.rows.items():
            gain = 100 * np.mean([cells[task].mean / reference[task].mean - 1 for task in reference])
            assert gain == pytest.approx(published.gains[label], abs=0.01), label


def test_each_cell_beside_the_paper_is_compared_in_plain_words(tmp_path: Path) -> None:
    """Within the published std, above or below it by how much (in its units), on how many seeds; not comparable
    below the paper's budget or while a run trains."""
    from ilcsan.analysis.render import paper_comparison

    paper = {task: build_table([], "perf").cell("ilc-san-pop-det", task).paper for task in ("Hopper", "Ant")}
    hopper, ant = paper["Hopper"], paper["Ant"]
    for seed, score in enumerate([hopper.mean + 0.5 * hopper.std, hopper.mean - 1.5 * hopper.std]):
        make_run(tmp_path, "Hopper", seed, "ILC-SAN (E_pop_det)", [score] * 100, table="perf", row="ilc-san-pop-det")
    for seed in (0, 1):
        make_run(tmp_path, "Ant", seed, "ILC-SAN (E_pop_det)", [ant.mean - 2 * ant.std] * 100, table="perf",
                 row="ilc-san-pop-det")
    make_run(tmp_path, "Walker2d", 0, "ILC-SAN (E_pop_det)", [5000.0] * 20, table="perf", row="ilc-san-pop-det")
    make_run(tmp_path, "HalfCheetah", 0, "ILC-SAN (E_pop_det)", [9000.0] * 100, table="perf",
             row="ilc-san-pop-det", finished=False)
    table = build_table(collect_runs(tmp_path), "perf")
    words = {task: paper_comparison(table.cell("ilc-san-pop-det", task)) for task in table.tasks}
    # the mean of +0.5 and −1.5 stds is 0.5 std below the paper's; only the first seed is within its std
    assert words["Hopper"] == (f"within the paper's std (−{0.5 * hopper.std:.0f}, 0.5 of its std); "
                               "1 of 2 seeds within the paper's mean ± std")
    assert words["Ant"] == (f"below the paper's mean by {2 * ant.std:.0f} (2.0 of its std); "
                            "0 of 2 seeds within the paper's mean ± std")
    hopper_cell = table.cell("ilc-san-pop-det", "Hopper")
    near = dataclasses.replace(hopper_cell, runs=hopper_cell.runs[:1])  # one seed, 0.5 std above
    assert paper_comparison(near).endswith("0.5 of its std); 1 of 1 seed within the paper's mean ± std")
    close = dataclasses.replace(near, runs=(dataclasses.replace(near.runs[0], best_return=hopper.mean + 4.3),))
    assert f"(+4, {4.3 / hopper.std:.2f} of its std)" in paper_comparison(close)  # two decimals below 0.1
    assert words["Walker2d"] == "not comparable: a run trained 200 000 steps, the paper's protocol 1 000 000"
    assert words["HalfCheetah"] == "not comparable yet: 1 of 1 runs still training"
    assert words["Humanoid"] is None  # no runs
    markdown = render_markdown(table)
    assert f"- Ant · ILC-SAN (E\\_pop\\_det): {format_stat(ant.mean - 2 * ant.std, 0.0)}" in markdown
    assert markdown.count("\n- ") >= 4 and "Beside the paper" in markdown


def test_missing_cells_say_so_and_still_show_the_paper(tmp_path: Path) -> None:
    intra_run(tmp_path, "Hopper", "intra", 0, [3500])
    result = build_table(collect_runs(tmp_path), "intra")
    assert [row.key for row in result.rows] == [
        "none", "self", "lateral", "bias", "lateral+bias", "self+bias", "self+lateral", "intra"]
    assert result.tasks == ("Ant", "HalfCheetah", "Hopper", "Walker2d")
    ant = result.cell("self", "Ant")
    assert ant.n == 0 and ant.mean is None and not ant.best
    markdown = render_markdown(result)
    assert "| I\\_self | — · paper 5245 ± 769 |" in markdown
    assert "Missing cells (no runs): 31 of 32" in markdown
    assert "I\\_self: all tasks;" in markdown and "I\\_intra: Ant, HalfCheetah, Walker2d." in markdown
    statuses = {(line["row"], line["task"]): line["status"] for line in csv.DictReader(io.StringIO(render_csv(result)))}
    assert statuses["self", "Ant"] == "missing"
    assert statuses["intra", "Hopper"] == "ok"
    assert "-- {\\scriptsize (paper 5245 $\\pm$ 769)}" in render_latex(result)


# ------------------------------------------------------------------------------------------------
# APR and best marks


def test_a_task_outside_the_table_is_an_extra_column_without_the_papers_numbers(tmp_path: Path) -> None:
    # `ilcsan reproduce intra --tasks InvertedDoublePendulum,Pendulum-v1`: the table's rows on other tasks
    intra_run(tmp_path, "InvertedDoublePendulum", "self", 0, [8000, 9300])
    intra_run(tmp_path, "Pendulum-v1", "self", 0, [-900, -150])
    intra_run(tmp_path, "Hopper", "self", 0, [3000, 3400])
    result = build_table(collect_runs(tmp_path), "intra")
    assert result.tasks == (*TABLES["intra"].tasks, "InvertedDoublePendulum", "Pendulum-v1")
    outside = result.cell("self", "Pendulum-v1")
    assert outside.mean == -150 and outside.n == 1 and outside.paper is None
    assert result.cell("self", "InvertedDoublePendulum").paper is None
    assert result.cell("self", "Hopper").paper is not None, "the table's own tasks keep the paper's numbers"
    header = next(line for line in render_markdown(result).splitlines() if line.startswith("| Row"))
    assert header.endswith("| InvertedDoublePendulum | Pendulum-v1 | APR |")
    row = next(line for line in render_markdown(result).splitlines() if line.startswith("| I\\_self"))
    assert "-150** (n=1) |" in row and row.count("paper") == 4 + 1, "paper values for the 4 tasks and APR"
    assert ("intra", "self", "Pendulum-v1") in {(line[0], line[1], line[3]) for line in
                                                csv.reader(render_csv(result).splitlines()[1:])}


def test_apr_against_dan_only_over_tasks_where_both_exist(tmp_path: Path) -> None:
    make_run(tmp_path, "Ant", 0, "DAN", [1000], table="perf", row="dan", preset="dan")
    make_run(tmp_path, "Ant", 1, "DAN", [1200], table="perf", row="dan", preset="dan")
    make_run(tmp_path, "Hopper", 0, "DAN", [2000], table="perf", row="dan", preset="dan")
    make_run(tmp_path, "Ant", 0, "PopSAN", [550], table="perf", row="popsan", preset="popsan")
    make_run(tmp_path, "Hopper", 0, "PopSAN", [3000], table="perf", row="popsan", preset="popsan")
    make_run(tmp_path, "Ant", 0, "ILC-SAN (E_pop_det)", [1650], table="perf", row="ilc-san-pop-det")
    result = build_table(collect_runs(tmp_path), "perf")
    # DAN Ant = (1000 + 1200) / 2 = 1100; PopSAN: (550/1100 + 3000/2000) / 2 = (0.5 + 1.5) / 2
    assert result.row("dan").apr == pytest.approx(100.0)
    assert result.row("popsan").apr == pytest.approx(100.0)
    assert result.row("popsan").apr_tasks == 2
    ilc = result.row("ilc-san-pop-det")
    assert ilc.apr == pytest.approx(150.0) and ilc.apr_tasks == 1
    assert ilc.best_apr and not result.row("popsan").best_apr
    assert result.row("mdc-san").apr is None
    markdown = render_markdown(result)
    assert "**150.00%** (1/8 tasks) · paper 118.05%" in markdown
    assert "100.00% (2/8 tasks) · paper 101.81%" in markdown
    assert "Table perf's DAN row" in result.reference or "this table's DAN row" in result.reference


def test_ablation_tables_take_their_dan_reference_from_table_perf(tmp_path: Path) -> None:
    make_run(tmp_path, "Hopper", 0, "DAN", [3000], table="perf", row="dan", preset="dan")
    make_run(tmp_path, "Walker2d", 0, "DAN", [4000], table="perf", row="dan", preset="dan")
    intra_run(tmp_path, "Hopper", "intra", 0, [3600])
    intra_run(tmp_path, "Walker2d", "intra", 0, [5000])
    intra_run(tmp_path, "Hopper", "none", 0, [1500])
    result = build_table(collect_runs(tmp_path), "intra")
    assert result.reference == "Table perf's DAN row"
    assert result.row("intra").apr == pytest.approx(100 * (3600 / 3000 + 5000 / 4000) / 2)
    assert result.row("none").apr == pytest.approx(50.0)
    assert result.row("self").apr is None


def test_bold_marks_the_true_best_of_each_column(tmp_path: Path) -> None:
    intra_run(tmp_path, "Ant", "intra", 0, [5000])
    intra_run(tmp_path, "Ant", "intra", 1, [1000])  # mean 3000, but a higher single seed
    intra_run(tmp_path, "Ant", "self", 0, [3100])
    intra_run(tmp_path, "Ant", "none", 0, [3050])
    intra_run(tmp_path, "Hopper", "none", 0, [2000])
    intra_run(tmp_path, "Hopper", "self", 0, [2000])  # a tie: both bold
    result = build_table(collect_runs(tmp_path), "intra")
    best_ant = [row.key for row in result.rows if row.cell("Ant").best]
    assert best_ant == ["self"]
    assert sorted(row.key for row in result.rows if row.cell("Hopper").best) == ["none", "self"]
    markdown = render_markdown(result)
    assert "**3100** (n=1)" in markdown
    assert "3000 ± 2828 (n=2)" in markdown and "**3000 ± 2828**" not in markdown  # std ddof=1: 4000/√2


# ------------------------------------------------------------------------------------------------
# Runs without tags, skipped and duplicate runs


def test_untagged_runs_make_rows_by_label_and_columns_by_task(tmp_path: Path) -> None:
    make_run(tmp_path, "Pendulum-v1", 0, "mine", [-300, -150])
    make_run(tmp_path, "Hopper", 0, "mine", [1000])
    make_run(tmp_path, "Hopper", 1, "mine", [2000])
    make_run(tmp_path, "Hopper", 0, "DAN", [1000], preset="dan")
    result = build_table(collect_runs(tmp_path))
    assert result.tasks == ("Hopper", "Pendulum-v1")  # the paper's tasks first, then the others
    assert sorted(row.label for row in result.rows) == ["DAN", "mine"]
    mine = result.row("mine")
    assert mine.cell("Hopper").mean == 1500 and mine.cell("Pendulum-v1").mean == -150
    assert mine.apr == pytest.approx(150.0) and mine.apr_tasks == 1
    assert result.row("DAN").cell("Pendulum-v1").n == 0
    assert "**-150** (n=1)" in render_markdown(result)  # the only run of its column is the best


def test_number_format_follows_the_paper_and_keeps_small_returns_readable() -> None:
    assert format_stat(3583.333, 62.36) == "3583 ± 62"
    assert format_stat(-15.04, 3.21) == "-15.0 ± 3.2"
    assert format_stat(0.5, 0.1234) == "0.50 ± 0.12"


def test_untagged_runs_with_the_same_label_but_other_switches_are_separate_rows(tmp_path: Path) -> None:
    for seed, intra in ((0, "intra"), (0, "none"), (1, "none")):
        run = make_run(tmp_path, "Hopper", seed, "ilc-san", [1000 + 500 * (intra == "none") + seed],
                       subdir=f"{intra}{seed}")
        config = json.loads((run / "config.json").read_text())
        config["actor"] |= {"intra": intra, "decoder": "last"}
        (run / "config.json").write_text(json.dumps(config))
    scan = scan_runs(tmp_path)
    assert len(scan.runs) == 3 and not scan.skipped  # same label and seed, other switches: not duplicates
    result = build_table(scan.runs)
    assert sorted(row.label for row in result.rows) == ["ilc-san (intra=intra)", "ilc-san (intra=none)"]
    assert result.cell("ilc-san (intra=none)", "Hopper").scores == (1500, 1501)


def test_untagged_runs_are_placed_in_a_grid_table_by_label(tmp_path: Path) -> None:
    make_run(tmp_path, "Hopper", 0, "I_self", [3000])
    result = build_table(collect_runs(tmp_path), "intra")
    assert result.cell("self", "Hopper").n == 1


def trained_run(root: Path, task: str, seed: int, returns: list[float], preset: str = "ilc-san",
                training: dict | None = None, **overrides) -> Path:
    """A run as ``ilcsan train`` writes it (no table or row tag; the full actor and training settings)."""
    from ilcsan.config import TrainingConfig, actor_config

    run = make_run(root, task, seed, preset, returns, subdir=f"mine/{preset}-{len(list(root.rglob('*')))}")
    config = json.loads((run / "config.json").read_text())
    config |= {"actor": actor_config(preset, **overrides).to_dict(),
               "training": json.loads(json.dumps(dataclasses.asdict(TrainingConfig(**(training or {})))))}
    (run / "config.json").write_text(json.dumps(config))
    return run


def test_untagged_runs_are_placed_in_a_table_by_their_configuration(tmp_path: Path) -> None:
    trained_run(tmp_path, "Hopper", 0, [3400])
    trained_run(tmp_path, "Hopper", 1, [3600])
    trained_run(tmp_path, "Hopper", 0, [900], hidden=(64, 64))  # another actor: in no row of the paper
    trained_run(tmp_path, "Hopper", 0, [3500], training={"target_actor": "proxy"})
    trained_run(tmp_path, "Hopper", 0, [3300], training={"exploration": "noisy"})
    trained_run(tmp_path, "Hopper", 2, [100], training={"preaction_penalty": 0.1})  # another objective: in no row
    runs = collect_runs(tmp_path)
    perf = build_table(runs, "perf")
    cell = perf.cell("ilc-san-pop-det", "Hopper")
    assert cell.n == 2 and cell.mean == pytest.approx(3500.0) and cell.paper is not None
    assert all(perf.cell(row.key, "Hopper").n == 0 for row in perf.rows if row.key != "ilc-san-pop-det")
    beyond = build_table(runs, "beyond")
    assert [beyond.cell(slug, "Hopper").mean for slug in ("ilc-san", "ilc-san+proxy", "ilc-san+noisy")] == \
        pytest.approx([3500.0, 3500.0, 3300.0])
    assert beyond.cell("ilc-san", "Hopper").n == 2 and beyond.cell("dan", "Hopper").n == 0


def test_runs_of_another_grid_join_a_table_by_their_configuration_also_when_saved_by_an_older_version(
        tmp_path: Path) -> None:
    def tagged(seed: int, returns: list[float], table: str, row: str, drop: str | None = None, **kwargs) -> None:
        run = trained_run(tmp_path, "Hopper", seed, returns, **kwargs)
        config = json.loads((run / "config.json").read_text()) | {"table": table, "row": row}
        config["actor"].pop(drop, None)  # a setting that did not exist when the run was saved
        (run / "config.json").write_text(json.dumps(config))

    tagged(0, [3600], "beyond", "ilc-san")
    tagged(1, [3400], "beyond", "ilc-san", drop="intra_timing")  # saved before --intra-timing: Algorithm 1's
    tagged(2, [3000], "fidelity", "authors", intra_timing="authors")  # another actor: in no row of perf
    tagged(3, [3500], "beyond", "ilc-san+proxy", training={"target_actor": "proxy"})  # another method
    tagged(4, [1000], "intra", "self", intra="self")
    trained_run(tmp_path, "Hopper", 5, [3200])
    runs = collect_runs(tmp_path)
    perf = build_table(runs, "perf")
    assert perf.cell("ilc-san-pop-det", "Hopper").scores == (3600, 3400, 3200)
    assert sum(perf.cell(row.key, "Hopper").n for row in perf.rows) == 3
    assert build_table(runs, "beyond").cell("ilc-san", "Hopper").scores == (3600, 3400, 3200)
    default = {result.name: result for result in report_tables(runs)}  # without --table: by tag, as before
    assert default["beyond"].cell("ilc-san", "Hopper").scores == (3600, 3400)


def test_the_algorithms_grid_takes_the_beyond_grids_ilc_san_runs_and_keeps_algorithms_apart(tmp_path: Path) -> None:
    def tagged(seed: int, returns: list[float], table: str, row: str, algorithm: str = "td3", **kwargs) -> None:
        run = trained_run(tmp_path, "Hopper", seed, returns, **kwargs)
        config = json.loads((run / "config.json").read_text()) | {"table": table, "row": row, "algorithm": algorithm}
        (run / "config.json").write_text(json.dumps(config))

    tagged(0, [1700], "beyond", "ilc-san")
    tagged(3, [40], "beyond", "ilc-san")
    tagged(3, [3100], "beyond", "ilc-san+proxy", training={"target_actor": "proxy"})  # a method the grid has no row for
    tagged(3, [2500], "algorithms", "ilc-san+sac", algorithm="sac")
    tagged(3, [2200], "algorithms", "ilc-san+ddpg", algorithm="ddpg")
    tagged(3, [2900], "algorithms", "ilc-san+care-bn", normalization="care-bn")
    trained_run(tmp_path, "Hopper", 1, [2000])  # untagged ILC-SAN trained by TD3 (a cell lists its runs by seed)
    table = build_table(collect_runs(tmp_path), "algorithms")
    scores = {slug: table.cell(slug, "Hopper").scores
              for slug in ("ilc-san", "ilc-san+ddpg", "ilc-san+sac", "ilc-san+care-bn")}
    assert scores == {"ilc-san": (1700, 2000, 40), "ilc-san+ddpg": (2200,), "ilc-san+sac": (2500,),
                      "ilc-san+care-bn": (2900,)}
    assert [row.key for row in table.rows] == list(scores)  # Proxy Target's run made no row of its own


def test_a_corrupt_run_is_skipped_and_reported(tmp_path: Path) -> None:
    intra_run(tmp_path, "Hopper", "intra", 0, [3500])
    bad_json = intra_run(tmp_path, "Hopper", "intra", 1, [3600])
    (bad_json / "config.json").write_text("{not json")
    empty_csv = intra_run(tmp_path, "Hopper", "intra", 2, [3600], result=False)
    (empty_csv / "metrics.csv").write_text("")
    bad_result = intra_run(tmp_path, "Hopper", "intra", 3, [3600])
    (bad_result / "result.json").write_text('{"best_return": "high"}')
    no_seed = intra_run(tmp_path, "Hopper", "intra", 4, [3600])
    (no_seed / "config.json").write_text(json.dumps({"task": "Hopper", "label": "I_intra"}))
    ragged = intra_run(tmp_path, "Hopper", "intra", 5, [3600])
    with (ragged / "metrics.csv").open("a") as stream:
        stream.write("60000,12\n")
    scan = scan_runs(tmp_path)
    assert [run.seed for run in scan.runs] == [0]
    reasons = {run.path: run.reason for run in scan.skipped}
    assert reasons[bad_json].startswith("config.json: invalid JSON")
    assert reasons[empty_csv] == "metrics.csv: empty file"
    assert "best_return" in reasons[bad_result]
    assert "'seed' must be an integer" in reasons[no_seed]
    assert "metrics.csv line 3" in reasons[ragged]
    paths = write_report(tmp_path, tmp_path / "out", table="intra")
    markdown = paths["markdown"].read_text()
    assert "## Skipped runs" in markdown
    assert f"- `{bad_json}`: config.json: invalid JSON" in markdown
    assert "**3500** (n=1) · paper 3583 ± 86" in markdown


def test_header_only_metrics_is_skipped(tmp_path: Path) -> None:
    run = intra_run(tmp_path, "Hopper", "intra", 0, [3500])
    (run / "metrics.csv").write_text(HEADER + "\n")
    (skipped,) = scan_runs(tmp_path).skipped
    assert skipped.reason == "metrics.csv: no evaluation rows"


def test_duplicate_runs_count_once(tmp_path: Path) -> None:
    intra_run(tmp_path, "Hopper", "intra", 0, [3500, 3600], subdir="a")
    intra_run(tmp_path, "Hopper", "intra", 0, [3500], subdir="b")
    scan = scan_runs(tmp_path)
    assert [run.path.name for run in scan.runs] == ["a"]
    assert "duplicate of" in scan.skipped[0].reason


def test_directories_below_a_run_are_not_runs(tmp_path: Path) -> None:
    run = intra_run(tmp_path, "Hopper", "intra", 0, [3500])
    (run / "checkpoints" / "step1").mkdir(parents=True)
    (run / "checkpoints" / "step1" / "config.json").write_text("{}")
    scan = scan_runs(tmp_path)
    assert len(scan.runs) == 1 and not scan.skipped


def test_a_configuration_above_runs_is_a_container_not_a_run(tmp_path: Path) -> None:
    (tmp_path / "config.json").write_text(json.dumps({"table": "intra", "seeds": 10}))
    intra_run(tmp_path, "Hopper", "intra", 0, [3500])
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    (fresh / "config.json").write_text(json.dumps({"task": "Hopper", "seed": 0, "label": "x"}))
    scan = scan_runs(tmp_path)
    assert len(scan.runs) == 1
    assert [(run.path, run.reason) for run in scan.skipped] == [
        (fresh, "neither result.json nor metrics.csv (no evaluation yet)")]


def test_a_run_before_its_first_evaluation_is_listed_not_scored(tmp_path: Path) -> None:
    run = intra_run(tmp_path, "Hopper", "intra", 0, [3500])
    (run / "metrics.csv").unlink()
    (run / "result.json").write_text(json.dumps({"best_return": None, "best_step": None, "steps_done": 900,
                                                 "steps_total": 1000, "finished": False}))
    (skipped,) = scan_runs(tmp_path).skipped
    assert skipped.reason.startswith("no evaluation yet")


def test_cmd_report_accepts_a_grid_file_and_rejects_unknown_tables(tmp_path: Path, capsys) -> None:
    runs = tmp_path / "runs"
    make_run(runs, "Hopper", 0, "ILC-SAN", [3500], table="mine", row="ilc")
    grid = tmp_path / "mine.toml"
    grid.write_text('name = "mine"\ntasks = ["Hopper", "Ant"]\n[[rows]]\nslug = "ilc"\nlabel = "ILC-SAN"\n'
                    'preset = "ilc-san"\n')
    args = build_parser().parse_args(["report", str(runs), "--table", str(grid), "--out", str(tmp_path / "out")])
    assert cmd_report(args) == 0
    assert "1 run(s) found" in capsys.readouterr().out
    markdown = (tmp_path / "out" / "report.md").read_text()
    assert "| ILC-SAN | **3500** (n=1) | — |" in markdown
    assert report_layout("mine", collect_runs(runs)) == "mine"  # a tag found among the runs
    with pytest.raises(ValueError, match="no table 'intro'"):
        report_layout("intro", collect_runs(runs))


def test_one_report_of_several_folders_counts_each_run_once(tmp_path: Path, capsys) -> None:
    """``ilcsan report A B --out O``: the runs of both folders in one table; a run found twice (a folder below both,
    or a copy of the same seed) counts once; several folders without --out are one line and exit code 2."""
    from ilcsan.cli import main

    beyond, algorithms = tmp_path / "beyond-grid", tmp_path / "algorithms-grid"
    make_run(beyond, "Hopper", 1, "ILC-SAN", [2100], table="beyond", row="ilc-san")
    make_run(beyond, "Hopper", 3, "ILC-SAN", [40], table="beyond", row="ilc-san")
    make_run(algorithms, "Hopper", 3, "ILC-SAN (SAC)", [2500], table="algorithms", row="ilc-san+sac")
    copy = make_run(algorithms, "Hopper", 1, "ILC-SAN", [2100], table="beyond", row="ilc-san", subdir="copy/seed1")
    for tagged in (*beyond.rglob("config.json"), copy / "config.json"):  # as the trainer writes them: every setting
        config = json.loads(tagged.read_text()) | {"actor": actor_config("ilc-san").to_dict(), "algorithm": "td3"}
        tagged.write_text(json.dumps(config))
    sac = next(algorithms.rglob("ilc-san+sac/seed3/config.json"))
    sac.write_text(json.dumps(json.loads(sac.read_text()) | {"actor": actor_config("ilc-san").to_dict(),
                                                             "algorithm": "sac"}))
    assert main(["report", str(beyond), str(algorithms), str(beyond / "beyond"), "--table", "algorithms",
                 "--out", str(tmp_path / "out")]) == 0
    assert "3 run(s) found below" in capsys.readouterr().out
    table = build_table(collect_runs([beyond, algorithms, beyond / "beyond"]), "algorithms")
    assert table.cell("ilc-san", "Hopper").scores == (2100, 40)
    assert table.cell("ilc-san+sac", "Hopper").scores == (2500,)
    markdown = (tmp_path / "out" / "report.md").read_text()
    assert "2500" in markdown and str(copy) in markdown  # the copy is listed as skipped, not counted
    assert main(["report", str(beyond), str(algorithms)]) == 2
    err = capsys.readouterr().err
    assert "needs --out" in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_report_of_some_seeds_compares_rows_on_the_same_seeds(tmp_path: Path, capsys) -> None:
    """``ilcsan report DIR --seeds 1-2``: only those seeds' runs in the cells, the title names them; seeds that
    match no run are one line and exit code 2."""
    from ilcsan.cli import main

    for seed, value in enumerate([1000.0, 2000.0, 3000.0, 40.0]):
        intra_run(tmp_path, "Hopper", "intra", seed, [value])
    intra_run(tmp_path, "Hopper", "self", 2, [2500.0])
    assert main(["report", str(tmp_path), "--seeds", "1-2", "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "5 run(s) found below" in out and ", 3 of seeds 1-2 reported" in out
    # the terminal also says how each cell stands beside the paper (here: too short to compare)
    assert "  Hopper · I_self: 2500 (n=1) against 3512 ± 146: not comparable: a run trained 10 000 steps" in out
    markdown = (tmp_path / "out" / "report.md").read_text()
    assert markdown.startswith("# ILC-SAN reproduction report: seeds 1–2 only\n")
    assert f"{format_stat(2500.0, float(np.std([2000.0, 3000.0], ddof=1)))}** (n=2)" in markdown  # seeds 0, 3 left out
    assert "**2500** (n=1) · paper 3512" in markdown
    assert (tmp_path / "out" / "report.tex").read_text().startswith("% ILC-SAN reproduction report: seeds 1–2 only;")
    assert main(["report", str(tmp_path), "--seeds", "7,9", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "no runs of seeds 7,9" in err and "seeds 0, 1, 2, 3" in err and len(err.strip().splitlines()) == 1


def test_seed_text_writes_consecutive_seeds_as_ranges() -> None:
    from ilcsan.analysis.report import seed_text

    assert seed_text({5, 0, 1, 2}) == "0–2, 5" and seed_text([3]) == "3" and seed_text(range(10)) == "0–9"


def test_report_without_table_groups_runs_by_their_tags(tmp_path: Path) -> None:
    intra_run(tmp_path, "Hopper", "intra", 0, [3500])
    make_run(tmp_path, "Hopper", 0, "D_fr", [700], table="decode", row="fr", preset="popsan")
    make_run(tmp_path, "Hopper", 0, "D_fr", [900], table="dec_intra", row="fr")
    make_run(tmp_path, "Hopper", 0, "mine", [100])
    results = report_tables(collect_runs(tmp_path))
    assert [result.name for result in results] == ["decode", "dec_intra", "intra", None]
    assert results[1].cell("fr", "Hopper").mean == 900
    assert [row.label for row in results[3].rows] == ["mine"]
    single = build_table(collect_runs(tmp_path))  # one table: the same label in two tables stays apart
    assert sorted(row.label for row in single.rows) == [
        "D_fr [dec_intra]", "D_fr [decode]", "I_intra", "mine"]
    assert single.row("D_fr [decode]").cell("Hopper").paper.mean == 517


def test_missing_directory_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="does not exist"):
        scan_runs(tmp_path / "nope")


# ------------------------------------------------------------------------------------------------
# Learning curves


def test_smoothing_is_a_trailing_moving_average_over_five_evaluations() -> None:
    assert smooth(np.array([1.0, 2, 3, 4, 5, 6, 7])).tolist() == [1, 1.5, 2, 2.5, 3, 4, 5]
    assert smooth(np.array([[0.0, 10], [2, 2]]), window=2).tolist() == [[0, 5], [2, 2]]


def test_curves_are_aligned_on_common_steps(tmp_path: Path) -> None:
    intra_run(tmp_path, "Hopper", "intra", 0, [10, 20, 30])
    intra_run(tmp_path, "Hopper", "intra", 1, [30, 40], result=False)
    steps, mean, std = curve(collect_runs(tmp_path), window=1)
    assert steps.tolist() == [10_000, 20_000]
    assert mean.tolist() == [20, 30]
    assert std == pytest.approx([200**0.5, 200**0.5]), "the sample std (ddof 1) of 10 and 30, as every table's"
    _, _, alone = curve(collect_runs(tmp_path)[:1])
    assert alone.tolist() == [0.0] * len(alone), "one seed has no spread"


def _is_png(path: Path) -> bool:
    return path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_plot_curves_one_panel_per_task(tmp_path: Path) -> None:
    for seed in range(2):
        intra_run(tmp_path / "runs", "Hopper", "intra", seed, list(np.linspace(0, 3000, 12) + seed * 100))
        intra_run(tmp_path / "runs", "Hopper", "none", seed, list(np.linspace(0, 2000, 12)))
    path = tmp_path / "plots" / "curves.png"
    intra_run(tmp_path / "runs", "Ant", "intra", 0, [100, 200])
    figure = plot_curves(collect_runs(tmp_path / "runs"), path, table="intra")
    # panels for the tasks that have runs only: HalfCheetah and Walker2d have none
    assert [axes.get_title() for axes in figure.axes] == ["Ant", "Hopper"]
    hopper = figure.axes[1]
    curves = [line.get_label() for line in hopper.get_lines() if line.get_gid() != "paper"]  # not the paper's lines
    assert sorted(curves) == ["I_intra", "No I_intra"]
    (intra_line,) = [line for line in hopper.get_lines() if line.get_label() == "I_intra"]
    # 12 evaluations: too short to smooth (smoothing_window), so the last point is the seeds' mean there
    assert intra_line.get_ydata()[-1] == pytest.approx(3000 + 50)
    assert _is_png(path) and path.stat().st_size > 10_000
    assert [p.name for p in path.parent.iterdir()] == ["curves.png"]  # no temporary file left
    import matplotlib.image

    height, width, _ = matplotlib.image.imread(path).shape
    assert width > height > 100


def test_plot_curves_of_one_task_is_one_large_panel_and_of_no_runs_every_task(tmp_path: Path) -> None:
    make_run(tmp_path, "Humanoid", 0, "DAN", [10, 20], table="perf", row="dan", preset="dan")
    figure = plot_curves(collect_runs(tmp_path), tmp_path / "c.png", table="perf")
    assert [axes.get_title() for axes in figure.axes] == ["Humanoid"]
    assert tuple(figure.get_size_inches()) == (6.4, 4.0)
    empty = plot_curves([], tmp_path / "empty.png", table="perf")
    assert len(empty.axes) == 8 and all(axes.texts[0].get_text() == "no runs" for axes in empty.axes)


def test_write_report_writes_all_four_files(tmp_path: Path) -> None:
    intra_run(tmp_path, "Hopper", "intra", 0, [1000, 3500, 3200])
    make_run(tmp_path, "Pendulum-v1", 0, "mine", [-300, -150])
    paths = write_report(tmp_path)
    assert set(paths) == {"markdown", "latex", "csv", "comparison", "curves"}
    assert all(path.parent == tmp_path and path.exists() for path in paths.values())
    assert _is_png(paths["curves"])
    latex = paths["latex"].read_text()
    for rule in (r"\toprule", r"\midrule", r"\bottomrule", r"\usepackage{booktabs}", r"I\_intra"):
        assert rule in latex
    markdown = paths["markdown"].read_text()
    assert "## Table `intra`: Max average rewards" in markdown and "Runs without a table tag" in markdown
    assert "ddof=1" in markdown
    lines = list(csv.DictReader(io.StringIO(paths["csv"].read_text())))
    assert {line["table"] for line in lines} == {"intra", ""}
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary files left
    # the report's own files are not runs: a second report finds the same runs
    assert write_report(tmp_path)["markdown"].read_text() == markdown


def test_write_report_on_an_empty_directory(tmp_path: Path) -> None:
    paths = write_report(tmp_path)
    assert "No runs found." in paths["markdown"].read_text()
    assert _is_png(paths["curves"])


def test_short_curves_are_not_smoothed_and_long_ones_are() -> None:
    assert smoothing_window(6) == 1 and smoothing_window(19) == 1
    assert smoothing_window(40) == 2 and smoothing_window(100) == 5 and smoothing_window(1000) == 5
