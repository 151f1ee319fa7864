"""TD3 training: K seeds in one process equal single runs, checkpoints resume exactly, results on disk."""

from __future__ import annotations

import csv
import dataclasses
import json

import numpy as np
import pytest
import torch

from ilcsan.compute.matmul import MatmulPath, onednn_available
from ilcsan.config import RunConfig, TrainingConfig, actor_config
from ilcsan.errors import UserError
from ilcsan.rl import training
from ilcsan.rl.agent_settings import ComputeSettings, TaskSpace
from ilcsan.rl.algorithms import TD3
from ilcsan.rl.training import Trainer, train
from ilcsan.runs.directory import RunDirectory

TINY_TRAINING_VALUES = {"start_steps": 150, "update_after": 100, "update_every": 25, "batch_size": 16}
TINY_TRAINING = TrainingConfig(**TINY_TRAINING_VALUES)


def tiny_training(**options):
    """:data:`TINY_TRAINING` as the training settings of the methods registered now (a test's own method included:
    TINY_TRAINING's class is the one of the methods registered when this module was imported)."""
    from ilcsan.config import training_config_class

    return training_config_class()(**{**TINY_TRAINING_VALUES, **options})


def tiny_run(**overrides) -> RunConfig:
    values = dict(task="Pendulum-v1", seeds=(0,), steps=300, eval_every=150, eval_episodes=1,
                  actor=actor_config("ilc-san", hidden=(16, 16)), training=TINY_TRAINING, threads=1)
    values.update(overrides)
    return RunConfig(**values)


def read_metrics(path):
    with open(path) as stream:
        return list(csv.DictReader(stream))


def test_critic_target_uses_min_of_twins_and_ignores_truncation():
    agent = TD3(actor_config("dan", hidden=(8,)), TrainingConfig(target_noise=0.0), TaskSpace(3, 1, [2.0], [0.0]), (0,))
    batch = {"obs": torch.zeros(1, 4, 3), "action": torch.zeros(1, 4, 1), "reward": torch.ones(1, 4),
             "next_obs": torch.ones(1, 4, 3), "terminal": torch.tensor([[0.0, 1.0, 0.0, 1.0]])}
    with torch.no_grad():
        next_action = agent.actor_target(batch["next_obs"])
        q_next = agent.critic_target(batch["next_obs"], next_action).min(dim=1).values
        expected_target = 1.0 + 0.99 * (1 - batch["terminal"]) * q_next
        q = agent.critic(batch["obs"], batch["action"])
    expected = ((q - expected_target.unsqueeze(1)) ** 2).mean(-1).sum()
    with torch.no_grad():
        target = agent.target_values({**batch, "smoothing_noise": torch.zeros(1, 4, 1)})
    assert torch.allclose(agent.critic_loss(batch, target), expected)


def test_each_seed_of_an_ensemble_updates_like_a_single_run():
    config = actor_config("ilc-san", hidden=(16, 16))
    many = TD3(config, TrainingConfig(), TaskSpace(3, 2, [1.0, 1.0], [0.0, 0.0]), (4, 11))
    single = TD3(config, TrainingConfig(), TaskSpace(3, 2, [1.0, 1.0], [0.0, 0.0]), (11,))
    rng = np.random.default_rng(0)
    for _ in range(4):
        arrays = {"obs": rng.normal(size=(2, 32, 3)), "action": rng.uniform(-1, 1, (2, 32, 2)),
                  "reward": rng.normal(size=(2, 32)), "next_obs": rng.normal(size=(2, 32, 3)),
                  "terminal": (rng.uniform(size=(2, 32)) < 0.1)}
        arrays = {k: v.astype(np.float32) for k, v in arrays.items()}
        many.update(many.to_batch(arrays))
        single.update(single.to_batch({k: v[1:] for k, v in arrays.items()}))
    for module in ("actor", "critic"):
        factor = 2 if module == "critic" else 1
        for (name, p_many), (_, p_single) in zip(getattr(many, module).named_parameters(),
                                                 getattr(single, module).named_parameters(), strict=True):
            assert torch.allclose(p_many[factor:], p_single, atol=1e-5), f"{module}.{name}"
    assert many.updates == 4


def _random_batch(rng, seeds, batch, state_dim, action_dim):
    arrays = {"obs": rng.normal(size=(seeds, batch, state_dim)),
              "action": rng.uniform(-1, 1, (seeds, batch, action_dim)),
              "reward": rng.normal(size=(seeds, batch)), "next_obs": rng.normal(size=(seeds, batch, state_dim)),
              "terminal": (rng.uniform(size=(seeds, batch)) < 0.1)}
    return {k: v.astype(np.float32) for k, v in arrays.items()}


