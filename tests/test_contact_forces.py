"""The paper's simulator: external contact forces read as zeros (mujoco-py 2.1 never computed them), in the state and
in the rewards made from them, while the dynamics and every other value stay Gymnasium's."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from spiking_policies import random_policy

from ilcsan.cli import main
from ilcsan.config import CONTACT_FORCE_TASKS, RunConfig, actor_config, contact_forces_of
from ilcsan.deploy.bundle import bundle_meta
from ilcsan.errors import UserError
from ilcsan.rl.tasks import TASK_SPECS, make_env, trained_contact_forces

CONTACT_VALUES = 84
"""cfrc_ext of the 14 bodies of Ant's and the humanoids' models, 6 values each, at the end of their states."""
STEPS = 40


def _play(env, actions):
    """Observations (reset first), rewards and infos of ``actions`` from ``env``'s seeded reset."""
    observation, _ = env.reset(seed=5)
    observations, rewards, infos = [observation], [], []
    for action in actions:
        observation, reward, terminated, truncated, info = env.step(action)
        observations.append(observation)
        rewards.append(reward)
        infos.append(info)
        if terminated or truncated:
            break
    env.close()
    return np.array(observations), np.array(rewards), infos


def _actions(env, count=STEPS):
    rng = np.random.default_rng(1)
    return [rng.uniform(env.action_space.low, env.action_space.high) for _ in range(count)]


@pytest.mark.parametrize("task", CONTACT_FORCE_TASKS)
def test_contact_forces_read_zero_and_every_other_value_is_gymnasiums(task):
    zeroed_env, simulated_env = make_env(task), make_env(task, contact_forces="simulated")
    actions = _actions(zeroed_env)
    zeroed, _, _ = _play(zeroed_env, actions)
    simulated, _, _ = _play(simulated_env, actions)
    assert zeroed.shape[1] == TASK_SPECS[task].state_dim  # the paper's N
    assert np.all(zeroed[:, -CONTACT_VALUES:] == 0.0)
    assert np.count_nonzero(simulated[:, -CONTACT_VALUES:]) > 0  # Gymnasium's own forces are real
    assert np.array_equal(zeroed[:, :-CONTACT_VALUES], simulated[:, :-CONTACT_VALUES])  # bit for bit


def test_ants_reward_is_the_papers_without_its_contact_cost():
    """Ant-v3's reward subtracted 5e-4·Σ clip(cfrc_ext)², zero in the paper's simulator: the same reward as Ant-v4
    without contact forces, whose reward has no contact cost."""
    zeroed_env = make_env("Ant")
    actions = _actions(zeroed_env)
    _, zeroed, _ = _play(zeroed_env, actions)
    _, simulated, _ = _play(make_env("Ant", contact_forces="simulated"), actions)
    _, without_forces, _ = _play(gym.make("Ant-v4", use_contact_forces=False), actions)
    assert np.array_equal(zeroed, without_forces)
    assert not np.array_equal(zeroed, simulated)


def test_humanoid_standups_impact_cost_is_zero():
    zeroed_env = make_env("HumanoidStandup")
    actions = _actions(zeroed_env)
    _, zeroed, zeroed_infos = _play(zeroed_env, actions)
    _, simulated, simulated_infos = _play(make_env("HumanoidStandup", contact_forces="simulated"), actions)
    assert all(info["reward_impact"] == 0.0 for info in zeroed_infos)
    impact = np.array([info["reward_impact"] for info in simulated_infos])
    assert np.any(impact != 0.0)
    np.testing.assert_allclose(zeroed, simulated - impact, rtol=0, atol=1e-9)


def test_a_task_that_never_reads_contact_forces_is_unchanged():
    env = make_env("Hopper", contact_forces="zeroed")
    actions = _actions(env, 200)
    zeroed = _play(env, actions)
    simulated = _play(make_env("Hopper", contact_forces="simulated"), actions)
    assert np.array_equal(zeroed[0], simulated[0]) and np.array_equal(zeroed[1], simulated[1])


def test_zeroing_a_task_without_mujoco_is_one_clear_error():
    with pytest.raises(UserError, match="needs a MuJoCo task"):
        make_env("Pendulum-v1", contact_forces="zeroed")


