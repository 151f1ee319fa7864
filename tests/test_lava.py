"""The actor as Lava processes (Loihi 2's SDK), ``ilcsan.deploy.lava``.

Everywhere: the plan, simulated in numpy with Lava's rules, equals the numpy runtime (actions and every layer's
spike trains) on every fully spiking CLIF actor; its fixed-point formats are Loihi 2's; actors it cannot map are
refused in one line. Where Lava's environment exists (``scripts/setup-lava``; the test script builds it when a
Python 3.10 is found): Lava's floating-point models give ``Policy.predict``'s actions to 1e-5 with the runtime's
spike counts, and its bit-accurate fixed-point models equal the numpy mirror of their integer rules exactly.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from spiking_policies import FULLY_SPIKING, case_id, deployed, hand_made_policy, observations, random_policy

from ilcsan.deploy import DeployedActor
from ilcsan.deploy.bundle import export_npz
from ilcsan.deploy.lava import LAVA_PYTHON_VARIABLE, lava_python
from ilcsan.deploy.lava.plan import (
    DECAY_BITS,
    DECODER,
    EXPONENT_LIMITS,
    THRESHOLD_LIMIT,
    WEIGHT_LIMITS,
    encoder_spikes,
    fix_plan,
    host_action,
    plan_actor,
    simulate,
)
from ilcsan.errors import UserError

CLIF = [case for case in FULLY_SPIKING if case[1].get("neuron") != "dynamic"]
IN_LAVA = [case for case in CLIF
           if case[1].get("alpha_v_li", 0.75) == 0.75 and case[1].get("hidden") in (None, (40,) * 4)]
"""Every intra variant, both timings, D_last/D_max/D_mean with α_V^LI = 0.75, 2 and 4 hidden layers, T = 2 and 8,
PopSAN's backbone: each Lava actor costs seconds to build, so the other α_V^LI and the 1- and 3-layer cases run in
numpy only (the plan's test above)."""
FIXED_CASES = ("ilc-san", "ilc-san-intra_timing=authors", "ilc-san-hidden=(40, 40, 40, 40)")
TOLERANCE = 1e-5


def plan_action(actor: DeployedActor, observation: np.ndarray, fixed=None) -> tuple[np.ndarray, dict]:
    plan = fixed.plan if fixed is not None else plan_actor(actor)
    voltages, recorded = simulate(plan, encoder_spikes(actor, observation), fixed, record=True)
    return host_action(actor, voltages), recorded


def layer_windows(recorded: dict, plan) -> list[np.ndarray]:
    """Each synaptic layer's spikes at its T steps of the block (layer l: steps l + 1 .. l + T)."""
    return [recorded[f"layer{index}"][index:index + plan.timesteps] for index in range(1, len(plan.populations))]


# --------------------------------------------------------------------------------- the plan, in numpy
@pytest.mark.parametrize("case", CLIF, ids=case_id)
def test_the_plan_equals_the_runtime_action_and_spikes(case):
    preset, overrides = case
    policy = random_policy(preset, **overrides)
    actor = deployed(policy)
    plan = plan_actor(actor)
    assert plan.block == plan.timesteps + len(actor.layers) + 1
    for observation in observations(policy, 6):
        action, recorded = plan_action(actor, observation)
        trains = actor.spike_trains(observation)
        assert np.abs(action - actor.act(observation)).max() < 1e-6
        for planned, train in zip(layer_windows(recorded, plan), trains[1:], strict=True):
            np.testing.assert_array_equal(planned, train.astype(bool))


def test_the_hand_made_actor_keeps_its_spikes_in_fixed_point():
    """The hand-made actor's spikes are known (tests/spiking_policies.py): the fixed-point plan keeps them all."""
    policy = hand_made_policy()
    actor = deployed(policy)
    observation = np.zeros(3)
    fixed = fix_plan(plan_actor(actor), [actor.spike_trains(observation)[0]])
    _, floating = plan_action(actor, observation)
    _, integer = plan_action(actor, observation, fixed)
    for name in ("layer1", "layer2"):
        np.testing.assert_array_equal(floating[name], integer[name])
    assert floating["layer1"][1:6, 0].all() and floating["layer1"][2:6, 1].all() and not floating["layer1"][1, 1]


def test_fixed_point_formats_are_loihi_2s():
    policy = random_policy("ilc-san")
    actor = deployed(policy)
    batch = observations(policy, 8)
    plan = plan_actor(actor)
    fixed = fix_plan(plan, [actor.spike_trains(row)[0] for row in batch])
    for population in plan.populations[:-1]:
        threshold = fixed.thresholds[population.name]
        assert 0 < threshold <= THRESHOLD_LIMIT and threshold & (threshold - 1) == 0  # a power of two
        assert fixed.units[population.name] * threshold == pytest.approx(population.threshold)
        assert 1 - (fixed.du[population.name] + 1) / 2 ** DECAY_BITS == 0.5  # α_C, exact
        assert 1 - fixed.dv[population.name] / 2 ** DECAY_BITS == 0.75  # α_V, exact
    for weights, exponent, projection in zip(fixed.weights, fixed.exponents, plan.projections, strict=True):
        assert weights.min() >= WEIGHT_LIMITS[0] and weights.max() <= WEIGHT_LIMITS[1] and not (weights % 2).any()
        assert EXPONENT_LIMITS[0] <= exponent <= EXPONENT_LIMITS[1]
        step = fixed.units[projection.target] * 2.0 ** exponent
        assert np.abs(weights * step - projection.weights).max() <= step * (1 + 1e-9)
    errors = [np.abs(plan_action(actor, row, fixed)[0] - actor.act(row)).max() for row in batch]
    assert max(errors) < 0.3 * np.max(actor.action_scale), errors  # 8-bit weights: close, not equal
    assert fixed.units[DECODER] > 0


def test_actors_lava_cannot_map_are_refused_in_one_line():
    with pytest.raises(UserError, match="CLIF actors") as error:
        plan_actor(deployed(random_policy("ilc-san", neuron="dynamic")))
    assert "\n" not in str(error.value)


def test_a_missing_lava_environment_is_one_line(monkeypatch, tmp_path):
    monkeypatch.setenv(LAVA_PYTHON_VARIABLE, str(tmp_path / "nowhere" / "python"))
    with pytest.raises(UserError, match="scripts/setup-lava"):
        lava_python()


@pytest.mark.parametrize("option, value, message", [
    ("--episodes", "0", "'0' must be at least 1"),
    ("--seed", "-1", "'-1' must be at least 0"),
    ("--check", "some", "'some' is not a whole number"),
])
def test_the_runner_refuses_bad_counts_before_loading_anything(option, value, message, capsys):
    from ilcsan.deploy.lava.__main__ import main

    with pytest.raises(SystemExit) as stop:
        main(["no-such-bundle.npz", option, value])
    assert stop.value.code == 2
    assert f"argument {option}: {message}" in capsys.readouterr().err


# --------------------------------------------------------------------------------- Lava itself
def _lava_or_skip() -> Path:
    try:
        return lava_python()
    except UserError as error:
        pytest.skip(f"Lava's environment is missing ({error})")


def test_lava_runs_every_clif_actor_as_predict_and_bit_accurately_in_fixed_point(tmp_path):
    python = _lava_or_skip()
    expected = {}
    for case in IN_LAVA:
        name = case_id(case)
        policy = random_policy(case[0], **case[1])
        batch = observations(policy, 3)
        export_npz(policy, tmp_path / f"{name}.npz")
        np.save(tmp_path / f"{name}.obs.npy", batch)
        actor = deployed(policy)
        counts = np.zeros(len(actor.layers), int)
        for row in batch:
            counts += [int(np.count_nonzero(train)) for train in actor.spike_trains(row)[1:]]
        expected[name] = (policy.predict(batch), counts)
    (tmp_path / "fixed.json").write_text(json.dumps(FIXED_CASES))
    script = Path(__file__).with_name("lava_check.py")
    done = subprocess.run([str(python), str(script), str(tmp_path)], capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    results = json.loads((tmp_path / "results.json").read_text())
    for name, (actions, counts) in expected.items():
        result = results[name]
        assert np.abs(np.array(result["actions"]) - actions).max() <= TOLERANCE, name
        assert [result["spikes"][f"layer{index + 1}"] for index in range(len(counts))] == counts.tolist(), name
        assert counts.min() > 0, name  # every layer spikes: the comparison is not of silence
    assert [results[name]["fixed_gap"] for name in FIXED_CASES] == [0.0] * len(FIXED_CASES)


def test_the_closed_loop_command_plays_the_mirror_like_the_runtime(tmp_path, capsys):
    """``python -m ilcsan.deploy.lava --engine mirror`` (Lava's rules in numpy) plays a Hopper episode as the numpy
    runtime does; a file that is not a bundle is one line and exit code 2."""
    from ilcsan.deploy.lava.__main__ import main

    bundle = export_npz(random_policy("ilc-san", hidden=(32,)), tmp_path / "actor.npz")
    returns = {}
    for engine in ("mirror", "numpy"):
        out = tmp_path / f"{engine}.json"
        assert main([str(bundle), "--engine", engine, "--episodes", "1", "--check", "20", "--json", str(out)]) == 0
        result = json.loads(out.read_text())
        returns[engine] = result["returns"]
        assert result["checked_actions"] == min(20, result["lengths"][0])
        assert result["max_action_error"] <= TOLERANCE and result["actions_off"] == 0
        assert result["median_action_error"] <= result["p90_action_error"] <= result["max_action_error"]
    assert returns["mirror"] == pytest.approx(returns["numpy"], abs=1e-3)
    (tmp_path / "broken.npz").write_text("not a bundle")
    assert main([str(tmp_path / "broken.npz"), "--engine", "mirror", "--episodes", "1"]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("error: ") and "\n" not in error


def test_a_lava_run_cut_short_keeps_its_episodes_and_its_check(tmp_path, monkeypatch, capsys):
    """The ``--json`` file holds every finished episode when a later one is interrupted, and the ``--check`` line is
    printed once, as soon as its N actions are compared, not only at the end."""
    import ilcsan.rl.tasks as tasks
    from ilcsan.deploy.lava.__main__ import main

    bundle = export_npz(random_policy("ilc-san", hidden=(32,)), tmp_path / "actor.npz")
    made = []

    def make_env_then_interrupt(task, seed, contact_forces=None):
        if len(made) == 2:
            raise KeyboardInterrupt
        made.append(seed)
        return real_make_env(task, seed=seed, contact_forces=contact_forces)

    real_make_env = tasks.make_env
    monkeypatch.setattr(tasks, "make_env", make_env_then_interrupt)
    out = tmp_path / "run.json"
    with pytest.raises(KeyboardInterrupt):
        main([str(bundle), "--engine", "mirror", "--episodes", "5", "--seed", "3", "--check", "5", "--json", str(out)])
    result = json.loads(out.read_text())
    assert made == [3, 4] and result["episodes_done"] == 2 and not result["finished"]
    assert len(result["returns"]) == len(result["lengths"]) == 2 and result["checked_actions"] == 5
    printed = capsys.readouterr().out.splitlines()
    check_lines = [number for number, line in enumerate(printed) if line.startswith("largest action error")]
    assert len(check_lines) == 1 and printed[check_lines[0] - 1].startswith("episode 1/5")
    assert not (tmp_path / "run.json.partial").exists()