def test_first_critic_equals_the_first_twin_of_every_seed():
    from ilcsan.rl.algorithms import Critics

    critic = Critics(3, 2, [8, 8], seeds=(0, 1, 2))
    generator = torch.Generator().manual_seed(0)
    state, action = torch.randn(3, 5, 3, generator=generator), torch.randn(3, 5, 2, generator=generator)
    both = critic(state, action)
    assert not torch.allclose(both[:, 0], both[:, 1])
    torch.testing.assert_close(critic.first(state, action), both[:, 0])


@pytest.fixture
def _restore_process_settings():
    before, threads = torch.get_float32_matmul_precision(), torch.get_num_threads()
    yield
    torch.set_float32_matmul_precision(before)
    torch.set_num_threads(threads)


@pytest.mark.parametrize(("preset", "path"), [("ilc-san", "aten"), ("dan", "aten"), ("ilc-san", "onednn")])
def test_compiled_update_program_equals_the_eager_update(preset, path):
    """The one definition of the update (:mod:`ilcsan.rl.algorithms.td3`) compiled as one program per variant
    (fullgraph=True: any graph break fails) leaves the same actor, critic, targets and Adam states as the same
    functions run uncompiled, over 12 updates (6 delayed), for 2 stacked seeds, on each float32 matmul path (eager,
    the paths agree: tests/test_matmul.py). (With Proxy Target: tests/test_proxy_target.py; NoisySAN:
    tests/test_noisy_exploration.py.)"""
    if path == "onednn" and not onednn_available():
        pytest.skip("this torch has no oneDNN")
    small = {"ilc-san": dict(hidden=(16,), population_in=4, population_out=4, timesteps=3), "dan": dict(hidden=(8,))}
    config = actor_config(preset, **small[preset])
    training = TrainingConfig(critic_hidden=(16, 16))
    task = TaskSpace(3, 2, [1.0, 2.0], [0.0, 0.5])
    eager = TD3(config, training, task, (7, 8), ComputeSettings(matmul_path=MatmulPath(path)))
    compiled = TD3(config, training, task, (7, 8), ComputeSettings(compile=True, matmul_path=MatmulPath(path)))
    assert eager.critic_step.__func__ is TD3._critic_step  # the same function, uncompiled
    rng = np.random.default_rng(1)
    batches = [_random_batch(rng, 2, 16, 3, 2) for _ in range(12)]
    assert_same_updates(eager, compiled, batches, atol=2e-5)
    assert compiled.critic_step.direct and compiled.delayed_step.direct
    for adam in ("actor_adam", "critic_adam"):
        for before, after in zip(*(getattr(agent, adam).tensors() for agent in (eager, compiled)), strict=True):
            for ours, theirs in zip(before, after, strict=True):
                torch.testing.assert_close(ours, theirs, atol=1e-6, rtol=1e-4)
    state = rng.normal(size=(2, 3)).astype(np.float32)
    assert np.allclose(eager.act(state), compiled.act(state), atol=1e-5)


def layer_paths(agent) -> set[str]:
    """The matmul kinds of every synaptic layer of an agent's networks."""
    return {module.matmul_path.kind for network in (agent.actor, agent.critic, agent.actor_target, agent.critic_target)
            for module in network.modules() if hasattr(module, "matmul_path")}


def test_matmul_option_gives_the_run_its_path_and_close_gives_the_process_its_settings_back(
        tmp_path, _restore_process_settings):
    torch.set_float32_matmul_precision("medium")
    torch.set_num_threads(2)
    trainer = Trainer(tiny_run(matmul="bf16", steps=10), tmp_path / "bf16", progress=False, log=lambda *_: None)
    # on a CPU the bf16 path rounds the products it chose itself; torch's precision keeps every other one float32
    assert layer_paths(trainer.agent) == {"bf16"} and torch.get_float32_matmul_precision() == "highest"
    assert torch.get_num_threads() == 1  # tiny_run's --threads
    trainer.close()
    assert torch.get_float32_matmul_precision() == "medium" and torch.get_num_threads() == 2
    trainer = Trainer(tiny_run(steps=10), tmp_path / "f32", progress=False, log=lambda *_: None)
    assert layer_paths(trainer.agent) <= {"aten", "onednn"} and torch.get_float32_matmul_precision() == "highest"
    trainer.close()
    with pytest.raises(UserError, match="--matmul 'fp8' is not one of: float32, aten, onednn, bf16"):
        Trainer(tiny_run(matmul="fp8"), tmp_path / "bad", progress=False, log=lambda *_: None)


