"""The user-facing surface: ilcsan.load(...).predict(obs), the CLI, and clear errors for bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import ilcsan
from ilcsan.cli import main
from ilcsan.cli.options import parse_seeds
from ilcsan.errors import UserError


def run_cli(capsys, *argv):
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def assert_one_line_error(code, err, *fragments):
    assert code == 2
    lines = [line for line in err.strip().splitlines() if line]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for fragment in fragments:
        assert fragment in lines[0]


def test_predict_single_and_batch(trained_run):
    policy = ilcsan.load(trained_run)
    observation = np.array([1.0, 0.0, 0.5])
    action = policy.predict(observation)
    assert action.shape == (1,) and -2.0 <= action[0] <= 2.0
    batch = policy.predict(np.stack([observation, -observation, observation]))
    assert batch.shape == (3, 1)
    assert batch[0] == pytest.approx(action[0], abs=1e-6) and batch[2] == pytest.approx(action[0], abs=1e-6)
    assert policy.predict(observation)[0] == action[0], "predict is deterministic"


def test_a_compiled_policy_predicts_the_eager_actions_for_each_batch_size(trained_run):
    eager, compiled = ilcsan.load(trained_run), ilcsan.load(trained_run, compile=True)
    assert compiled.compiled and not eager.compiled
    observations = np.random.default_rng(0).normal(size=(5, 3)) * [1.0, 1.0, 4.0]
    for batch in (observations[0], observations, observations[:2]):  # batch 1, 5, 2: a program each
        np.testing.assert_allclose(compiled.predict(batch), eager.predict(batch), atol=1e-5)
    assert len(compiled.forward.programs) == 3
    with pytest.raises(UserError, match="NaN"):  # validated before the program runs
        compiled.predict(np.array([np.nan, 0.0, 0.0]))


def test_predict_uses_the_frozen_normaliser(trained_run):
    policy = ilcsan.load(trained_run)
    observation = np.array([0.3, -0.2, 1.0])
    normalised = np.clip((observation - policy.obs_mean) / policy.obs_std, -3, 3)
    import torch

    with torch.no_grad():
        expected = policy.actor(torch.tensor(normalised, dtype=torch.float32).reshape(1, 1, 3))[0, 0].numpy()
    assert policy.predict(observation) == pytest.approx(expected, abs=1e-6)


@pytest.mark.parametrize("observation, message", [
    (np.zeros(4), "shape"), (np.zeros((2, 2)), "shape"), (np.array([np.nan, 0.0, 0.0]), "NaN"),
    (np.array([np.inf, 0.0, 0.0]), "NaN or inf"), ("abc", "numbers"), (np.zeros((0, 3)), "shape"),
])
def test_predict_rejects_bad_observations(trained_run, observation, message):
    policy = ilcsan.load(trained_run)
    with pytest.raises(UserError, match=message):
        policy.predict(observation)


def test_checkpoint_loads_as_the_last_actor(trained_run):
    policy = ilcsan.load(trained_run / "checkpoint.pt")
    assert policy.predict(np.zeros(3)).shape == (1,)


def test_evaluate_command(trained_run, capsys):
    code, out, _ = run_cli(capsys, "evaluate", str(trained_run), "--episodes", "2")
    assert code == 0 and "average return" in out and "Pendulum-v1" in out and "(std over the episodes; min" in out


def test_evaluate_plays_a_deploy_bundle_in_the_numpy_runtime(trained_run, tmp_path, capsys):
    from ilcsan.deploy import DeployedActor
    from ilcsan.rl.evaluation import evaluate_policy

    for weights in ("float32", "int8"):
        assert run_cli(capsys, "export", str(trained_run), "--weights", weights,
                       "--out", str(tmp_path / f"{weights}.npz"))[0] == 0
    policy_returns, policy_lengths = evaluate_policy(ilcsan.load(trained_run), episodes=2, seed=3)
    bundle_returns, bundle_lengths = evaluate_policy(DeployedActor.load(tmp_path / "float32.npz"), episodes=2, seed=3)
    assert bundle_lengths == policy_lengths == [200, 200]
    np.testing.assert_allclose(bundle_returns, policy_returns, rtol=1e-4)  # actions equal to float32 rounding
    code, out, _ = run_cli(capsys, "evaluate", str(tmp_path / "int8.npz"), "--episodes", "2", "--seed", "3")
    assert code == 0 and "Pendulum-v1 · ilc-san · deploy bundle, int8 weights · 2 episodes: average return" in out
    int8 = DeployedActor.load(tmp_path / "int8.npz")
    evaluate_policy(int8, episodes=2, seed=3)
    assert int8.inferences == 400 and int8.total_sop > 0
    assert f"synaptic operations per action: {int8.total_sop / 400:.0f} on average over 400 actions" in out


def test_commands_refuse_what_they_cannot_use_in_one_line(tmp_path, capsys):
    graph, bundle = tmp_path / "actor.nir", tmp_path / "actor.npz"
    graph.write_bytes(b"")
    bundle.write_bytes(b"")
    for command in ("evaluate", "export", "energy", "lava"):
        assert_one_line_error(*run_cli(capsys, command, str(graph))[::2], "is a NIR graph", "not a trained policy")
    for command in ("export", "energy"):
        assert_one_line_error(*run_cli(capsys, command, str(bundle))[::2], "is a deploy bundle", "run directory")
    empty = tmp_path / "empty"
    empty.mkdir()
    assert_one_line_error(*run_cli(capsys, "report", str(empty))[::2], "no runs below", "config.json")
    assert not any(empty.iterdir()), "no report is written without runs"
    broken = empty / "run"
    broken.mkdir()
    (broken / "config.json").write_text("{")
    (broken / "metrics.csv").write_text("step\n")
    assert_one_line_error(*run_cli(capsys, "report", str(empty))[::2], "no usable run", "1 skipped", "config.json")


def test_export_npz_bundle_names_and_meta(trained_run, tmp_path, capsys):
    target = tmp_path / "actor.npz"
    code, out, _ = run_cli(capsys, "export", str(trained_run), "--format", "npz", "--out", str(target))
    assert code == 0 and target.is_file()
    with np.load(target, allow_pickle=False) as bundle:
        names = set(bundle.files)
        meta = json.loads(str(bundle["meta"]))
        assert bundle["encoder.mu"].shape == (3, 10) and bundle["encoder.mu"].dtype == np.float32
        assert bundle["layers.0.weight"].shape == (16, 30)
        assert bundle["layers.2.weight"].shape == (10, 16)
        assert bundle["intra.weight"].shape == (1, 10, 10)
        assert bundle["decoder.weight"].shape == (1, 10) and bundle["decoder.bias"].shape == (1,)
    assert {"encoder.mu", "encoder.sigma", "layers.0.weight", "layers.0.bias", "layers.1.weight", "layers.1.bias",
            "layers.2.weight", "layers.2.bias", "intra.weight", "intra.bias", "decoder.weight", "decoder.bias",
            "meta"} == names
    for key in ("T", "alpha_c", "alpha_v", "v_th", "v_reset", "alpha_v_li", "v_reset_li", "statistic", "encoder",
                "enc_v_th", "obs_mean", "obs_std", "obs_clip", "action_scale", "output"):
        assert key in meta
    assert meta["T"] == 5 and meta["statistic"] == "last" and meta["action_scale"] == [2.0]


@pytest.mark.parametrize("argv, fragments", [
    (["train", "--task", "NoSuchTask-v9", "--steps", "10"], ["unknown task", "NoSuchTask-v9"]),
    (["train", "--task", "CartPole-v1", "--steps", "10"], ["Discrete", "Box"]),
    (["train", "--actor", "snn", "--steps", "10"], ["unknown actor preset"]),
    (["train", "--intra", "diagonal", "--steps", "10"], ["--intra"]),
    (["train", "--hidden-width", "0"], ["--hidden-width", "at least 1"]),
    (["train", "--hidden-layers", "7"], ["1 to 4"]),
    (["train", "--seeds", "3-1"], ["--seeds"]),
    (["train", "--steps", "many"], ["--steps"]),
    (["train", "--engine", "turbo", "--steps", "10"], ["--engine"]),
    (["train", "--no-such-option"], ["unrecognized"]),
    (["evaluate", "/nonexistent/run"], ["does not exist"]),
    (["export", "/nonexistent/run", "--format", "onnx"], ["--format"]),
    (["lava", "/nonexistent/run", "--episodes", "0"], ["--episodes", "'0' must be at least 1"]),
    (["lava", "/nonexistent/run", "--check", "some"], ["--check", "not a whole number"]),
    (["frobnicate"], ["invalid choice"]),
])
def test_user_mistakes_are_one_line_and_exit_2(capsys, tmp_path, argv, fragments):
    if argv[0] == "train":
        argv = [*argv, "--out", str(tmp_path / "run")]
    code, _, err = run_cli(capsys, *argv)
    assert_one_line_error(code, err, *fragments)
    assert not (tmp_path / "run" / "checkpoint.pt").exists()


def test_corrupt_and_foreign_files_are_refused(trained_run, tmp_path, capsys):
    truncated = tmp_path / "policy.pt"
    truncated.write_bytes((trained_run / "policy.pt").read_bytes()[:2000])
    code, _, err = run_cli(capsys, "evaluate", str(truncated))
    assert_one_line_error(code, err, "corrupt")
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a checkpoint at all")
    code, _, err = run_cli(capsys, "evaluate", str(garbage))
    assert_one_line_error(code, err)


def test_malicious_checkpoint_is_never_executed(tmp_path, capsys):
    import pickle

    marker = tmp_path / "pwned"

    class Exploit:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    path = tmp_path / "policy.pt"
    with open(path, "wb") as stream:
        pickle.dump({"format": "ilcsan-policy", "payload": Exploit()}, stream)
    code, _, err = run_cli(capsys, "evaluate", str(path))
    assert_one_line_error(code, err, "refused")
    assert not marker.exists()


def test_seed_lists():
    assert parse_seeds("0-3") == (0, 1, 2, 3)
    assert parse_seeds("2,5,7") == (2, 5, 7)
    assert parse_seeds("4") == (4,)
    for bad in ("a", "1-", "3,3", "-2"):
        with pytest.raises(UserError):
            parse_seeds(bad)


def test_listings(capsys):
    code, out, _ = run_cli(capsys, "actors")
    assert code == 0
    for preset in ("ilc-san", "popsan", "mdc-san", "akl", "dan"):
        assert preset in out
    code, out, _ = run_cli(capsys, "tasks")
    assert code == 0 and "Ant-v4" in out and "111" in out and "HumanoidStandup" in out


def test_console_script_exit_code(tmp_path):
    result = subprocess.run([sys.executable, "-m", "ilcsan.cli", "train", "--task", "Nope-v0", "--out",
                             str(tmp_path / "x")], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
