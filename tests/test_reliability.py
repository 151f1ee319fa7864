"""Reliability and security: untrusted files are data, numerical faults stop a run cleanly, bad output
folders are reported before training, servers stay local.

Every check goes through the command line in this process (`ilcsan.cli.main`) where the user would meet
the failure, and asserts the whole contract: the exit code, exactly one line on stderr without a
traceback, the words that say what happened, and what is (or is not) left on disk.
"""

from __future__ import annotations

import csv
import errno
import os
import pathlib
import pickle
import shutil
import time

import gymnasium as gym
import numpy as np
import pytest
import torch

from ilcsan.cli import main
from ilcsan.config import RunConfig
from ilcsan.errors import UserError
from ilcsan.files import safe_torch_load
from ilcsan.rl.training import Trainer, load_run_config

# the settings of the `trained_run` fixture (conftest.py), as command-line options
RUN_OPTIONS = ["--task", "Pendulum-v1", "--steps", "300", "--eval-every", "150", "--eval-episodes", "1",
               "--start-steps", "150", "--update-after", "100", "--update-every", "25", "--batch-size", "16",
               "--hidden-width", "16", "--threads", "1", "--no-progress"]


def cli(capsys, *argv: str) -> tuple[int, str, str]:
    code = main([str(arg) for arg in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def assert_user_error(code: int, err: str, *fragments: str) -> str:
    line = one_line(err)
    assert code == 2, (code, err)
    assert line.startswith("ilcsan: error: "), line
    for fragment in fragments:
        assert fragment in line, (fragment, line)
    return line


def eval_curve(directory: pathlib.Path) -> list[str]:
    with open(directory / "metrics.csv", newline="") as stream:
        return [row["eval_return_mean"] for row in csv.DictReader(stream)]


@pytest.fixture
def run_copy(trained_run, tmp_path):
    """A private copy of the tiny trained run, to damage."""
    target = tmp_path / "run"
    shutil.copytree(trained_run, target)
    return target


def resume(capsys, directory, *extra: str):
    options = list(RUN_OPTIONS)
    for flag, value in zip(extra[::2], extra[1::2], strict=True):
        if flag in options:
            options[options.index(flag) + 1] = value
        else:
            options += [flag, value]
    return cli(capsys, "train", *options, "--out", directory, "--resume")


def edit_checkpoint(directory: pathlib.Path, change) -> None:
    state = torch.load(directory / "checkpoint.pt", weights_only=True)
    change(state)
    torch.save(state, directory / "checkpoint.pt")


# ------------------------------------------------------------------------------------------------
# Untrusted files are data, never code


class Exploit:
    """Unpickling this would create the marker file: the proof that code ran."""

    def __init__(self, marker: pathlib.Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


@pytest.mark.parametrize("container", ["torch.save", "plain pickle"])
def test_malicious_checkpoint_on_resume_is_refused_and_never_run(run_copy, tmp_path, capsys, container):
    marker = tmp_path / "pwned"
    payload = {"format": "ilcsan-checkpoint", "version": 1, "step": 150, "config": Exploit(marker)}
    if container == "torch.save":
        torch.save(payload, run_copy / "checkpoint.pt")
    else:
        with open(run_copy / "checkpoint.pt", "wb") as stream:
            pickle.dump(payload, stream)
    code, _, err = resume(capsys, run_copy)
    line = assert_user_error(code, err, "checkpoint.pt", "refused", "never executed")
    assert "weights_only" not in line and "Re-running" not in line, "never advise loading the file unsafely"
    assert not marker.exists(), "the payload ran"


@pytest.mark.parametrize("options, fragment", [
    (("--actor", "popsan"), "different settings (actor)"),
    (("--task", "MountainCarContinuous-v0"), "different settings (task"),
    (("--hidden-width", "32"), "different settings (actor)"),
    (("--steps", "150"), "checkpoint is at step 300, past --steps 150"),
])
def test_checkpoint_of_another_actor_task_or_run_is_refused(run_copy, capsys, options, fragment):
    before = (run_copy / "checkpoint.pt").read_bytes()
    code, _, err = resume(capsys, run_copy, *options)
    assert_user_error(code, err, fragment)
    assert (run_copy / "checkpoint.pt").read_bytes() == before, "a refused resume must not touch the run"


def test_checkpoint_with_weights_of_another_shape_is_refused(run_copy, capsys):
    def shrink(state):
        state["actor"]["layers.0.weight"] = state["actor"]["layers.0.weight"][:, :8]

    edit_checkpoint(run_copy, shrink)
    code, _, err = resume(capsys, run_copy)
    assert_user_error(code, err, "layers.0.weight", "shape")
    code, _, err = cli(capsys, "evaluate", run_copy / "checkpoint.pt", "--episodes", "1")
    assert_user_error(code, err, "layers.0.weight", "shape")


def test_checkpoint_with_optimizer_state_of_another_shape_is_refused(run_copy, capsys):
    def shrink(state):
        entry = state["critic_optimizer"]["mlp.layers.0.weight"]
        entry["exp_avg"] = entry["exp_avg"][..., :3]

    edit_checkpoint(run_copy, shrink)
    code, _, err = resume(capsys, run_copy)
    assert_user_error(code, err, "optimizer state", "shape")


@pytest.mark.parametrize("key", ["config", "actor", "critic_optimizer", "normalizer", "replay", "rng", "env",
                                 "evaluations", "updates"])
def test_checkpoint_with_a_missing_part_is_one_line(run_copy, capsys, key):
    edit_checkpoint(run_copy, lambda state: state.pop(key))
    code, _, err = resume(capsys, run_copy)
    assert_user_error(code, err, "checkpoint")


@pytest.mark.parametrize("keep", [0, 100, 5000, -10])
def test_truncated_checkpoint_is_one_line(run_copy, capsys, keep):
    data = (run_copy / "checkpoint.pt").read_bytes()
    (run_copy / "checkpoint.pt").write_bytes(data[:keep])
    code, _, err = resume(capsys, run_copy)
    assert_user_error(code, err, "corrupt or truncated")


def test_missing_replay_segment_is_one_line(run_copy, capsys):
    next(iter((run_copy / "replay").glob("*.npz"))).unlink()
    code, _, err = resume(capsys, run_copy)
    assert_user_error(code, err, "replay segment", "missing or corrupt")


def test_policy_file_cannot_make_us_allocate_a_huge_network(run_copy, capsys):
    state = torch.load(run_copy / "policy.pt", weights_only=True)
    state["actor_config"]["hidden"] = [200_000, 200_000]  # 40 G parameters if built; the tensors stay tiny
    torch.save(state, run_copy / "policy.pt")
    start = time.perf_counter()
    code, _, err = cli(capsys, "evaluate", run_copy / "policy.pt")
    assert_user_error(code, err, "shape")
    assert time.perf_counter() - start < 10


@pytest.mark.parametrize("damage, fragment", [
    (lambda s: s["actor"].__setitem__("decoder.bias", torch.full_like(s["actor"]["decoder.bias"], float("nan"))),
     "NaN"),
    (lambda s: s.__setitem__("obs_std", torch.zeros_like(s["obs_std"])), "normaliser"),
    (lambda s: s.__setitem__("obs_mean", torch.zeros(7, dtype=torch.float64)), "inconsistent"),
    (lambda s: s.__setitem__("actor_config", {"hidden": "wide"}), "incomplete or corrupt"),
    (lambda s: s.__setitem__("actor_config", {"colour": "red"}), "unknown actor setting"),
    (lambda s: s.pop("actor"), "incomplete or corrupt"),
])
def test_damaged_policy_file_is_one_line(run_copy, capsys, damage, fragment):
    state = torch.load(run_copy / "policy.pt", weights_only=True)
    damage(state)
    torch.save(state, run_copy / "policy.pt")
    code, _, err = cli(capsys, "evaluate", run_copy / "policy.pt", "--episodes", "1")
    assert_user_error(code, err, fragment)


@pytest.fixture
def bundle(trained_run, tmp_path):
    path = tmp_path / "actor.npz"
    from ilcsan.deploy.export import export

    export(trained_run, "npz", path)
    with np.load(path, allow_pickle=False) as data:
        return path, {name: data[name] for name in data.files}


@pytest.mark.parametrize("damage, fragment", [
    (lambda a: a.pop("layers.1.weight"), "layers"),
    (lambda a: a.pop("decoder.weight"), "no array 'decoder.weight'"),
    (lambda a: a.pop("meta"), "no 'meta'"),
    (lambda a: a.__setitem__("layers.0.weight", a["layers.0.weight"][:, :5]), "has shape"),
    (lambda a: a.__setitem__("intra.weight", a["intra.weight"].reshape(-1)), "has shape"),
    (lambda a: a.__setitem__("decoder.bias", a["decoder.bias"].astype(np.complex64)), "dtype"),
    (lambda a: a.__setitem__("meta", np.array("{not json")), "JSON"),
    (lambda a: a.__setitem__("meta", np.array('{"T": 5}')), "lacks"),
])
def test_damaged_deploy_bundle_is_one_line(bundle, tmp_path, damage, fragment):
    from ilcsan.deploy import DeployedActor

    _, arrays = bundle
    damage(arrays)
    damaged = tmp_path / "damaged.npz"
    np.savez(damaged, **arrays)
    with pytest.raises(UserError, match=fragment) as caught:
        DeployedActor.load(damaged)
    assert "\n" not in str(caught.value)


def test_deploy_bundle_with_pickled_objects_is_refused(bundle, tmp_path):
    from ilcsan.deploy import DeployedActor

    _, arrays = bundle
    marker = tmp_path / "pwned"
    arrays["layers.0.weight"] = np.array([Exploit(marker)], dtype=object)
    damaged = tmp_path / "evil.npz"
    np.savez(damaged, **arrays)
    with pytest.raises(UserError):
        DeployedActor.load(damaged).act(np.zeros(3))
    assert not marker.exists()


# ------------------------------------------------------------------------------------------------
# Numerical faults: the run stops at once, names the step and the cause, keeps its last checkpoint

FAULT_OPTIONS = ["--steps", "300", "--eval-every", "150", "--eval-episodes", "1", "--start-steps", "100",
                 "--update-after", "100", "--update-every", "25", "--batch-size", "16", "--hidden-width", "16",
                 "--threads", "1", "--no-progress"]


class FaultyPendulum(gym.Wrapper):
    """Pendulum whose ``fault_step``-th step (counted per environment, from 1) returns a bad value.

    ``instance`` picks which environment the trainer makes is faulty: 0 the training environment (made
    first), 1 the evaluation environment; ``reward_from`` makes every reward from that step on ``value``."""

    made = 0

    def __init__(self, what: str = "obs", value: float = float("nan"), fault_step: int = 160, instance: int = 0,
                 reward_from: int | None = None):
        super().__init__(gym.make("Pendulum-v1"))
        self.what, self.value, self.fault_step, self.reward_from = what, value, fault_step, reward_from
        self.faulty = FaultyPendulum.made == instance
        FaultyPendulum.made += 1
        self.count = 0

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        self.count += 1
        if self.faulty and self.count == self.fault_step and self.reward_from is None:
            if self.what == "obs":
                observation = observation.copy()
                observation[1] = self.value
            else:
                reward = self.value
        if self.faulty and self.reward_from is not None and self.count >= self.reward_from:
            reward = self.value
        return observation, reward, terminated, truncated, info


FAULTY = {
    "ilcsan-test/NaNObservation-v0": dict(what="obs", value=float("nan")),
    "ilcsan-test/InfReward-v0": dict(what="reward", value=float("inf")),
    "ilcsan-test/Float32OverflowReward-v0": dict(what="reward", value=1e39),
    # the evaluation environment steps 200 times per evaluation: its step 230 is in the evaluation at step 300
    "ilcsan-test/NaNInEvaluation-v0": dict(what="obs", value=float("nan"), fault_step=230, instance=1),
    "ilcsan-test/HugeRewards-v0": dict(what="reward", value=1e30, reward_from=151),
}
for env_id, kwargs in FAULTY.items():
    if env_id not in gym.registry:
        gym.register(env_id, entry_point=FaultyPendulum, kwargs=kwargs)


@pytest.fixture(autouse=False)
def faulty():
    FaultyPendulum.made = 0
    yield


def assert_stopped_cleanly(directory: pathlib.Path, code: int, err: str, *fragments: str) -> str:
    line = one_line(err)
    assert code == 3 and line.startswith("ilcsan: stopped: "), (code, err)
    for fragment in fragments:
        assert fragment in line, (fragment, line)
    checkpoint = safe_torch_load(directory / "checkpoint.pt")
    assert checkpoint["step"] == 150, "the last good checkpoint is the evaluation before the fault"
    assert len(eval_curve(directory)) == 1
    assert not list(directory.rglob("*.tmp"))
    return line


@pytest.mark.parametrize("env_id, fragments", [
    ("ilcsan-test/NaNObservation-v0", ["step 160:", "non-finite observation", "seed 0", "last checkpoint"]),
    ("ilcsan-test/InfReward-v0", ["step 160:", "non-finite reward"]),
    ("ilcsan-test/Float32OverflowReward-v0", ["step 160:", "reward", "float32"]),
    ("ilcsan-test/NaNInEvaluation-v0", ["step 300:", "evaluation environment", "observation"]),
])
def test_non_finite_values_from_the_environment_stop_the_run(tmp_path, capsys, faulty, env_id, fragments):
    code, _, err = cli(capsys, "train", "--task", env_id, *FAULT_OPTIONS, "--out", tmp_path / "run")
    assert_stopped_cleanly(tmp_path / "run", code, err, *fragments)


def test_diverging_loss_stops_the_run(tmp_path, capsys, faulty):
    # rewards of 1e30 from step 151 on: the critic's squared error overflows float32 at the next update
    code, _, err = cli(capsys, "train", "--task", "ilcsan-test/HugeRewards-v0", *FAULT_OPTIONS,
                       "--out", tmp_path / "run")
    line = assert_stopped_cleanly(tmp_path / "run", code, err, "training loss diverged")
    assert any(f"step {step}:" in line for step in (175, 200, 225, 250, 275, 300)), line


def test_nan_loss_is_caught_at_the_update_chunk_it_appears(tmp_path, capsys, monkeypatch):
    from ilcsan.rl.algorithms import TD3

    original, calls = TD3.critic_loss, {"n": 0}

    def poisoned(self, batch, target, critic=None):
        calls["n"] += 1
        loss = original(self, batch, target, critic)
        return loss * float("nan") if calls["n"] > 75 else loss  # updates 1-75: steps 100-150; 76-100: step 175

    monkeypatch.setattr(TD3, "critic_loss", poisoned)
    code, _, err = cli(capsys, "train", "--task", "Pendulum-v1", *FAULT_OPTIONS, "--out", tmp_path / "run")
    assert_stopped_cleanly(tmp_path / "run", code, err, "step 175:", "training loss diverged", "critic nan")


# ------------------------------------------------------------------------------------------------
# Output folders that cannot take the results: reported before training starts


@pytest.fixture
def no_training(monkeypatch):
    """Fail the test if an agent is built: the folder must be checked before any training starts (the task's
    environments are built first, so that nothing is written for a task that cannot be built)."""
    def refuse(*_args, **_kwargs):
        raise AssertionError("an agent was built before the output folder was checked")

    monkeypatch.setattr("ilcsan.rl.run_setup.build_algorithm", refuse)


def test_output_below_a_file_is_reported_before_training(tmp_path, capsys, no_training):
    (tmp_path / "file").write_text("x")
    code, _, err = cli(capsys, "train", *RUN_OPTIONS, "--out", tmp_path / "file" / "run")
    assert_user_error(code, err, "cannot write results to", "Not a directory", "choose another --out")


def test_read_only_output_folder_is_reported_before_training(tmp_path, capsys, monkeypatch, no_training):
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o555)
    if os.geteuid() == 0:  # root ignores the mode bits: simulate what the kernel says to everyone else
        def refuse(self, *_args, **_kwargs):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(self))

        monkeypatch.setattr(pathlib.Path, "write_bytes", refuse)
    try:
        code, _, err = cli(capsys, "train", *RUN_OPTIONS, "--out", folder / "run")
    finally:
        folder.chmod(0o755)
    assert_user_error(code, err, "cannot write results to", "Permission denied")


def test_full_disk_is_reported_before_training(tmp_path, capsys, monkeypatch, no_training):
    # the write probe (64 KiB) fails as on a full disk
    def full(self, *_args, **_kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))

    monkeypatch.setattr(pathlib.Path, "write_bytes", full)
    code, _, err = cli(capsys, "train", *RUN_OPTIONS, "--out", tmp_path / "run")
    assert_user_error(code, err, "cannot write results to", "No space left on device")
    assert not (tmp_path / "run" / "config.json").exists()