def test_the_default_follows_the_task_name():
    assert contact_forces_of("ant", None) == contact_forces_of("HumanoidStandup", None) == "zeroed"
    assert contact_forces_of("Ant-v4", None) == contact_forces_of("Hopper", None) == "simulated"
    assert contact_forces_of("Ant", "simulated") == "simulated"
    assert contact_forces_of("Hopper", "zeroed") == "zeroed"


def test_config_json_records_the_contact_forces_and_an_older_one_ran_mujocos():
    ant = RunConfig(task="Ant", actor=actor_config("ilc-san"))
    assert ant.contact_forces is None and ant.for_seed(0)["contact_forces"] == "zeroed"
    assert RunConfig(task="Ant", contact_forces="simulated").for_seed(0)["contact_forces"] == "simulated"
    older = {key: value for key, value in ant.for_seed(0).items() if key != "contact_forces"}
    assert RunConfig.from_dict(older).task_contact_forces() == "simulated"
    assert RunConfig.from_dict(ant.for_seed(0)).task_contact_forces() == "zeroed"


def test_bundles_and_policies_carry_the_contact_forces_they_trained_with():
    policy = random_policy()
    assert trained_contact_forces(policy) == "simulated"  # a policy saved before the setting: MuJoCo's forces
    policy.contact_forces = "zeroed"
    assert bundle_meta(policy)["contact_forces"] == "zeroed"
    assert trained_contact_forces(policy) == "zeroed"


def test_the_cli_refuses_an_unknown_choice_and_tasks_shows_the_default(capsys):
    assert main(["train", "--task", "Ant", "--contact-forces", "none", "--steps", "10"]) == 2
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0 and "--contact-forces 'none' is not one of: zeroed, simulated" in error
    assert main(["tasks"]) == 0
    rows = {line.split()[0]: line for line in capsys.readouterr().out.splitlines() if line}
    assert " zeroed " in rows["Ant"] and " zeroed " in rows["Humanoid"] and " zeroed " not in rows["Hopper"]


def test_a_training_run_uses_and_records_the_papers_contact_forces(tmp_path):
    from ilcsan.deploy.policy import load
    from ilcsan.rl.training import Trainer

    config = RunConfig(task="Ant", seeds=(0,), steps=60, eval_every=60, eval_episodes=1,
                       actor=actor_config("ilc-san", hidden=(8,)), threads=1, compile="off")
    trainer = Trainer(config, tmp_path, progress=False, log=lambda *_: None)
    trainer.train()
    observations = trainer.replay.sample_states([np.random.default_rng(0)], 50)
    assert np.all(observations[..., -CONTACT_VALUES:] == 0.0) and np.any(observations[..., :-CONTACT_VALUES] != 0)
    assert json.loads((tmp_path / "config.json").read_text())["contact_forces"] == "zeroed"
    assert load(tmp_path).contact_forces == "zeroed"


def _ant_cell(root, *choices):
    """Table intra's Ant I_intra cell, one run per choice, each config.json with that contact-forces value (None: a
    run recorded before the setting)."""
    from test_report import intra_run

    for seed, choice in enumerate(choices):
        folder = intra_run(root, "Ant", "intra", seed, [1000.0 + seed, 2000.0])
        config = json.loads((folder / "config.json").read_text())
        if choice is not None:
            config["contact_forces"] = choice
        (folder / "config.json").write_text(json.dumps(config))


@pytest.mark.parametrize(("choices", "expected"), [
    (("zeroed", "zeroed"), None),
    (("zeroed", "simulated", None), "runs differ in contact forces (simulated ×2, zeroed ×1)"),
    (("simulated", None), "contact forces simulated: not the paper's states"),
])
def test_the_report_names_cells_whose_contact_forces_differ_or_are_not_the_papers(tmp_path, choices, expected):
    from test_provenance import report_notes

    _ant_cell(tmp_path, *choices)
    notes, _, _ = report_notes(tmp_path)
    if expected is None:
        assert notes == []
    else:
        assert len(notes) == 1 and notes[0].startswith("Ant · I\\_intra: " + expected)
