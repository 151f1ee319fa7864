"""The algorithms behind the seam (:mod:`ilcsan.rl.algorithms`): DDPG and SAC against hand-computed cases, compiled
against eager, checkpoints, deployment and the command line. TD3 itself: test_training.py and the methods' tests."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import torch
from torch.distributions import Normal, TransformedDistribution
from torch.distributions.transforms import TanhTransform

import ilcsan
import ilcsan.errors
from ilcsan.config import PRESETS, RunConfig, TrainingConfig, actor_config
from ilcsan.rl.agent_settings import ComputeSettings, TaskSpace
from ilcsan.rl.algorithms import DDPG, SAC, TD3
from ilcsan.rl.training import train
from ilcsan.snn.output import PassOptions

SMALL = {"ilc-san": dict(hidden=(16,), population_in=4, population_out=4, timesteps=3), "dan": dict(hidden=(8,))}
SCALE, OFFSET = [2.0, 1.0], [0.0, 0.5]


def _agent(cls, preset="ilc-san", seeds=(0,), training=None, **options):
    return cls(actor_config(preset, **SMALL[preset]), training or TrainingConfig(critic_hidden=(16, 16)),
               TaskSpace(3, 2, SCALE, OFFSET), seeds, ComputeSettings(**options))


def _batch(seeds: int, size: int = 8, seed: int = 0) -> dict[str, torch.Tensor]:
    rng = np.random.default_rng(seed)
    arrays = {"obs": rng.normal(size=(seeds, size, 3)), "next_obs": rng.normal(size=(seeds, size, 3)),
              "action": rng.uniform(-1, 1, size=(seeds, size, 2)) * SCALE + OFFSET,
              "reward": rng.normal(size=(seeds, size)), "terminal": (rng.uniform(size=(seeds, size)) < 0.3)}
    return {name: torch.as_tensor(value, dtype=torch.float32) for name, value in arrays.items()}


# ------------------------------------------------------------------------------------------- DDPG
def test_ddpg_has_one_critic_and_no_target_smoothing():
    """y = r + γ(1 − d) Q'(s', π'(s')): one critic per seed, the target action unperturbed (TD3 at σ̃ = 0 over its
    twin minimum would differ)."""
    agent = _agent(DDPG, seeds=(0, 1))
    batch = _batch(2)
    assert agent.critic(batch["obs"], batch["action"]).shape == (2, 1, 8)
    with torch.no_grad():
        q_next = agent.critic_target.mlp(torch.cat([batch["next_obs"], agent.actor_target(batch["next_obs"])], -1))
        expected = batch["reward"] + 0.99 * (1 - batch["terminal"]) * q_next.squeeze(-1)
        torch.testing.assert_close(agent.target_values(batch), expected)


def test_ddpg_steps_the_actor_and_targets_at_every_update():
    agent = _agent(DDPG, "dan")
    before = [p.clone() for p in agent.actor_target.parameters()]
    for update in range(3):
        losses = agent.update(_batch(1, seed=update))
        assert losses["actor_loss"] is not None
    assert all(not torch.equal(a, b) for a, b in zip(before, agent.actor_target.parameters(), strict=True))
    agent = _agent(TD3, "dan")
    assert [agent.update(_batch(1, seed=u))["actor_loss"] is None for u in range(4)] == [True, False, True, False]


# -------------------------------------------------------------------------------------------- SAC
def test_sac_log_density_is_the_squashed_gaussians():
    """log π of a sample equals torch.distributions' tanh-transformed Normal at the unscaled action tanh(u)."""
    agent = _agent(SAC, "dan", seeds=(0, 1))
    states, noise = _batch(2)["obs"], torch.randn(2, 8, 2, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        action, log_prob, mean = agent.sample(agent.actor, states, noise)
        readout = agent.actor(states, options=PassOptions(preaction=True))[1]
    log_std = readout[..., 2:].clamp(-20, 2)
    assert torch.equal(mean, readout[..., :2])
    squashed = TransformedDistribution(Normal(mean, log_std.exp()), [TanhTransform()])
    unscaled = (action - agent.offset) / agent.scale
    torch.testing.assert_close(log_prob, squashed.log_prob(unscaled).sum(-1), atol=2e-4, rtol=1e-4)


def test_sac_target_values_subtract_the_entropy_term():
    """y = r + γ(1 − d)(min_j Q'_j(s', a') − α log π(a' | s')) with a' the reparameterised sample of ε'."""
    agent = _agent(SAC, seeds=(0, 1))
    batch = {**_batch(2), "next_noise": torch.randn(2, 8, 2, generator=torch.Generator().manual_seed(5))}
    alpha = torch.tensor([0.5, 2.0])
    with torch.no_grad():
        next_action, log_prob, _ = agent.sample(agent.actor, batch["next_obs"], batch["next_noise"])
        q_next = agent.critic_target(batch["next_obs"], next_action)
        expected = batch["reward"] + 0.99 * (1 - batch["terminal"]) * (
            torch.minimum(q_next[:, 0], q_next[:, 1]) - alpha[:, None] * log_prob)
        torch.testing.assert_close(agent.target_values(batch, agent.actor, agent.critic_target, alpha), expected)


def test_sac_entropy_coefficient_moves_toward_the_target_entropy():
    """Adam's first step moves log α by lr against the sign of ∂/∂log α = −mean(log π(ã|s) + H̄), H̄ = −M, with ã the
    update's own sample (the generators' second draw, taken before the actor's step)."""
    training = TrainingConfig(critic_hidden=(16, 16), entropy_lr=0.01, initial_entropy_coefficient=0.3)
    agent = _agent(SAC, seeds=(0, 1), training=training)
    batch = _batch(2)
    generators = [copy.deepcopy(g.get_state()) for g in agent.noise_generators]
    actor = copy.deepcopy(agent.actor)
    agent.standard_noise(8)  # a' comes first
    noise = agent.standard_noise(8)
    for generator, state in zip(agent.noise_generators, generators, strict=True):
        generator.set_state(state)
    with torch.no_grad():
        _, log_prob, _ = agent.sample(actor, batch["obs"], noise)
    gradient = -(log_prob - 2.0).mean(-1)
    agent.update(batch)
    expected = math.log(0.3) - 0.01 * torch.sign(gradient)
    torch.testing.assert_close(agent.entropy.log_alpha.detach(), expected, atol=1e-6, rtol=0)
    assert np.allclose(agent.alpha, np.exp(expected.numpy()))


@pytest.mark.parametrize("preset", ["ilc-san", "dan"])
def test_sac_acts_with_the_mean_and_deploys_only_the_means_populations(preset):
    agent = _agent(SAC, preset, seeds=(0, 1))
    states = _batch(2)["obs"]
    with torch.no_grad():
        readout = agent.actor(states, options=PassOptions(preaction=True))[1]
        deployed = agent.deployable_actor()
        expected = agent.offset + agent.scale * torch.tanh(readout[..., :2])
        torch.testing.assert_close(deployed(states), expected)
    np.testing.assert_allclose(agent.act(states.numpy()), expected.numpy(), rtol=1e-5, atol=1e-6)
    assert sum(p.numel() for p in deployed.parameters()) < sum(p.numel() for p in agent.actor.parameters())
    explored = agent.explore(states[:, 0].numpy(), [np.random.default_rng(1), np.random.default_rng(2)])
    assert explored.shape == (2, 2) and not np.allclose(explored, expected[:, 0].numpy())
    assert np.all(np.abs(explored - OFFSET) <= SCALE)


@pytest.mark.parametrize("cls", [SAC, DDPG])
def test_compiled_update_equals_the_eager_update(cls):
    eager, compiled = _agent(cls, seeds=(7, 8)), _agent(cls, seeds=(7, 8), compile=True)
    for update in range(6):
        losses = [agent.update(_batch(2, seed=update)) for agent in (eager, compiled)]
        for key in ("critic_loss", "actor_loss"):
            assert float(losses[0][key]) == pytest.approx(float(losses[1][key]), rel=1e-4, abs=1e-5), key
    for name, _, _ in eager.networks():
        for ours, theirs in zip(getattr(eager, name).parameters(), getattr(compiled, name).parameters(), strict=True):
            torch.testing.assert_close(ours, theirs, atol=2e-5, rtol=1e-4)
    program = compiled.update_step if cls is SAC else compiled.delayed_step  # DDPG: an actor step every update
    assert program.direct


@pytest.mark.parametrize("preset", list(PRESETS))
@pytest.mark.parametrize("cls", [DDPG, SAC])
def test_every_preset_trains_and_deploys_with_ddpg_and_sac(cls, preset):
    """Each actor of the paper and its baselines under DDPG and SAC: two updates move every parameter of the actor
    (spiking presets through their surrogate gradients), the losses are finite, and the deployed actor gives one
    action per state inside the action bounds."""
    small = SMALL.get(preset, SMALL["ilc-san"])
    agent = cls(actor_config(preset, **small), TrainingConfig(critic_hidden=(16, 16)), TaskSpace(3, 2, SCALE, OFFSET),
                (0, 1))
    before = [parameter.clone() for parameter in agent.actor.parameters()]
    for update in range(2):
        losses = agent.update(_batch(2, seed=update))
    assert math.isfinite(float(losses["critic_loss"])) and math.isfinite(float(losses["actor_loss"]))
    unchanged = [index for index, (old, new) in enumerate(zip(before, agent.actor.parameters(), strict=True))
                 if torch.equal(old, new)]
    assert not unchanged, f"{preset}: actor parameters {unchanged} did not move"
    states = _batch(2)["obs"]
    with torch.no_grad():
        actions = agent.deployable_actor()(states)
    assert actions.shape == (2, 8, 2)
    assert torch.all((actions - torch.tensor(OFFSET)).abs() <= torch.tensor(SCALE))


# ---------------------------------------------------------------------------- runs, files, CLI
def _run(algorithm: str, steps: int = 400, **options) -> RunConfig:
    return RunConfig(task="Pendulum-v1", seeds=(0, 1), steps=steps, eval_every=200, eval_episodes=2,
                     actor=actor_config("ilc-san", **SMALL["ilc-san"]), algorithm=algorithm, threads=1,
                     compile="off", training=TrainingConfig(start_steps=100, update_after=100, update_every=25,
                                                  critic_hidden=(16, 16)), **options)


@pytest.mark.parametrize("algorithm", ["sac", "ddpg"])
def test_an_interrupted_run_resumes_exactly(tmp_path, monkeypatch, algorithm):
    from test_training import interrupt_after_first_checkpoint, on_the_path_of, read_metrics

    config = _run(algorithm)
    interrupt_after_first_checkpoint(config, tmp_path / "cut", monkeypatch)
    train(config, tmp_path / "cut", resume=True, progress=False, log=lambda *_: None)
    straight_config = on_the_path_of(config, tmp_path / "cut" / "seed0")
    train(straight_config, tmp_path / "straight", progress=False, log=lambda *_: None)
    for seed in ("seed0", "seed1"):
        straight, resumed = (read_metrics(tmp_path / run / seed / "metrics.csv") for run in ("straight", "cut"))
        keep = [key for key in straight[0] if key not in ("wall_seconds", "steps_per_second")]
        assert [[row[key] for key in keep] for row in straight] == [[row[key] for key in keep] for row in resumed]


def test_a_sac_policy_file_holds_the_deterministic_actor(tmp_path):
    config = _run("sac", steps=200)
    train(config, tmp_path / "run", progress=False, log=lambda *_: None)
    policy = ilcsan.load(tmp_path / "run" / "seed1")
    observation = np.array([0.3, -0.9, 0.5], dtype=np.float32)
    action = policy.predict(observation)
    assert action.shape == (1,) and np.all(np.abs(action) <= 2.0)
    assert policy.actor.layers[-1].weight.shape[1] == 1 * 4  # one action dimension × P_out: the mean's populations


def test_resuming_with_another_algorithm_is_refused(tmp_path):
    train(_run("sac", steps=200), tmp_path / "run", progress=False, log=lambda *_: None)
    with pytest.raises(ilcsan.errors.UserError, match="algorithm"):
        train(_run("td3", steps=400), tmp_path / "run", resume=True, progress=False, log=lambda *_: None)


@pytest.mark.parametrize(("flags", "message"), [
    (["--algorithm", "sac", "--exploration", "noisy"], "--exploration noisy is a method for TD3 and DDPG"),
    (["--algorithm", "sac", "--target-actor", "proxy"], "--target-actor proxy is a method for TD3 and DDPG"),
    (["--algorithm", "ppo"], "--algorithm"),
])
def test_impossible_algorithm_settings_are_one_line(tmp_path, capsys, flags, message):
    from ilcsan.cli import main

    code = main(["train", "--task", "Pendulum-v1", "--steps", "100", "--out", str(tmp_path / "run"), *flags])
    err = capsys.readouterr().err
    assert code == 2 and message in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()


def test_a_sac_checkpoint_loads_as_its_deterministic_policy(tmp_path):
    """A checkpoint holds SAC's whole actor (mean and log-std populations); loaded as a policy it acts as policy.pt,
    with the mean's."""
    train(_run("sac", steps=200), tmp_path / "run", progress=False, log=lambda *_: None)
    observations = np.random.default_rng(0).normal(size=(4, 3)).astype(np.float32)
    from_checkpoint = ilcsan.load(tmp_path / "run" / "seed0" / "checkpoint.pt").predict(observations)
    from_policy = ilcsan.load(tmp_path / "run" / "seed0" / "policy.pt").predict(observations)
    np.testing.assert_allclose(from_checkpoint, from_policy, rtol=1e-5, atol=1e-6)


def test_the_old_name_of_the_polyak_target_still_works(tmp_path, capsys):
    """``--target-actor spiking`` (its name before DDPG and SAC) runs as ``polyak`` with one note; a config.json that
    holds the old name reads as today's, and such a run is the same configuration in reports."""
    from ilcsan.analysis.collect import configuration_key
    from ilcsan.cli import main

    assert TrainingConfig(target_actor="spiking").target_actor == "polyak"
    assert TrainingConfig.from_dict({**TrainingConfig().to_dict(), "target_actor": "spiking"}) == TrainingConfig()
    actor = actor_config("ilc-san").to_dict()
    assert configuration_key(actor, {"target_actor": "spiking"}) == configuration_key(actor, {})
    assert configuration_key(actor, {}, "sac") != configuration_key(actor, {})
    code = main(["train", "--task", "Pendulum-v1", "--steps", "1", "--eval-every", "1", "--eval-episodes", "1",
                 "--hidden-width", "8", "--target-actor", "spiking", "--no-progress", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 0 and "note: --target-actor spiking is now called polyak (the old name still works)" in err
    assert '"target_actor": "polyak"' in (tmp_path / "run" / "config.json").read_text()