def test_disk_full_at_a_checkpoint_keeps_the_last_one_and_resumes_exactly(trained_run, tmp_path, capsys,
                                                                         monkeypatch):
    import ilcsan.runs.directory as directory

    original, calls = directory.atomic_torch_save, {"n": 0}

    def fills_up(path, obj):
        calls["n"] += 1
        if pathlib.Path(path).name == "checkpoint.pt" and calls["n"] > 2:  # policy + checkpoint at step 150
            with open(path.parent / f".{path.name}.ilcsan-test.tmp", "wb"):
                pass  # what a real failed write leaves is removed by io's cleanup; prove resume cleans it too
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        original(path, obj)

    monkeypatch.setattr(directory, "atomic_torch_save", fills_up)
    out = tmp_path / "run"
    code, _, err = cli(capsys, "train", *RUN_OPTIONS, "--out", out)
    kept = (f"ilcsan: error: step 300: cannot write to {out}: No space left on device; the checkpoint at step 150 is "
            "kept: free some space, then continue with --resume")
    assert assert_user_error(code, err) == kept
    assert safe_torch_load(out / "checkpoint.pt")["step"] == 150
    # still full: the resumed run fails at the same write and names the checkpoint it resumed from
    code, _, err = cli(capsys, "train", *RUN_OPTIONS, "--out", out, "--resume")
    assert assert_user_error(code, err) == kept
    monkeypatch.setattr(directory, "atomic_torch_save", original)
    code, _, err = cli(capsys, "train", *RUN_OPTIONS, "--out", out, "--resume")
    assert code == 0, err
    assert eval_curve(out) == eval_curve(trained_run), "the resumed run equals the uninterrupted one"
    assert not list(out.rglob("*.tmp"))