def test_multi_seed_run_equals_single_runs(tmp_path):
    together = train(tiny_run(seeds=(0, 1)), tmp_path / "together", progress=False, log=lambda *_: None)
    train(tiny_run(seeds=(1,)), tmp_path / "alone", progress=False, log=lambda *_: None)
    assert [r["directory"] for r in together] == [str(tmp_path / "together" / f"seed{s}") for s in (0, 1)]
    rows_together = read_metrics(tmp_path / "together" / "seed1" / "metrics.csv")
    rows_alone = read_metrics(tmp_path / "alone" / "metrics.csv")
    assert len(rows_together) == len(rows_alone) == 2
    for a, b in zip(rows_together, rows_alone, strict=True):
        assert float(a["eval_return_mean"]) == pytest.approx(float(b["eval_return_mean"]), rel=1e-4)
    rows_seed0 = read_metrics(tmp_path / "together" / "seed0" / "metrics.csv")
    assert rows_seed0[0]["eval_return_mean"] != rows_together[0]["eval_return_mean"]


def interrupt_after_first_checkpoint(config, out, monkeypatch) -> None:
    """Train ``config`` into ``out`` and stop it (as Ctrl-C would) right after its first checkpoint."""
    original, calls = Trainer._write_checkpoints, {"n": 0}

    def crash_after_first_checkpoint(self):
        original(self)
        calls["n"] += 1
        if calls["n"] == 1:
            raise KeyboardInterrupt

    monkeypatch.setattr(Trainer, "_write_checkpoints", crash_after_first_checkpoint)
    with pytest.raises(KeyboardInterrupt):
        train(config, out, progress=False, log=lambda *_: None)
    monkeypatch.setattr(Trainer, "_write_checkpoints", original)


def on_the_path_of(config: RunConfig, directory) -> RunConfig:
    """``config`` with the matmul path the run in ``directory`` recorded (``--matmul aten`` or ``onednn``): runs of a
    seed compute alike only on one path, and each measures at its start which is faster (on a noisy machine, not
    always the same one)."""
    return dataclasses.replace(config, matmul=RunDirectory(directory).matmul_choice()["path"])


def tiny_method_run(**training_options) -> RunConfig:
    """Two stacked seeds on Pendulum, 450 steps, an evaluation every 150: for checking that a training method
    (``training_options``, e.g. ``target_actor="proxy"``) resumes exactly."""
    training = dataclasses.replace(TINY_TRAINING, **training_options)
    return tiny_run(seeds=(0, 1), steps=450, training=training)


def assert_resumes_to_the_same_curve(config, tmp_path, monkeypatch, edit=None) -> list[tuple[dict, dict]]:
    """Train ``config`` straight and interrupted-then-resumed: every seed's evaluations must be equal. ``edit``, if
    given, rewrites each seed's checkpoint dictionary before the resume (an older checkpoint's layout). Returns each
    seed's final checkpoints (straight, resumed) for the caller's own checks."""
    interrupt_after_first_checkpoint(config, tmp_path / "interrupted", monkeypatch)
    straight_config = on_the_path_of(config, tmp_path / "interrupted" / f"seed{config.seeds[0]}")
    train(straight_config, tmp_path / "straight", progress=False, log=lambda *_: None)
    for seed in config.seeds if edit else ():
        path = tmp_path / "interrupted" / f"seed{seed}" / "checkpoint.pt"
        torch.save(edit(torch.load(path, weights_only=True)), path)
    train(config, tmp_path / "interrupted", resume=True, progress=False, log=lambda *_: None)
    checkpoints = []
    for seed in config.seeds:
        straight = read_metrics(tmp_path / "straight" / f"seed{seed}" / "metrics.csv")
        resumed = read_metrics(tmp_path / "interrupted" / f"seed{seed}" / "metrics.csv")
        assert len(straight) == config.steps // config.eval_every
        assert [r["eval_return_mean"] for r in resumed] == [r["eval_return_mean"] for r in straight]
        checkpoints.append(tuple(torch.load(tmp_path / run / f"seed{seed}" / "checkpoint.pt", weights_only=True)
                                 for run in ("straight", "interrupted")))
    return checkpoints


