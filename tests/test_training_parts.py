"""The collaborators around the training loop, each on its own: the folder lock, per-seed checkpoint slices,
the two-phase commit, the evaluation's episode seeds, the reporters, policies rebuilt from checkpoints."""

from __future__ import annotations

import copy
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch

from ilcsan.config import RunConfig, TrainingConfig, actor_config
from ilcsan.deploy.policy import load
from ilcsan.errors import UserError
from ilcsan.rl.agent_settings import TaskSpace
from ilcsan.rl.algorithms import TD3
from ilcsan.rl.callbacks import ProgressReport, TensorBoardLog, best_so_far
from ilcsan.rl.evaluation import episode_seed, evaluate_policy, run_lockstep, training_evaluation_seed
from ilcsan.rl.rollout import TrainingEnvironments
from ilcsan.rl.training import Trainer
from ilcsan.runs.checkpoint import (
    finish_interrupted_commit,
    open_for_training,
    slice_state,
    write_together,
)
from ilcsan.runs.directory import RunDirectory


# ------------------------------------------------------------------------------------------------ lock
def test_a_locked_folder_refuses_a_second_lock_until_released(tmp_path):
    folder = RunDirectory(tmp_path)
    first = folder.lock()
    assert first.held
    with pytest.raises(UserError, match="another ilcsan process is training"):
        folder.lock()
    first.close()
    folder.lock().close()


def test_open_for_training_refuses_an_existing_run_and_finds_a_partial_checkpoint(tmp_path):
    seeds = [RunDirectory(tmp_path / "seed0"), RunDirectory(tmp_path / "seed1")]
    locks, resumable = open_for_training(seeds, resume=False, log=lambda *_: None)
    assert not resumable and all(lock.held for lock in locks)
    for lock in locks:
        lock.close()
    seeds[0].write_checkpoint({"format": "ilcsan-checkpoint", "step": 5})
    with pytest.raises(UserError, match="already holds a run"):
        open_for_training(seeds, resume=False, log=lambda *_: None)
    with pytest.raises(UserError, match="only some seeds"):
        open_for_training(seeds, resume=True, log=lambda *_: None)
    seeds[1].lock().close()  # the refusal released every lock it took


# ------------------------------------------------------------------------------ per-seed checkpoints
def _agent(seeds):
    return TD3(actor_config("ilc-san", hidden=(8, 8)), TrainingConfig(), TaskSpace(3, 2, [1.0, 1.0], [0.0, 0.0]), seeds)


def _train_once(agent):
    rng = np.random.default_rng(0)
    k = len(agent.seeds)
    arrays = {"obs": rng.normal(size=(k, 8, 3)), "action": rng.uniform(-1, 1, (k, 8, 2)),
              "reward": rng.normal(size=(k, 8)), "next_obs": rng.normal(size=(k, 8, 3)), "terminal": np.zeros((k, 8))}
    for _ in range(2):  # two updates: the actor and its optimizer move too (policy delay 2)
        agent.update(agent.to_batch({name: value.astype(np.float32) for name, value in arrays.items()}))


def test_a_seeds_slice_is_its_own_rows_and_its_twin_critics():
    agent = _agent((0, 1, 2))
    _train_once(agent)
    actor, critic = slice_state(agent.actor, 1, 1), slice_state(agent.critic, 1, 2)
    for name, param in agent.actor.named_parameters():
        assert torch.equal(actor[name], param.detach()[1:2])
    for name, param in agent.critic.named_parameters():
        assert torch.equal(critic[name], param.detach()[2:4])
    moments = agent.critic_adam.seed_state(2, 2)
    name = agent.critic_adam.names[0]
    assert torch.equal(moments[name]["exp_avg"], agent.critic_adam.averages[0][4:6])
    assert moments[name]["exp_avg"].abs().sum() > 0 and float(moments[name]["step"]) == 2.0