def test_disk_full_before_the_first_checkpoint_says_none_is_kept(trained_run, tmp_path, capsys, monkeypatch):
    import ilcsan.runs.directory as directory

    original = directory.atomic_torch_save

    def full_for_checkpoints(path, obj):
        if pathlib.Path(path).name == "checkpoint.pt":  # the first one is due at the first evaluation, step 150
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        original(path, obj)

    monkeypatch.setattr(directory, "atomic_torch_save", full_for_checkpoints)
    out = tmp_path / "run"
    code, _, err = cli(capsys, "train", *RUN_OPTIONS, "--out", out)
    assert assert_user_error(code, err) == (
        f"ilcsan: error: step 150: cannot write to {out}: No space left on device; no checkpoint has been written "
        "yet: free some space, then start again with --resume (from step 0)")
    assert not (out / "checkpoint.pt").exists()
    monkeypatch.setattr(directory, "atomic_torch_save", original)
    code, _, err = cli(capsys, "train", *RUN_OPTIONS, "--out", out)  # hence "with --resume": the folder holds metrics
    assert_user_error(code, err, "already holds a run")
    code, printed, err = cli(capsys, "train", *RUN_OPTIONS, "--out", out, "--resume")
    assert code == 0, err
    assert f"no checkpoint in {out} yet; starting from step 0" in printed + err
    assert eval_curve(out) == eval_curve(trained_run), "started again from step 0, it equals an uninterrupted run"


