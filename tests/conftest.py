"""Shared fixtures: one torch thread per test process, quiet MuJoCo logs, small actors."""

from __future__ import annotations

import os

import pytest
import torch

os.environ.setdefault("MPLBACKEND", "Agg")
torch.set_num_threads(1)


@pytest.fixture(autouse=True)
def _no_machine_measurement(monkeypatch):
    """A listing's estimates from a set speed, not from measuring this machine (a minute, and a real training run
    inside a test that may have stubbed the agent); the tests of the measurement unset it."""
    monkeypatch.setenv("ILCSAN_STEPS_PER_SECOND", "200")


@pytest.fixture(autouse=True)
def _deterministic_torch():
    torch.manual_seed(0)
    yield
    from ilcsan.compute.process import denormals_flushed, flush_denormals

    if denormals_flushed():  # a run flushes denormals and must give the setting back (hypothesis needs them)
        flush_denormals(False)
        pytest.fail("the test left this process flushing denormal floats to zero")


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory):
    """A tiny ILC-SAN run on Pendulum (300 steps): a real run directory with policy and checkpoint."""
    from ilcsan.config import RunConfig, TrainingConfig, actor_config
    from ilcsan.rl.training import train

    out = tmp_path_factory.mktemp("runs") / "pendulum"
    config = RunConfig(task="Pendulum-v1", seeds=(0,), steps=300, eval_every=150, eval_episodes=1,
                       actor=actor_config("ilc-san", hidden=(16, 16)),
                       training=TrainingConfig(start_steps=150, update_after=100, update_every=25, batch_size=16),
                       threads=1)
    train(config, out, progress=False, log=lambda *_: None)
    return out