def test_seed_states_stack_back_into_an_ensemble_in_any_order():
    trained = _agent((0, 1))
    _train_once(trained)
    states = [trained.seed_state(index) for index in (1, 0)]
    swapped = _agent((1, 0))
    swapped.load_seed_states(states)
    assert swapped.updates == trained.updates
    for (name, mine), (_, theirs) in zip(swapped.critic.named_parameters(), trained.critic.named_parameters(),
                                         strict=True):
        assert torch.equal(mine[:2], theirs[2:]) and torch.equal(mine[2:], theirs[:2]), name
    other = TD3(actor_config("ilc-san", hidden=(4, 4)), TrainingConfig(), TaskSpace(3, 2, [1.0, 1.0], [0.0, 0.0]),
                (0, 1))
    with pytest.raises(UserError, match="has shape"):
        other.load_seed_states(states)


# ------------------------------------------------------------------------------ two-phase commit
def _seeds(tmp_path, count=3):
    return [RunDirectory(tmp_path / f"seed{index}") for index in range(count)]


def test_write_together_leaves_only_committed_checkpoints(tmp_path):
    seeds = _seeds(tmp_path)
    write_together(seeds, [{"format": "ilcsan-checkpoint", "step": 10} for _ in seeds], step=10, kept=None)
    assert [d.checkpoint_step() for d in seeds] == [10, 10, 10]
    assert not any(d.has_checkpoint(pending=True) for d in seeds)


def test_an_interrupted_first_phase_is_undone(tmp_path):
    seeds = _seeds(tmp_path)
    write_together(seeds, [{"format": "ilcsan-checkpoint", "step": 10} for _ in seeds], step=10, kept=None)
    for directory in seeds[:2]:  # the crash came before seed 2 had its new checkpoint
        directory.write_checkpoint({"format": "ilcsan-checkpoint", "step": 20}, pending=True)
    finish_interrupted_commit(seeds)
    assert [d.checkpoint_step() for d in seeds] == [10, 10, 10]
    assert not any(d.has_checkpoint(pending=True) for d in seeds)


def test_an_interrupted_second_phase_is_completed(tmp_path):
    seeds = _seeds(tmp_path)
    write_together(seeds, [{"format": "ilcsan-checkpoint", "step": 10} for _ in seeds], step=10, kept=None)
    seeds[0].write_checkpoint({"format": "ilcsan-checkpoint", "step": 20})  # renamed before the crash
    for directory in seeds[1:]:
        directory.write_checkpoint({"format": "ilcsan-checkpoint", "step": 20}, pending=True)
    finish_interrupted_commit(seeds)
    assert [d.checkpoint_step() for d in seeds] == [20, 20, 20]


# ------------------------------------------------------------------------------------ evaluation
def test_lockstep_episodes_are_seeded_first_seed_plus_episode():
    envs = [gym.make("Pendulum-v1") for _ in range(6)]
    seen = []
    for env in envs:
        original = env.reset

        def reset(*, seed=None, _original=original, **kwargs):
            seen.append(seed)
            return _original(seed=seed, **kwargs)

        env.reset = reset
    returns, lengths = run_lockstep([envs[:3], envs[3:]], lambda obs: np.zeros((*obs.shape[:2], 1)), [100, 200])
    assert seen == [100, 101, 102, 200, 201, 202]
    assert [len(r) for r in returns] == [3, 3] and lengths == [[200] * 3] * 2