# ------------------------------------------------------------------------------------------------
# Settings that cannot run on this machine: refused at once, nothing allocated


@pytest.mark.parametrize("option, value, fragment", [
    ("--hidden-width", "1000000000", "needs at least"),
    ("--batch-size", "1000000000", "needs at least"),  # used to be killed by the kernel's OOM killer
    ("--timesteps", "1000000000", "needs at least"),  # used to hang
    ("--population-in", "1000000000", "needs at least"),
    ("--seeds", "0-999999", "at most 1000"),  # used to build a list of a million seeds
    ("--threads", "100000", "more than 4 per core"),  # used to crash in libgomp
    ("--device", "toaster", "not a device"),
    ("--device", "meta", "not supported"),
    ("--device", "cuda:7", "cuda"),
])
def test_impossible_settings_are_refused_at_once(tmp_path, capsys, option, value, fragment):
    threads = torch.get_num_threads()
    start = time.perf_counter()
    options = list(RUN_OPTIONS)
    if option in options:
        options[options.index(option) + 1] = value
    else:
        options += [option, value]
    code, _, err = cli(capsys, "train", *options, "--out", tmp_path / "run")
    torch.set_num_threads(threads)
    assert_user_error(code, err, fragment)
    assert time.perf_counter() - start < 20
    assert not (tmp_path / "run" / "checkpoint.pt").exists()