def assert_same_updates(eager, compiled, batches, atol: float) -> None:
    """Give two agents the same minibatches; their actor, critic and target actor must stay equal."""
    for arrays in batches:
        losses = eager.update(eager.to_batch(arrays)), compiled.update(compiled.to_batch(arrays))
        for key in ("critic_loss", "actor_loss"):
            assert (losses[0][key] is None) == (losses[1][key] is None)
            if losses[0][key] is not None:
                assert float(losses[0][key]) == pytest.approx(float(losses[1][key]), rel=1e-4, abs=1e-5), key
    for module in ("actor", "critic", "actor_target", "critic_target"):
        for (name, p_eager), (_, p_compiled) in zip(getattr(eager, module).named_parameters(),
                                                    getattr(compiled, module).named_parameters(), strict=True):
            assert torch.allclose(p_eager, p_compiled, atol=atol), f"{module}.{name}"


def test_a_run_that_cannot_start_leaves_the_process_settings_as_they_were(tmp_path, _restore_process_settings):
    train(tiny_run(steps=10, eval_every=10), tmp_path / "run", progress=False, log=lambda *_: None)
    torch.set_num_threads(2)
    torch.set_float32_matmul_precision("high")
    with pytest.raises(UserError, match="--resume"):  # the folder holds a run: refused after the settings applied
        Trainer(tiny_run(steps=10, eval_every=10, matmul="bf16"), tmp_path / "run", progress=False,
                log=lambda *_: None)
    assert (torch.get_num_threads(), torch.get_float32_matmul_precision()) == (2, "high")


def test_interrupted_run_resumes_to_the_same_curve(tmp_path, monkeypatch):
    config = tiny_run(steps=450)
    interrupt_after_first_checkpoint(config, tmp_path / "interrupted", monkeypatch)
    train(on_the_path_of(config, tmp_path / "interrupted"), tmp_path / "straight", progress=False, log=lambda *_: None)
    assert len(read_metrics(tmp_path / "interrupted" / "metrics.csv")) == 1
    with pytest.raises(UserError, match="--resume"):
        train(config, tmp_path / "interrupted", progress=False, log=lambda *_: None)
    train(config, tmp_path / "interrupted", resume=True, progress=False, log=lambda *_: None)
    straight = read_metrics(tmp_path / "straight" / "metrics.csv")
    resumed = read_metrics(tmp_path / "interrupted" / "metrics.csv")
    assert [r["eval_return_mean"] for r in resumed] == [r["eval_return_mean"] for r in straight]
    result = json.loads((tmp_path / "interrupted" / "result.json").read_text())
    assert result["finished"] and result["steps_done"] == 450


def test_a_timed_checkpoint_between_evaluations_resumes_to_the_same_curve(tmp_path, monkeypatch):
    config = tiny_run(steps=450)  # evaluations at 150, 300, 450
    written, original = [], Trainer._write_checkpoints

    def crash_after_the_timed_checkpoint(self):
        original(self)
        written.append(self.step)
        if self.step == 220:
            raise KeyboardInterrupt

    monkeypatch.setattr(Trainer, "_checkpoint_due", lambda self: self.step == 220)  # as if the minutes had passed
    monkeypatch.setattr(Trainer, "_write_checkpoints", crash_after_the_timed_checkpoint)
    with pytest.raises(KeyboardInterrupt):
        train(config, tmp_path / "interrupted", progress=False, log=lambda *_: None)
    monkeypatch.undo()
    assert written == [150, 220]
    assert torch.load(tmp_path / "interrupted" / "checkpoint.pt", weights_only=False)["step"] == 220
    assert len(read_metrics(tmp_path / "interrupted" / "metrics.csv")) == 1
    train(config, tmp_path / "interrupted", resume=True, progress=False, log=lambda *_: None)
    train(on_the_path_of(config, tmp_path / "interrupted"), tmp_path / "straight", progress=False, log=lambda *_: None)
    straight = read_metrics(tmp_path / "straight" / "metrics.csv")
    resumed = read_metrics(tmp_path / "interrupted" / "metrics.csv")
    assert [r["eval_return_mean"] for r in resumed] == [r["eval_return_mean"] for r in straight]