@pytest.mark.parametrize("compile_mode", ["off", "on"])
def test_training_evaluation_runs_every_episode_together_and_equals_them_one_by_one(tmp_path, compile_mode):
    """K seeds × E episodes in lockstep, one batched actor call per step; each return equals that episode played
    alone with batch-1 actions (Hopper: chaotic, so any difference in the actions would show)."""
    from ilcsan.rl.evaluation import episode_seed
    from ilcsan.rl.tasks import make_env

    config = RunConfig(task="Hopper", seeds=(0, 1), steps=60, eval_every=10**6, eval_episodes=3,
                       actor=actor_config("ilc-san", hidden=(16, 16)),
                       training=TrainingConfig(start_steps=60, update_after=60, batch_size=16), threads=1,
                       compile=compile_mode)
    trainer = Trainer(config, tmp_path / "run", progress=False, log=lambda *_: None)
    try:
        for _ in range(config.steps):
            trainer.train_step()
        calls = []
        act = trainer.agent.act
        trainer.agent.act = lambda states: calls.append(states.shape) or act(states)
        rows = trainer.evaluate()
        trainer.agent.act = act
        assert set(calls) == {(2, 3, 11)}
        longest = 0
        for k, seed in enumerate(config.seeds):
            alone = []
            for episode in range(3):
                env = make_env("Hopper")
                observation = env.reset(seed=episode_seed(training_evaluation_seed(seed, 0), episode))[0]
                total, done, length = 0.0, False, 0
                while not done:
                    action = trainer._act(np.repeat(observation[None], 2, axis=0))[k]
                    observation, reward, terminated, truncated, _ = env.step(action)
                    total, done, length = total + reward, terminated or truncated, length + 1
                env.close()
                alone.append((total, length))
            assert rows[k]["eval_return_mean"] == pytest.approx(np.mean([r for r, _ in alone]), rel=1e-9)
            assert rows[k]["eval_length_mean"] == pytest.approx(np.mean([n for _, n in alone]))
            longest = max(longest, *(n for _, n in alone))
        assert len(calls) == longest  # one actor call per step for all seeds and episodes
    finally:
        trainer.close()


def test_evaluate_with_the_training_seed_replays_the_training_evaluation(trained_run):
    policy = load(trained_run)
    evaluation = policy.info["step"] // 150  # the trained_run fixture evaluates every 150 steps
    returns, _ = evaluate_policy(policy, episodes=1, seed=training_evaluation_seed(0, evaluation))
    assert returns[0] == pytest.approx(policy.info["eval_return_mean"], rel=1e-4)


def test_evaluate_steps_all_episodes_with_one_predict_call_and_equals_them_played_alone(trained_run):
    policy = load(trained_run)
    calls = []
    predict = policy.predict
    policy.predict = lambda observations: calls.append(observations.shape) or predict(observations)
    returns, lengths = evaluate_policy(policy, episodes=3, seed=40)
    policy.predict = predict
    assert set(calls) == {(3, 3)} and len(calls) == max(lengths)  # (episodes, N) per step, one call
    for episode in range(3):
        alone, length = evaluate_policy(policy, episodes=1, seed=episode_seed(40, episode))
        assert returns[episode] == pytest.approx(alone[0], rel=1e-5) and lengths[episode] == length[0]


# ------------------------------------------------------------------------------------- reporters
class _Run:
    def __init__(self, step, evaluations):
        self.step, self.evaluations = step, evaluations
        self.config = RunConfig(task="Pendulum-v1", seeds=(0, 1), label="mine")
        self.agent = type("Agent", (), {"execution": "compiled update + acting"})()


def test_the_evaluation_line_names_the_run_returns_and_best(capsys):
    lines = []
    report = ProgressReport(progress=False, log=lines.append)
    rows = [{"eval_return_mean": -10.0}, {"eval_return_mean": -30.0}]
    run = _Run(400, [[{"eval_return_mean": -50.0}, rows[0]], [{"eval_return_mean": -20.0}, rows[1]]])
    report.start(run)
    report.step(run)
    report.evaluated(run, rows, 123.4, {})
    report.close()
    assert lines == ["[Pendulum-v1 mine] step 400: eval return -10.0 -30.0 · best -15.0 · 123 steps/s "
                     "(compiled update + acting)"]
    assert best_so_far([[], []]) == "no evaluation yet"


def test_tensorboard_writes_each_seeds_scalars_in_its_folder(tmp_path):
    log = TensorBoardLog([tmp_path / "a", tmp_path / "b"], first_step=0)
    rows = [{"eval_return_mean": 1.0, "eval_return_std": 0.0}, {"eval_return_mean": 2.0, "eval_return_std": 0.0}]
    log.evaluated(_Run(10, []), rows, 50.0, {"critic_loss": 0.5})
    log.close()
    assert list((tmp_path / "a").iterdir()) and list((tmp_path / "b").iterdir())