def test_the_memory_estimate_admits_the_papers_largest_runs():
    from ilcsan.config import actor_config
    from ilcsan.rl.ram import check_memory, memory_estimate

    paper = RunConfig(task="Humanoid", seeds=(0,), steps=1_000_000)
    check_memory(paper, 376, 17)  # one seed of the paper's largest task fits
    need = memory_estimate(paper, 376, 17)
    assert 2e9 < need["replay"] < 4e9 and need["networks"] < 1e9
    check_memory(RunConfig(task="Humanoid", actor=actor_config("ilc-san", hidden_width=4096), steps=1000), 376, 17)
    huge = RunConfig(task="Humanoid", actor=actor_config("ilc-san", hidden_width=100_000), steps=1000)
    assert memory_estimate(huge, 376, 17)["networks"] > 100 * need["networks"]
    with pytest.raises(UserError, match="GiB for its networks"):
        check_memory(huge, 376, 17)


# ------------------------------------------------------------------------------------------------
# One run directory, one process


def test_a_second_process_cannot_train_into_the_same_run(tmp_path, trained_run):
    config = load_run_config(trained_run)
    shutil.copytree(trained_run, tmp_path / "run")
    first = Trainer(config, tmp_path / "run", resume=True, progress=False, log=lambda *_: None)
    try:
        with pytest.raises(UserError, match="another ilcsan process is training"):
            Trainer(config, tmp_path / "run", resume=True, progress=False, log=lambda *_: None)
    finally:
        first.close()
    second = Trainer(config, tmp_path / "run", resume=True, progress=False, log=lambda *_: None)
    second.close()


