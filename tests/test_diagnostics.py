"""The stuck-actor diagnostics: hand-made spike trains, a frozen actor against a working one, and a training run
that reports them at every evaluation and names a stuck seed once."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch

from ilcsan.actors import build_actor
from ilcsan.analysis.report import write_report
from ilcsan.config import RunConfig, TrainingConfig, actor_config
from ilcsan.rl.training import Trainer
from ilcsan.runs.directory import DIAGNOSTICS
from ilcsan.snn.diagnostics import (
    STUCK_EVALUATIONS,
    EvaluationActions,
    constant_saturated_action,
    diagnose_actor,
    is_stuck,
    output_diagnostics,
    saturated_share,
    stuck_reason,
)
from ilcsan.snn.output import ActorOutput


def test_output_diagnostics_of_hand_made_trains():
    # K = 1, T = 2, B = 3 states, 2 output neurons: neuron 0 fires (1, 0) for every state (frozen), neuron 1 fires
    # for the second state only; membranes |H − 0.5| < 0.5 for 3 of the 12 neuron-steps
    spikes = torch.tensor([[[[1.0, 0.0], [1.0, 1.0], [1.0, 0.0]], [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]]]])
    membranes = torch.full((1, 2, 3, 2), 5.0)
    membranes[0, 0, 0, 1], membranes[0, 1, 2, 0], membranes[0, 1, 1, 1] = 0.1, 0.9, 0.5
    readout = torch.tensor([[[2.0, -4.0], [0.0, 0.0], [1.0, -1.0]]])
    output = ActorOutput(torch.tanh(readout), (), spikes, None, readout, membranes)
    values = output_diagnostics(output, threshold=0.5, surrogate_width=0.5)
    assert values["frozen_output_neurons"].tolist() == [0.5]
    assert values["surrogate_active"].tolist() == pytest.approx([3 / 12])
    assert values["mean_abs_preaction"].tolist() == pytest.approx([8.0 / 6])


def test_saturated_share_is_relative_to_the_action_bounds():
    scale, offset = np.array([2.0, 0.5]), np.array([1.0, 0.0])
    actions = np.array([[2.99, 0.4], [-0.99, -0.496], [1.0, 0.0]])  # |a − offset| / scale: .995 .8 / .995 .992 / 0 0
    assert saturated_share(actions, scale, offset) == pytest.approx(3 / 6)


def test_evaluation_actions_count_only_the_running_episodes():
    """Two seeds, two episodes, M = 2, scale (2, 0.5): seed 0's second episode ended after the first step, so its later
    (wild) actions are not taken; seed 1 acts with one constant corner."""
    counter = EvaluationActions(2, np.array([2.0, 0.5]), np.array([1.0, 0.0]))
    steps = [np.array([[[2.99, 0.1], [-0.99, -0.3]], [[-0.99, 0.5], [-0.99, 0.5]]]),
             np.array([[[1.0, 0.2], [9.0, 9.0]], [[-0.99, 0.5], [-0.99, 0.5]]])]
    running = [np.array([[True, True], [True, True]]), np.array([[True, False], [True, True]])]
    for actions, mask in zip(steps, running, strict=True):
        counter.observe(actions, mask)
    first, second = counter.rows()
    # seed 0: components .995/.2, .995/.6, 0/.4 → 2 of 6 saturated; ranges (2.99 − −0.99)/4 = .995, (.2 − −.3)/1 = .5
    assert first == pytest.approx({"saturated_actions": 2 / 6, "action_spread": 0.995})
    assert second == {"saturated_actions": 1.0, "action_spread": 0.0}
    assert constant_saturated_action(second) and not constant_saturated_action(first)


def frozen_actor():
    """An ILC-SAN whose output population ignores its input: every output neuron fires at every step for every
    state (zero weights, bias 10), and the decoder drives tanh far into saturation."""
    actor = build_actor(actor_config("ilc-san", hidden=(32, 32)), 3, 2, [2.0, 2.0], seeds=(0, 1))
    with torch.no_grad():
        actor.layers[-1].weight.zero_()
        actor.layers[-1].bias.fill_(10.0)
        actor.decoder.weight.fill_(1.0)
    return actor


def test_a_frozen_actor_reports_every_output_neuron_frozen():
    actor = frozen_actor()
    states = torch.randn(2, 500, 3, generator=torch.Generator().manual_seed(0)) * 2
    for row in diagnose_actor(actor, states):
        assert row["frozen_output_neurons"] == 1.0
        assert row["surrogate_active"] == 0.0  # H ≥ 10 everywhere: far outside the window
        assert row["mean_abs_preaction"] > 40
    with torch.no_grad():
        actions = actor(states).numpy()
    counter = EvaluationActions(2, np.array([2.0, 2.0]), np.zeros(2))
    counter.observe(actions, np.ones(actions.shape[:2], bool))
    for row in counter.rows():
        assert row == {"saturated_actions": 1.0, "action_spread": 0.0} and constant_saturated_action(row)


def test_a_working_actor_does_not():
    """A fresh actor whose output neurons respond to the state (weights scaled up so that they spike)."""
    actor = build_actor(actor_config("ilc-san", hidden=(32, 32)), 3, 2, [2.0, 2.0], seeds=(0, 1))
    with torch.no_grad():
        for layer in actor.layers:
            layer.weight.mul_(4.0)
    states = torch.randn(2, 500, 3, generator=torch.Generator().manual_seed(0)) * 2
    for row in diagnose_actor(actor, states):
        assert row["frozen_output_neurons"] < 0.5
        assert row["surrogate_active"] > 0.05
    with torch.no_grad():
        actions = actor(states).numpy()
    counter = EvaluationActions(2, np.array([2.0, 2.0]), np.zeros(2))
    counter.observe(actions, np.ones(actions.shape[:2], bool))
    assert all(row["action_spread"] > 0.1 and not constant_saturated_action(row) for row in counter.rows())


def test_a_constant_action_from_frozen_output_neurons_is_stuck_without_saturating():
    """As PopSAN's seed 0 on Hopper at 1M: two of three components saturated, one constant action, every output neuron
    frozen (metrics.csv at every evaluation) is stuck; the same action with outputs that still respond to the state,
    or any spread, is not; a deep actor (no frozen share) is stuck only when saturated."""
    popsan = {"saturated_actions": 2 / 3, "action_spread": 0.0, "frozen_output_neurons": 1.0}
    assert not constant_saturated_action(popsan) and "same spike train" in stuck_reason(popsan)
    assert stuck_reason({**popsan, "frozen_output_neurons": 0.5}) is None
    assert stuck_reason({**popsan, "action_spread": 0.2}) is None
    assert stuck_reason({**popsan, "frozen_output_neurons": float("nan")}) is None  # a deep actor, not saturated
    assert "saturated" in stuck_reason({"saturated_actions": 1.0, "action_spread": 0.0,
                                        "frozen_output_neurons": float("nan")})
    rows = [{"step": step, **popsan} for step in (10_000, 20_000, 30_000, 40_000)]
    assert is_stuck(rows, start_steps=10_000) and not is_stuck(rows[:3], start_steps=10_000)  # 3 after the random phase
    assert not is_stuck([*rows, {"step": 50_000, **popsan, "action_spread": 0.3}], start_steps=10_000)


def test_diagnosing_leaves_the_global_random_stream_alone():
    actor = build_actor(actor_config("ilc-san", encoder="pop-prob", hidden=(16,)), 3, 1, [1.0])
    torch.manual_seed(5)
    diagnose_actor(actor, torch.randn(1, 50, 3))
    after = torch.rand(3)
    torch.manual_seed(5)
    torch.randn(1, 50, 3)
    assert torch.equal(after, torch.rand(3))


def read_metrics(path) -> list[dict[str, str]]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_training_reports_the_diagnostics_and_names_a_stuck_seed_once(tmp_path):
    """Two seeds on Pendulum; seed 8's actor is made frozen before training and cannot learn (learning rate
    ~0), seed 9's is left as it is: after the random phase seed 8 is reported stuck once, seed 9 never."""
    config = RunConfig(task="Pendulum-v1", seeds=(8, 9), steps=1000, eval_every=200, eval_episodes=2,
                       actor=actor_config("ilc-san", hidden=(32, 32), learning_rate=1e-12),
                       training=TrainingConfig(start_steps=200, update_after=200, update_every=50, batch_size=32),
                       threads=1, compile="off")
    lines: list[str] = []
    trainer = Trainer(config, tmp_path / "run", progress=False, log=lines.append)
    with torch.no_grad():
        for actor in (trainer.agent.actor, trainer.agent.actor_target):
            actor.layers[-1].weight[0].zero_()
            actor.layers[-1].bias[0].fill_(10.0)
            actor.decoder.weight[0].fill_(1.0)
    trainer.train()
    stuck = [line for line in lines if "is stuck" in line]
    assert len(stuck) == 1 and "seed 8 is stuck" in stuck[0], lines
    frozen, working = (read_metrics(tmp_path / "run" / f"seed{seed}" / "metrics.csv") for seed in (8, 9))
    assert len(frozen) == 5 and all(name in frozen[0] for name in DIAGNOSTICS)
    evaluations_before_the_line = STUCK_EVALUATIONS + 1  # step 200 is still the random phase
    assert len(frozen) >= evaluations_before_the_line
    for row in frozen:
        assert float(row["saturated_actions"]) == 1.0 and float(row["frozen_output_neurons"]) == 1.0
        assert float(row["surrogate_active"]) == 0.0 and float(row["action_spread"]) == 0.0
    for row in working:
        assert float(row["frozen_output_neurons"]) < 1.0 and float(row["saturated_actions"]) < 0.99
        assert float(row["action_spread"]) > 0.01
    report = (write_report(tmp_path / "run")["markdown"]).read_text()
    seed_lines = {seed: next(line for line in report.splitlines() if line.startswith("| ilc-san | Pendulum-v1 | "
                                                                                     f"{seed} |")) for seed in (8, 9)}
    assert seed_lines[8].endswith("| 1.00 | 1.00 | 0.00 | " + seed_lines[8].split(" | ")[-3] + " | 0.00 | **stuck** |")
    assert "stuck" not in seed_lines[9]
    assert "stuck at their last evaluations: 1)" in report
