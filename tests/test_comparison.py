"""Telling rows of a reward table apart (ilcsan.analysis.comparison) on scores whose answer is known."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import pytest
from rliable import metrics
from test_report import make_run

from ilcsan.analysis.collect import collect_runs
from ilcsan.analysis.comparison import (
    APR,
    IMPROVEMENT,
    OUR_DAN,
    PAPER_DAN,
    Aggregate,
    Bootstrap,
    Comparison,
    Interval,
    Selection,
    TableComparison,
    common_selection,
    compare,
    compare_table,
    iqm_and_mean,
    probability_of_improvement,
    select_seeds,
)
from ilcsan.analysis.figures import draw_intervals
from ilcsan.analysis.report import write_report
from ilcsan.analysis.reward_tables import build_table
from ilcsan.paper.published import published_cell

TASKS = ("Ant", "HalfCheetah", "Hopper", "Walker2d")
QUICK = Bootstrap(reps=400, seed=3)


def scores(values: np.ndarray, tasks=TASKS) -> dict[str, dict[int, float]]:
    """A (seeds × tasks) array as task → seed → score."""
    return {task: {seed: float(values[seed, j]) for seed in range(values.shape[0])} for j, task in enumerate(tasks)}


def spread(seeds: int = 3, offset: float = 0.0) -> np.ndarray:
    return np.random.default_rng(7).normal(1000.0, 100.0, size=(seeds, len(TASKS))) + offset


# ------------------------------------------------------------------------------------------------
# P(improvement) and the APR


def test_identical_rows_are_even_and_cannot_be_told_apart() -> None:
    row = scores(spread())
    comparison = compare(IMPROVEMENT, ("A", row), ("B", row), TASKS, QUICK)
    assert comparison.interval.estimate == 0.5  # exactly: every run pair has its mirror
    assert comparison.interval.low < 0.5 < comparison.interval.high
    assert comparison.verdict == "cannot tell apart on these seeds"
    assert comparison.sentence().startswith("A over B: P(improvement) = 0.50, 95 % CI ")
    assert comparison.sentence().endswith("4 tasks × 3 seeds (Ant, HalfCheetah, Hopper, Walker2d; seeds 0, 1, 2): "
                                          "cannot tell apart on these seeds; per task: Ant 0.50, HalfCheetah 0.50, "
                                          "Hopper 0.50, Walker2d 0.50")


def test_a_row_far_above_is_better_and_the_other_way_round_worse() -> None:
    low, high = scores(spread()), scores(spread(offset=5000.0))
    better = compare(IMPROVEMENT, ("high", high), ("low", low), TASKS, QUICK)
    assert better.interval.estimate == 1.0 and better.interval.low > 0.5
    assert better.verdict == "better" and better.unanimous
    # every pair agrees, so the interval has no width: the sentence says that this is not certainty
    assert (better.interval.low, better.interval.high) == (1.0, 1.0)
    assert better.sentence().endswith(": better (every pair of runs agreed, which leaves the bootstrap no other "
                                      "answer; with 3 seeds per task that is not certainty); per task: Ant 1.00, "
                                      "HalfCheetah 1.00, Hopper 1.00, Walker2d 1.00")
    worse = compare(IMPROVEMENT, ("low", low), ("high", high), TASKS, QUICK)
    assert worse.interval.high < 0.5 and worse.verdict == "worse" and worse.unanimous


def test_a_row_above_on_most_pairs_has_an_interval_and_no_unanimity_caveat() -> None:
    low, high = spread(), spread(offset=150.0)
    high[0, 0] = low[:, 0].min() - 1.0  # one run of the higher row below every run of the other
    comparison = compare(IMPROVEMENT, ("high", scores(high)), ("low", scores(low)), TASKS, QUICK)
    assert comparison.interval.low < comparison.interval.high and not comparison.unanimous
    assert "every pair of runs agreed" not in comparison.sentence()
    apr_only = compare(APR, ("high", scores(high)), ("DAN", scores(low)), TASKS, QUICK)
    assert not apr_only.unanimous


def test_probability_of_improvement_is_rliables_statistic() -> None:
    rng = np.random.default_rng(1)
    x, y = rng.integers(0, 4, size=(3, 5)).astype(float), rng.integers(0, 4, size=(4, 5)).astype(float)  # with ties
    assert probability_of_improvement(x, y)[0] == pytest.approx(metrics.probability_of_improvement(x, y))
    x, y = rng.normal(size=(5, 3)), rng.normal(size=(2, 3))
    assert probability_of_improvement(x, y)[0] == pytest.approx(metrics.probability_of_improvement(x, y))


def test_a_comparison_names_the_tasks_that_decide_it() -> None:
    """Hand-computed: on Ant the runs 1, 2, 3 against 2, 2, 2 win 3 pairs, tie 3 and lose 3 (0.5); on Hopper every
    pair is won (1.0); the whole P(improvement) is their mean, 0.75. Each task's value is rliable's on that task."""
    x = {"Ant": {0: 1.0, 1: 2.0, 2: 3.0}, "Hopper": {0: 10.0, 1: 11.0, 2: 12.0}}
    y = {"Ant": {0: 2.0, 1: 2.0, 2: 2.0}, "Hopper": {0: 1.0, 1: 1.0, 2: 1.0}}
    comparison = compare(IMPROVEMENT, ("X", x), ("Y", y), ("Ant", "Hopper"), QUICK)
    assert comparison.per_task == (0.5, 1.0) and comparison.interval.estimate == 0.75
    assert comparison.sentence().endswith("; per task: Ant 0.50, Hopper 1.00")
    matrices = [np.array([[row[task][seed] for task in ("Ant", "Hopper")] for seed in range(3)]) for row in (x, y)]
    for column, value in enumerate(comparison.per_task):
        assert value == pytest.approx(metrics.probability_of_improvement(*(m[:, [column]] for m in matrices)))
    apr_ = compare(APR, ("X", x), ("DAN", y), ("Ant", "Hopper"), QUICK)
    assert apr_.per_task == pytest.approx((100.0, 1100.0)) and apr_.interval.estimate == pytest.approx(600.0)
    assert apr_.sentence().endswith("; per task: Ant 100.0 %, Hopper 1100.0 %")


@pytest.mark.parametrize("shape", [(3, 8), (10, 1), (2, 5), (4, 7)])
def test_iqm_and_mean_are_rliables(shape: tuple[int, int]) -> None:
    values = np.random.default_rng(sum(shape)).normal(size=shape)
    values[0, 0] = values[-1, -1]  # a tie
    assert iqm_and_mean(values) == pytest.approx([metrics.aggregate_iqm(values), metrics.aggregate_mean(values)])


def test_apr_of_a_row_at_1_2_times_dan_is_120_percent() -> None:
    dan = spread()
    comparison = compare(APR, ("ILC-SAN", scores(1.2 * dan)), ("DAN", scores(dan)), TASKS, QUICK)
    assert comparison.interval.estimate == pytest.approx(120.0)
    assert comparison.interval.low <= 120.0 <= comparison.interval.high
    assert comparison.interval.low < comparison.interval.high  # the seeds are resampled: a real interval
    assert "ILC-SAN against DAN: APR = 120.0 %, 95 % CI " in comparison.sentence()


def test_the_bootstrap_is_reproducible_and_leaves_numpys_random_state_alone() -> None:
    low, high = scores(spread()), scores(spread(offset=150.0))
    np.random.seed(123)
    expected = np.random.random()
    np.random.seed(123)
    first = compare(APR, ("A", high), ("B", low), TASKS, QUICK)
    assert np.random.random() == expected
    assert compare(APR, ("A", high), ("B", low), TASKS, QUICK) == first
    assert compare(APR, ("A", high), ("B", low), TASKS, Bootstrap(reps=400, seed=4)).interval != first.interval


# ------------------------------------------------------------------------------------------------
# Which runs: common seeds, every task with two of them


def test_every_task_with_two_common_seeds_is_kept_with_the_fewest_seeds_among_them() -> None:
    # A 5, B 3, C 4, D 2 common seeds are kept (k = 2, D's count); E with 1 is left out
    selection = select_seeds({"A": [4, 3, 2, 1, 0], "B": [0, 1, 2], "C": [0, 1, 2, 7], "D": [0, 1], "E": [0]})
    assert (selection.k, selection.tasks) == (2, ("A", "B", "C", "D"))
    assert selection.seeds == ((0, 1),) * 4  # each task's first k seeds
    assert selection.left_out == (("E", "1 common seed"),)
    # one deep task does not crowd out a shallow one: 10 seeds of A and 3 of B give 2 tasks × 3 seeds
    deep = select_seeds({"A": list(range(10)), "B": [5, 6, 7]})
    assert (deep.k, deep.tasks, deep.seeds) == (3, ("A", "B"), ((0, 1, 2), (5, 6, 7)))
    assert select_seeds({"A": [0], "B": []}).k == 0


def test_rows_are_paired_on_the_seeds_both_ran_and_the_sentence_says_which() -> None:
    x = {"Ant": {0: 1.0, 1: 2.0, 2: 3.0, 3: 4.0}, "Hopper": {0: 1.0, 1: 2.0}, "Walker2d": {5: 1.0, 6: 2.0}}
    y = {"Ant": {1: 1.0, 2: 2.0, 3: 3.0, 4: 4.0}, "Hopper": {0: 1.0, 1: 2.0}, "Walker2d": {5: 1.0}}
    selection = common_selection([("X", x), ("Y", y)], ("Ant", "HalfCheetah", "Hopper", "Walker2d"))
    assert (selection.tasks, selection.seeds) == (("Ant", "Hopper"), ((1, 2), (0, 1)))
    assert selection.left_out == (("HalfCheetah", "no runs of X"), ("Walker2d", "1 common seed"))
    assert selection.text == ("2 tasks × 2 seeds (Ant, Hopper; the first 2 common seeds of each; left out: "
                              "HalfCheetah (no runs of X); Walker2d (1 common seed))")
    single = compare(IMPROVEMENT, ("X", {"Ant": {0: 1.0}}), ("Y", {"Ant": {0: 2.0}}), ("Ant",), QUICK)
    assert single.interval is None
    assert single.sentence() == ("X over Y: P(improvement): not computed: fewer than 2 common seeds on every task "
                                 "(Ant (1 common seed))")


# ------------------------------------------------------------------------------------------------
# Normalised scores and the report


def test_scores_divided_by_the_papers_dan_value_give_a_hand_computed_iqm_and_mean(tmp_path: Path) -> None:
    hopper, ant = published_cell("perf", "dan", "Hopper").mean, published_cell("perf", "dan", "Ant").mean
    for seed, (h, a) in enumerate([(1.0, 1.0), (2.0, 0.5), (0.5, 1.5)]):  # ratios to the paper's DAN
        make_run(tmp_path, "Hopper", seed, "ILC-SAN (E_pop_det)", [h * hopper], table="perf", row="ilc-san-pop-det")
        make_run(tmp_path, "Ant", seed, "ILC-SAN (E_pop_det)", [a * ant], table="perf", row="ilc-san-pop-det")
    result = compare_table(build_table(collect_runs(tmp_path), "perf"), QUICK)
    (paper,) = [item for item in result.aggregates if item.normaliser == PAPER_DAN]
    # 0.5 0.5 1 1 1.5 2: the IQM drops one of six at each end (rliable's 25 % trim) → mean(0.5, 1, 1, 1.5)
    assert paper.iqm.estimate == pytest.approx(1.0)
    assert paper.mean.estimate == pytest.approx(6.5 / 6)
    assert paper.selection.tasks == ("Ant", "Hopper")
    assert result.notes[0].startswith("No DAN runs: ")


def test_the_report_says_in_words_whether_ilc_san_beats_dan(tmp_path: Path) -> None:
    for seed in range(3):
        for task, dan, ours in (("Hopper", 3000.0, 3500.0), ("Ant", 5000.0, 5600.0)):
            make_run(tmp_path, task, seed, "DAN", [dan + 10 * seed], table="perf", row="dan", preset="dan")
            make_run(tmp_path, task, seed, "ILC-SAN (E_pop_det)", [ours + 10 * seed], table="perf",
                     row="ilc-san-pop-det")
    make_run(tmp_path, "Hopper", 0, "PopSAN", [3100.0], table="perf", row="popsan", preset="popsan")
    paths = write_report(tmp_path, table="perf", bootstrap=QUICK)
    assert paths["intervals"] == tmp_path / "intervals.png" and paths["intervals"].exists()
    markdown = paths["markdown"].read_text()
    assert "### Telling the rows apart" in markdown
    assert ("- ILC-SAN (E\\_pop\\_det) over DAN: P(improvement) = 1.00, 95 % CI 1.00–1.00 on 2 tasks × 3 seeds "
            "(Ant, Hopper; seeds 0, 1, 2; left out: HalfCheetah, Walker2d, Humanoid, HumanoidStandup, "
            "InvertedDoublePendulum, BipedalWalker (no runs of ILC-SAN (E\\_pop\\_det))): better") in markdown
    assert markdown.index("### Telling the rows apart") > markdown.index("| ILC-SAN (E\\_pop\\_det) |")
    assert "- PopSAN over DAN: P(improvement): not computed: fewer than 2 common seeds on every task" in markdown
    lines = list(csv.DictReader(io.StringIO(paths["comparison"].read_text())))
    (apr,) = [line for line in lines if line["statistic"] == "apr" and line["row"] == "ILC-SAN (E_pop_det)"]
    expected = 100 * np.mean([3510 / 3010, 5610 / 5010])
    assert float(apr["estimate"]) == pytest.approx(expected)
    assert (apr["verdict"], apr["tasks"], apr["seeds_per_task"], apr["reps"]) == ("better", "Ant;Hopper", "3", "400")
    per_task = dict(item.split(":") for item in apr["per_task"].split(";"))
    assert {task: float(value) for task, value in per_task.items()} == pytest.approx(
        {"Ant": 100 * 5610 / 5010, "Hopper": 100 * 3510 / 3010})


# ------------------------------------------------------------------------------------------------
# intervals.png


def test_the_interval_figure_draws_each_computed_interval_as_a_bar_and_skips_rows_without_numbers(
        tmp_path: Path) -> None:
    selection = Selection(("Ant", "Hopper"), ((0, 1, 2), (0, 1, 2)))
    aggregates = (Aggregate("ILC-SAN", OUR_DAN, selection, Interval(1.1, 0.9, 1.3), Interval(1.2, 1.0, 1.4)),
                  Aggregate("PopSAN", OUR_DAN, Selection((), ())))
    comparisons = (Comparison(IMPROVEMENT, "ILC-SAN", "DAN", selection, Interval(0.7, 0.55, 0.85)),
                   Comparison(IMPROVEMENT, "PopSAN", "DAN", Selection((), ())))
    path = tmp_path / "intervals.png"
    figure = draw_intervals([TableComparison("perf", aggregates, comparisons, (), QUICK)], path)
    assert path.read_bytes().startswith(b"\x89PNG")
    iqm, mean, improvement = figure.axes
    assert iqm.get_title() == f"IQM of score / {OUR_DAN}"
    (bar,) = iqm.patches
    assert (bar.get_x(), bar.get_x() + bar.get_width()) == pytest.approx((0.9, 1.3))
    assert [tick.get_text() for tick in iqm.get_yticklabels()] == ["ILC-SAN\n2 tasks × 3 seeds"]
    (tick,) = [line for line in iqm.lines if line.get_color() == "black"]
    assert list(tick.get_xdata()) == pytest.approx([1.1, 1.1])
    (bar,) = improvement.patches
    assert (bar.get_x(), bar.get_x() + bar.get_width()) == pytest.approx((0.55, 0.85))
    assert any(list(line.get_xdata()) == [0.5, 0.5] and line.get_linestyle() == "--" for line in improvement.lines)
    assert not any(line.get_linestyle() == "--" for line in iqm.lines)


def test_the_interval_figure_is_not_written_when_nothing_was_computed(tmp_path: Path) -> None:
    empty = TableComparison("perf", (Aggregate("PopSAN", OUR_DAN, Selection((), ())),),
                            (Comparison(IMPROVEMENT, "PopSAN", "DAN", Selection((), ())),), (), QUICK)
    assert draw_intervals([empty], tmp_path / "intervals.png") is None
    assert not (tmp_path / "intervals.png").exists()
    make_run(tmp_path, "Hopper", 0, "PopSAN", [3100.0], table="perf", row="popsan", preset="popsan")
    paths = write_report(tmp_path, table="perf", bootstrap=QUICK)
    assert "intervals" not in paths and not (tmp_path / "intervals.png").exists()
