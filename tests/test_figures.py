"""Figures of ``ilcsan report``: the paper's Fig. 5 and Fig. 6, and the paper's values on the curves panels."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from matplotlib.colors import to_rgba
from test_report import intra_run, make_run

from ilcsan.analysis.collect import collect_runs
from ilcsan.analysis.curves import PAPER_GID, PAPER_LABEL, plot_curves
from ilcsan.analysis.figures import PAPER_FIGURES, draw_comparison
from ilcsan.analysis.report import write_report
from ilcsan.analysis.reward_tables import build_table
from ilcsan.paper.published import FIRST_FOUR, published_cell

FIG5, FIG6 = PAPER_FIGURES


def perf_run(root: Path, task: str, row: str, seed: int, returns: list[float]) -> Path:
    """A run of Table perf's ``row`` as ``ilcsan reproduce perf`` tags it."""
    labels = {"popsan": "PopSAN", "ilc-san-pop-det": "ILC-SAN (E_pop_det)", "mdc-san": "MDC-SAN",
              "ilc-san-pop": "ILC-SAN (E_pop)"}
    preset = "ilc-san" if row.startswith("ilc-san") else row
    return make_run(root, task, seed, labels[row], returns, table="perf", row=row, preset=preset)


def paper_lines(axes) -> list:
    return [line for line in axes.get_lines() if line.get_gid() == PAPER_GID]


def curve_line(axes, label: str):
    (line,) = [line for line in axes.get_lines() if line.get_label().startswith(label)]
    return line


def band_half_widths(axes, color) -> dict[float, float]:
    """Half the height of the shaded band of the curve in ``color`` at each of its steps."""
    (band,) = [collection for collection in axes.collections
               if np.allclose(collection.get_facecolor()[0][:3], to_rgba(color)[:3])]
    heights: dict[float, list[float]] = {}
    for x, y in band.get_paths()[0].vertices:
        heights.setdefault(float(x), []).append(float(y))
    return {x: (max(ys) - min(ys)) / 2 for x, ys in heights.items()}


def test_fig5_shades_half_the_sample_std_over_seeds_around_the_mean(tmp_path: Path) -> None:
    popsan = [[0, 100, 200], [100, 300, 600]]  # 3 evaluations: too short to be smoothed
    ilc = [[500, 1500, 3000], [700, 2500, 3400]]
    for seed in range(2):
        perf_run(tmp_path, "Hopper", "popsan", seed, popsan[seed])
        perf_run(tmp_path, "Hopper", "ilc-san-pop-det", seed, ilc[seed])
    result = build_table(collect_runs(tmp_path), "perf")
    figure = draw_comparison(result, FIG5, tmp_path / "fig5.png")
    assert [axes.get_title() for axes in figure.axes] == list(FIRST_FOUR)
    hopper = figure.axes[FIRST_FOUR.index("Hopper")]
    for label, values in (("PopSAN", popsan), ("ILC-SAN (E_pop_det)", ilc)):
        line = curve_line(hopper, label)
        assert line.get_label() == f"{label} (n=2)"
        assert line.get_ydata().tolist() == pytest.approx(np.mean(values, axis=0).tolist())
        by_hand = [abs(a - b) / 2**0.5 / 2 for a, b in zip(*values, strict=True)]  # ddof=1 std of two, halved
        widths = band_half_widths(hopper, line.get_color())
        assert [widths[step] for step in (10_000, 20_000, 30_000)] == pytest.approx(by_hand)
    # the other tasks have no runs of either row
    for task in ("Ant", "HalfCheetah", "Walker2d"):
        axes = figure.axes[FIRST_FOUR.index(task)]
        assert not axes.get_lines() and [text.get_text() for text in axes.texts] == ["no runs"]


def test_fig5_names_the_row_missing_on_a_panel_and_draws_the_other(tmp_path: Path) -> None:
    perf_run(tmp_path, "Hopper", "popsan", 0, [0, 100])
    perf_run(tmp_path, "Hopper", "ilc-san-pop-det", 0, [0, 200])
    perf_run(tmp_path, "Ant", "ilc-san-pop-det", 0, [0, 300])
    figure = draw_comparison(build_table(collect_runs(tmp_path), "perf"), FIG5, tmp_path / "fig5.png")
    ant = figure.axes[0]
    assert [line.get_label() for line in ant.get_lines() if line.get_gid() != PAPER_GID] == [
        "ILC-SAN (E_pop_det) (n=1)"]
    assert [text.get_text() for text in ant.texts] == ["no runs of PopSAN"]