def test_stale_temporary_files_are_removed_on_resume(run_copy, capsys):
    stale = [run_copy / ".checkpoint.pt.abc123.tmp", run_copy / "replay" / ".0000000150-0000000300.npz.x.tmp"]
    for path in stale:
        path.write_bytes(b"half a file")
    code, _, err = resume(capsys, run_copy)
    assert code == 0, err
    assert not any(path.exists() for path in stale)


# ------------------------------------------------------------------------------------------------
# Servers stay local


def test_a_local_ray_binds_to_loopback_with_its_dashboard_off(monkeypatch):
    ray = pytest.importorskip("ray")
    from ilcsan.experiments import ray_cluster as experiments

    calls: list[dict] = []
    monkeypatch.setattr(ray, "init", lambda *args, **kwargs: calls.append(dict(kwargs, args=args)))
    experiments.start_local_ray(2)
    experiments.start_local_ray(2, dashboard=True)
    quiet, asked = calls
    for kwargs in calls:
        assert kwargs["address"] == "local", "never join a cluster found through RAY_ADDRESS"
        assert kwargs["_node_ip_address"] == "127.0.0.1"
        assert kwargs.get("dashboard_host", "127.0.0.1") == "127.0.0.1"
    assert quiet["include_dashboard"] is False
    assert asked["include_dashboard"] is True and asked["dashboard_host"] == "127.0.0.1"


def test_tensorboard_instructions_bind_to_loopback():
    root = pathlib.Path(__file__).resolve().parents[1]
    documents = [root / "README.md", *sorted((root / "docs").glob("*.md"))]
    mentions = [(path.name, line) for path in documents if path.is_file()
                for line in path.read_text(encoding="utf-8").splitlines() if "tensorboard --logdir" in line]
    assert mentions, "the docs explain how to watch training in TensorBoard"
    for name, line in mentions:
        assert "--host 127.0.0.1" in line, f"{name}: {line.strip()}"


def test_export_and_report_outputs_that_cannot_be_written_are_one_line(run_copy, tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    code, _, err = cli(capsys, "export", run_copy, "--out", tmp_path / "file" / "actor.npz")
    assert_user_error(code, err, "cannot write", "choose another --out")
    code, _, err = cli(capsys, "report", run_copy, "--out", tmp_path / "file")
    assert_user_error(code, err, "cannot write the report")
    # an existing folder as --out gets the default file name inside it (it used to be a traceback)
    (tmp_path / "folder").mkdir()
    code, out, err = cli(capsys, "export", run_copy, "--out", tmp_path / "folder")
    assert code == 0 and (tmp_path / "folder" / "actor.npz").is_file(), err


def test_reproduce_into_an_unwritable_folder_is_one_line(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    grid = tmp_path / "grid.toml"
    grid.write_text('name = "tiny"\ntasks = ["Pendulum-v1"]\nseeds = 1\nsteps = 300\n'
                    '[[rows]]\nslug = "ilc"\npreset = "ilc-san"\noverrides = { hidden_width = 16 }\n')
    code, _, err = cli(capsys, "reproduce", grid, "--out", tmp_path / "file" / "out", "--workers", "1")
    assert_user_error(code, err, "cannot write results to", "Not a directory")
