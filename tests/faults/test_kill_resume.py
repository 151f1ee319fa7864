"""kill -9 a real `ilcsan train` process at three moments (CI subset of benchmarks/faults.py).

After each kill: every checkpoint on disk loads, none is older than the last evaluation the process
reported, `--resume` succeeds, and the resumed curve equals exactly that of an uninterrupted run on the
matmul path the trial measured at its start. To stay quick, the uninterrupted runs and the final resume
run through `ilcsan.cli.main` in this process (the killed run is always a real process);
benchmarks/faults.py runs everything as separate processes and checks that the in-process curve equals a
process's.
"""

from __future__ import annotations

import pytest
from fault_harness import After, During, References, RunSpec, kill_and_resume

SINGLE = RunSpec(steps=450, eval_every=150)
TWO_SEEDS = RunSpec(steps=300, eval_every=150, seeds="0,1")


@pytest.fixture(scope="module")
def references(tmp_path_factory):
    """Uninterrupted runs made on the matmul path each trial measured at its start (usually one per spec)."""
    base = tmp_path_factory.mktemp("reference")
    return {SINGLE: References(SINGLE, base / "one"), TWO_SEEDS: References(TWO_SEEDS, base / "two")}


def assert_survived(result, kills=1):
    assert result.kills == kills, result.kill_points
    assert result.corrupt == [], result.corrupt
    assert result.lost == [], result.lost
    assert result.resume_codes and all(code == 0 for code in result.resume_codes), result.resume_errors
    assert result.curves_equal
    assert result.leftovers == [], "no temporary file or orphan replay segment may stay behind"


def test_kill_at_a_moment_during_training_then_resume_exactly(tmp_path, references):
    # 0.3 s after the first checkpoint: the run is stepping and learning between evaluations
    result = kill_and_resume(SINGLE, tmp_path / "run", [After("checkpoint.pt", 0.3)], references[SINGLE],
                             final_in_process=True)
    assert_survived(result)
    assert result.checkpoint_steps == [[150]]


def test_kill_while_the_checkpoint_is_half_written(tmp_path, references):
    point = During(".checkpoint.pt.*.tmp", occurrence=2, delay=0.15)
    result = kill_and_resume(SINGLE, tmp_path / "run", [point], references[SINGLE],
                             final_in_process=True)
    assert_survived(result)
    assert result.checkpoint_steps == [[150]], "the kill hit the second checkpoint: the first one is kept"


def test_kill_between_the_seeds_checkpoints_of_a_multi_seed_run(tmp_path, references):
    # seed 0's new checkpoint is complete, seed 1's is half-written: both must resume from one step
    point = During("seed1/.checkpoint*.tmp", occurrence=2, delay=0.15)
    result = kill_and_resume(TWO_SEEDS, tmp_path / "run", [point], references[TWO_SEEDS],
                             final_in_process=True)
    assert_survived(result)
    assert result.checkpoint_steps == [[150, 150]]