def test_fig5_and_fig6_are_written_only_when_both_of_their_rows_ran_on_one_task(tmp_path: Path) -> None:
    runs, out = tmp_path / "runs", tmp_path / "out"
    perf_run(runs, "Hopper", "ilc-san-pop-det", 0, [0, 100])
    paths = write_report(runs, out, table="perf")
    assert "fig5" not in paths and not (out / "fig5.png").exists()
    perf_run(runs, "Ant", "popsan", 0, [0, 100])  # both rows, but not on the same task
    assert "fig5" not in write_report(runs, out, table="perf")
    perf_run(runs, "Hopper", "popsan", 0, [0, 100])
    paths = write_report(runs, out, table="perf")
    assert paths["fig5"] == out / "fig5.png" and paths["fig5"].read_bytes()[:4] == b"\x89PNG"
    assert "fig6" not in paths and not (out / "fig6.png").exists()
    perf_run(runs, "Walker2d", "mdc-san", 0, [0, 100])
    perf_run(runs, "Walker2d", "ilc-san-pop", 0, [0, 100])
    assert {"fig5", "fig6"} <= set(write_report(runs, out, table="perf"))
    # a table other than perf (here intra, whose rows are other) never draws them
    intra_run(tmp_path / "intra", "Hopper", "intra", 0, [0, 100])
    assert "fig5" not in write_report(tmp_path / "intra")


def test_a_figure_an_earlier_report_drew_is_removed_when_the_runs_no_longer_show_it(tmp_path: Path) -> None:
    """Re-reporting into the same folder: fig5.png of runs that are gone does not stay beside the new report."""
    runs, out = tmp_path / "runs", tmp_path / "out"
    perf_run(runs, "Hopper", "ilc-san-pop-det", 0, [0, 100])
    popsan = perf_run(runs, "Hopper", "popsan", 0, [0, 100])
    assert (out / "fig5.png") in write_report(runs, out, table="perf").values()
    (out / "notes.png").write_bytes(b"mine")  # not a report's figure: kept
    shutil.rmtree(popsan)
    paths = write_report(runs, out, table="perf")
    assert "fig5" not in paths and not (out / "fig5.png").exists()
    assert (out / "notes.png").read_bytes() == b"mine" and paths["curves"].exists()


def test_curves_panels_draw_the_papers_value_of_each_row_in_its_colour(tmp_path: Path) -> None:
    for seed in range(2):
        intra_run(tmp_path, "Hopper", "intra", seed, [1000, 3000 + seed])
        intra_run(tmp_path, "Hopper", "none", seed, [800, 2500])
    intra_run(tmp_path, "Pendulum-v1", "intra", 0, [-900, -200])  # a task the paper did not run
    figure = plot_curves(collect_runs(tmp_path), tmp_path / "curves.png", table="intra")
    hopper, pendulum = figure.axes
    assert (hopper.get_title(), pendulum.get_title()) == ("Hopper", "Pendulum-v1")
    for row, label in (("intra", "I_intra"), ("none", "No I_intra")):
        paper = published_cell("intra", row, "Hopper")
        color = curve_line(hopper, label).get_color()
        (line,) = [line for line in paper_lines(hopper) if line.get_color() == color]
        assert line.get_linestyle() == "--" and list(line.get_ydata()) == [paper.mean, paper.mean]
        (band,) = [patch for patch in hopper.patches
                   if patch.get_gid() == PAPER_GID and np.allclose(patch.get_facecolor()[:3], to_rgba(color)[:3])]
        assert (band.get_y(), band.get_y() + band.get_height()) == pytest.approx(
            (paper.mean - paper.std, paper.mean + paper.std))
    assert len(paper_lines(hopper)) == 2
    legend = [text.get_text() for text in hopper.get_legend().get_texts()]
    assert legend == ["No I_intra", "I_intra", PAPER_LABEL], "the paper is one legend entry for both lines"
    assert not paper_lines(pendulum) and not [patch for patch in pendulum.patches if patch.get_gid() == PAPER_GID]
    assert PAPER_LABEL not in [text.get_text() for text in pendulum.get_legend().get_texts()]


def test_a_row_without_runs_gets_no_paper_line_on_its_panel(tmp_path: Path) -> None:
    intra_run(tmp_path, "Hopper", "intra", 0, [1000, 3000])  # row "none" has a published value but no runs
    (hopper,) = plot_curves(collect_runs(tmp_path), tmp_path / "curves.png", table="intra").axes
    assert [line.get_ydata()[0] for line in paper_lines(hopper)] == [published_cell("intra", "intra", "Hopper").mean]