def test_checkpoints_are_due_after_the_minutes_given(tmp_path, monkeypatch):
    trainer = Trainer(tiny_run(checkpoint_minutes=2.0), tmp_path / "run", progress=False, log=lambda *_: None)
    try:
        now = [1000.0]
        monkeypatch.setattr(training.time, "perf_counter", lambda: now[0])
        trainer._clock = training.TrainingClock(0)
        now[0] += 119.0
        assert not trainer._checkpoint_due()
        now[0] += 1.0
        assert trainer._checkpoint_due()
        assert trainer._clock.stop() == 120.0  # training time counted up to the checkpoint
        trainer._clock.restart()
        assert not trainer._checkpoint_due()
        trainer.config = dataclasses.replace(trainer.config, checkpoint_minutes=0.0)
        now[0] += 10_000.0
        assert not trainer._checkpoint_due()  # 0: at evaluations only
    finally:
        trainer.close()


def test_a_finished_run_resumed_with_a_larger_budget_continues_as_if_started_with_it(tmp_path):
    train(tiny_run(steps=300), tmp_path / "extended", progress=False, log=lambda *_: None)
    lines = []
    train(tiny_run(steps=450), tmp_path / "extended", resume=True, progress=False, log=lines.append)
    train(on_the_path_of(tiny_run(steps=450), tmp_path / "extended"), tmp_path / "straight", progress=False,
          log=lambda *_: None)
    assert any("budget: 300 → 450 steps" in line for line in lines)
    straight = read_metrics(tmp_path / "straight" / "metrics.csv")
    extended = read_metrics(tmp_path / "extended" / "metrics.csv")
    assert len(straight) == 3
    assert [r["eval_return_mean"] for r in extended] == [r["eval_return_mean"] for r in straight]
    assert json.loads((tmp_path / "extended" / "config.json").read_text())["steps"] == 450
    result = json.loads((tmp_path / "extended" / "result.json").read_text())
    assert result["finished"] and result["steps_done"] == 450
    with pytest.raises(UserError, match="at step 450, past --steps 300; give --steps 450 or more"):
        train(tiny_run(steps=300), tmp_path / "extended", resume=True, progress=False, log=lambda *_: None)


def test_resume_refuses_a_run_with_other_settings(tmp_path):
    train(tiny_run(), tmp_path / "run", progress=False, log=lambda *_: None)
    other = tiny_run(actor=actor_config("popsan", hidden=(16, 16)))
    with pytest.raises(UserError, match="different settings"):
        train(other, tmp_path / "run", resume=True, progress=False, log=lambda *_: None)


def test_run_directory_contents(tmp_path):
    train(tiny_run(), tmp_path / "run", progress=False, log=lambda *_: None)
    names = {p.name for p in (tmp_path / "run").iterdir()}
    assert {"config.json", "metrics.csv", "result.json", "policy.pt", "checkpoint.pt", "provenance.json", "replay",
            "tensorboard"} <= names
    assert not [p for p in (tmp_path / "run").rglob("*.tmp")], "no temporary file may be left behind"
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    assert config["seed"] == 0 and config["actor"]["intra"] == "intra" and config["label"] == "ilc-san"
    assert list(read_metrics(tmp_path / "run" / "metrics.csv")[0]) == [
        "step", "eval_return_mean", "eval_return_std", "eval_length_mean", "wall_seconds", "steps_per_second",
        "saturated_actions", "frozen_output_neurons", "surrogate_active", "mean_abs_preaction", "action_spread"]
    assert list((tmp_path / "run" / "tensorboard").iterdir()), "TensorBoard events are written"


def test_compiled_acting_calls_inductor_directly_and_sees_weights_changed_in_place():
    """The acting program resolves every input of the compiled graph (so it runs without dynamo's frame entry)
    and, holding the parameters themselves, acts with weights changed in place as the eager actor does."""
    config = actor_config("ilc-san", hidden=(16,), population_in=4, population_out=4, timesteps=3)
    agent = TD3(config, TrainingConfig(), TaskSpace(3, 2, [1.0, 1.0], [0.0, 0.0]), (0, 1),
                ComputeSettings(compile=True))
    state = np.random.default_rng(0).normal(size=(2, 3)).astype(np.float32)
    before = agent.act(state)
    (program,) = agent.actor_fn.programs.values()
    assert program.direct
    with torch.no_grad():
        for layer in agent.actor.layers:
            layer.weight.mul_(-1.5)
        eager = agent.actor(torch.as_tensor(state)[:, None, :])[:, 0].numpy()
    assert not np.allclose(before, eager, atol=1e-3)
    np.testing.assert_allclose(agent.act(state), eager, atol=1e-5)
