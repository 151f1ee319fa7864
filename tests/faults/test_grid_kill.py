"""kill -9 an `ilcsan reproduce GRID.toml` with its worker processes, run it again (CI subset of
benchmarks/faults.py): the grid finishes, no checkpoint is corrupt, nothing is left half-written, and
every run's curve equals the same cell trained without interruption. More kill points (between
evaluations, at random moments, several kills in a row) are in benchmarks/faults.py."""

from __future__ import annotations

from fault_harness import During, GridSpec, grid_reference_in_process, kill_grid_and_rerun

GRID = GridSpec(seeds=2, steps=1100, eval_every=550, rows=1, workers=1)


def test_grid_killed_with_its_workers_then_run_again_equals_a_straight_run(tmp_path):
    # the kill hits the worker while seed 1's final checkpoint is half-written (seed 0's is complete)
    point = During("**/seed1/.checkpoint*.tmp", occurrence=2, delay=0.15)
    report = kill_grid_and_rerun(GRID, tmp_path / "grid", [point], final_in_process=True)
    assert report["kills"] == 1, report["kill_points"]
    assert report["corrupt"] == []
    assert report["codes"] == [0], report["errors"]
    assert report["leftovers"] == []
    curves = report["curves"]
    assert sorted(curves) == ["faults/Pendulum-v1/ilc/seed0", "faults/Pendulum-v1/ilc/seed1"]
    assert all(len(values) == 2 for values in curves.values())
    assert curves == grid_reference_in_process(tmp_path / "grid" / "out")

