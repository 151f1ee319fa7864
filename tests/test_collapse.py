"""The collapsed-start statistics: Wilson's interval and Fisher's exact test against hand-computed values, the
per-row table from run records, and the diagnostics figure."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from ilcsan.analysis.collapse import (
    collapse_markdown,
    collapse_rows,
    diagnostic_panels,
    fisher_exact,
    plot_diagnostics,
    wilson_interval,
)
from ilcsan.analysis.collect import RunRecord


def test_wilson_interval_of_hand_computed_shares():
    # 0 of 16: (0, z²/(n + z²)) = (0, 3.8415/19.8415)
    low, high = wilson_interval(0, 16)
    assert low == 0.0 and high == pytest.approx(3.841459 / 19.841459, rel=1e-6)
    low, high = wilson_interval(5, 10)  # symmetric around 1/2: 0.5 ± z·sqrt(0.025 + z²/400)/(1 + z²/10)
    half = 1.959964 * math.sqrt(0.025 + 1.959964 ** 2 / 400) / (1 + 1.959964 ** 2 / 10)
    assert (low, high) == pytest.approx((0.5 - half, 0.5 + half), rel=1e-6)
    assert math.isnan(wilson_interval(0, 0)[0])


def test_fisher_exact_reproduces_the_lady_tasting_tea():
    # Fisher's own example: 3 of 4 against 1 of 4, two-sided p = 34/70
    assert fisher_exact((3, 4), (1, 4)) == pytest.approx(34 / 70)
    assert fisher_exact((4, 4), (0, 4)) == pytest.approx(2 / 70)
    assert fisher_exact((2, 8), (2, 8)) == pytest.approx(1.0)
    # 6 of 23 against 1 of 9 (the pooled counts): hypergeometric sum by hand below
    n1, n2, k = 23, 9, 7
    probabilities = [math.comb(n1, a) * math.comb(n2, k - a) / math.comb(n1 + n2, k) for a in range(0, 8)]
    observed = probabilities[6]
    assert fisher_exact((6, 23), (1, 9)) == pytest.approx(sum(p for p in probabilities if p <= observed * (1 + 1e-9)))


def record(seed: int, returns: list[float], diagnostics: dict | None = None) -> RunRecord:
    steps = tuple(10_000 * (index + 1) for index in range(len(returns)))
    return RunRecord(path=Path(f"/runs/seed{seed}"), task="Hopper", seed=seed, label="x", table=None, row=None,
                     actor={}, best_return=max(returns), best_step=steps[returns.index(max(returns))],
                     steps_done=steps[-1], steps_total=None, finished=True, steps=steps, returns=tuple(returns),
                     diagnostics=diagnostics or {})


def test_collapse_rows_count_seeds_below_the_threshold_at_each_step():
    runs = [record(0, [39, 39, 40, 41, 300]), record(1, [39, 250, 800, 900, 1000]), record(2, [39, 39, 39, 39, 39])]
    (row,) = collapse_rows({"paper": runs}, steps=(30_000, 50_000))
    assert row.counts == {30_000: (2, 3), 50_000: (1, 3)}
    assert row.best == (300, 1000, 39) and row.last == (300, 1000, 39)
    (short,) = collapse_rows({"paper": runs}, steps=(30_000,), until=30_000)
    assert short.best == (40, 800, 39)
    table = collapse_markdown(collapse_rows({"a": runs, "b": runs[:2]}, steps=(30_000,)), steps=(30_000,))
    assert "| a | 2/3 (67 %" in table and "a vs b: at 30 000: p = " in table
    young = [record(3, [39, 150])]  # a row still running: no evaluation at 30 000 yet
    table = collapse_markdown(collapse_rows({"a": runs, "young": young}, steps=(30_000,)), steps=(30_000,))
    assert "- a vs young: no test: one of them has no evaluation at these steps yet" in table


def test_the_diagnostics_figure_is_drawn(tmp_path):
    diagnostics = {"saturated_actions": (1.0, 1.0), "frozen_output_neurons": (1.0, 1.0), "surrogate_active": (0.0, 0.0),
                   "mean_abs_preaction": (40.0, 41.0)}
    runs = [record(0, [39, 39], diagnostics), record(1, [39, 400], {k: (0.2, 0.1) for k in diagnostics})]
    path = plot_diagnostics({"paper": runs}, tmp_path / "diagnostics.png", collapsed_at=20_000, until=50_000)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 10_000


def test_the_figure_leaves_out_runs_without_diagnostics_and_draws_only_logged_columns():
    """Runs of the authors' code log returns only; older runs lack the later diagnostics."""
    older = {"saturated_actions": (1.0, 0.5), "frozen_output_neurons": (1.0, 0.2)}
    groups = {"paper": [record(0, [39, 400], older)], "authors' code": [record(1, [39, 39], {})],
              "late": [record(2, [39, 39], {**older, "surrogate_active": (0.1, float("nan"))})]}
    logged, names = diagnostic_panels(groups, until=50_000)
    assert list(logged) == ["paper", "late"]
    assert names == ["saturated_actions", "frozen_output_neurons", "surrogate_active"]
    assert diagnostic_panels(groups, until=5_000) == ({}, [])  # nothing logged before the first evaluation


def write_run(folder: Path, seed: int, row: str, returns: list[float]) -> None:
    folder.mkdir(parents=True)
    (folder / "config.json").write_text(json.dumps({"task": "Hopper", "seed": seed, "label": row, "table": "mine",
                                                    "row": row, "actor": {"preset": "ilc-san"}}))
    lines = ["step,eval_return_mean,saturated_actions,frozen_output_neurons,surrogate_active,mean_abs_preaction"]
    for index, value in enumerate(returns):
        collapsed = value < 100
        lines.append(f"{10_000 * (index + 1)},{value},{1.0 if collapsed else 0.3},{1.0 if collapsed else 0.2},"
                     f"{0.0 if collapsed else 0.4},{40.0 if collapsed else 1.0}")
    (folder / "metrics.csv").write_text("\n".join(lines) + "\n")


def test_report_collapse_adds_the_table_and_the_figure(tmp_path, capsys):
    from ilcsan.cli import main

    for seed, returns in enumerate([[39, 39, 39, 39, 39], [39, 39, 300, 800, 900], [39, 150, 400, 900, 1200]]):
        write_run(tmp_path / "runs" / "paper" / f"seed{seed}", seed, "paper", returns)
    for seed in range(3):
        write_run(tmp_path / "runs" / "authors" / f"seed{seed}", seed, "authors", [39, 200, 500, 900, 1500])
    assert main(["report", str(tmp_path / "runs"), "--collapse", "30000,50000"]) == 0
    report = (tmp_path / "runs" / "report.md").read_text()
    assert "## Collapsed start" in report and "| paper | 1/3 (33 %" in report and "| authors | 0/3 (0 %" in report
    assert "authors vs paper: at 30 000: p = 1.000, at 50 000: p = 1.000" in report
    assert (tmp_path / "runs" / "diagnostics.png").stat().st_size > 10_000
    capsys.readouterr()
    assert main(["report", str(tmp_path / "runs"), "--collapse", "thirty"]) == 2
    assert "--collapse 'thirty': give positive step numbers" in capsys.readouterr().err