# ------------------------------------------------------------------------- environments and folders
def test_training_environments_snapshot_and_restore_a_running_episode():
    first, second = TrainingEnvironments("Pendulum-v1", (3,)), TrainingEnvironments("Pendulum-v1", (3,))
    first.start()
    for step in range(1, 6):
        first.step(np.full((1, 1), 0.5), step)
    assert second.restore(0, copy.deepcopy(first.snapshot(0)), step=5)
    assert np.array_equal(second.observations, first.observations)
    transition_a, _ = first.step(np.full((1, 1), -1.0), 6)
    transition_b, _ = second.step(np.full((1, 1), -1.0), 6)
    assert np.array_equal(transition_a.next_obs, transition_b.next_obs)
    assert second.episode_returns[0] == pytest.approx(first.episode_returns[0])
    first.close()
    second.close()


class _Unbuildable(gym.Env):
    def __init__(self):
        raise RuntimeError("this task needs a library that is not installed")


if "ilcsan-test/Unbuildable-v0" not in gym.registry:
    gym.register("ilcsan-test/Unbuildable-v0", entry_point=_Unbuildable)


def test_a_task_that_cannot_be_built_writes_nothing(tmp_path):
    config = RunConfig(task="ilcsan-test/Unbuildable-v0", seeds=(0, 1), steps=10, threads=1)
    with pytest.raises((UserError, RuntimeError)):
        Trainer(config, tmp_path / "run", progress=False, log=lambda *_: None)
    assert not (tmp_path / "run").exists()


# --------------------------------------------------------------------------- policies from checkpoints
def test_a_checkpoint_rebuilds_its_policy_without_an_environment(trained_run, tmp_path, monkeypatch):
    import ilcsan.rl.tasks

    checkpoint = trained_run / "checkpoint.pt"
    state = torch.load(checkpoint, weights_only=True)
    assert state["action_scale"].shape == (1,)

    def refuse(*_args, **_kwargs):
        raise AssertionError("an environment was built to load a checkpoint")

    with monkeypatch.context() as patched:
        patched.setattr(ilcsan.rl.tasks, "make_env", refuse)
        action = load(checkpoint).predict(np.zeros(3))
    for key in ("action_scale", "action_offset"):  # a checkpoint of an earlier version: the task gives the bounds
        state.pop(key)
    torch.save(state, tmp_path / "checkpoint.pt")
    old = load(tmp_path / "checkpoint.pt")
    assert np.array_equal(old.action_scale, [2.0]) and np.array_equal(old.predict(np.zeros(3)), action)


def test_a_training_process_flushes_denormal_floats_to_zero_and_gives_the_setting_back(tmp_path):
    from ilcsan.compute.process import denormals_flushed, flush_denormals

    flush_denormals(False)
    denormal = torch.full((1000,), 1e-39)  # below float32's smallest normal, 1.18e-38
    assert not denormals_flushed() and (denormal * 0.5).min() > 0  # kept: a gradual underflow
    config = RunConfig(task="Pendulum-v1", seeds=(0,), steps=300, eval_episodes=1, threads=1,
                       actor=actor_config("ilc-san", hidden=(16, 16)))
    trainer = Trainer(config, tmp_path / "run", progress=False, log=lambda *_: None)
    try:
        assert denormals_flushed()
        assert (denormal * 0.5).max() == 0 and (denormal + 1e-39).max() == 0  # flushed, and read as zero
        assert (torch.full((3,), 2e-38) * 0.75).min() == pytest.approx(1.5e-38)  # normal numbers are untouched
    finally:
        trainer.close()
    assert not denormals_flushed() and (denormal * 0.5).min() > 0  # this process's setting is given back


def test_threads_started_after_the_flush_flush_denormals_too():
    code = ("import torch\n"
            "from ilcsan.compute.process import flush_denormals\n"
            "assert flush_denormals()\n"
            "torch.set_num_threads(2)\n"
            "x = torch.full((400_000,), 1e-39)\n"
            "y = x * 0.5  # split over two threads: each half must be exactly zero\n"
            "bits = y.view(torch.int32)\n"
            "print(int((bits[:200_000] != 0).sum()), int((bits[200_000:] != 0).sum()))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["0", "0"]
