"""Proxy Target (Xu et al., NeurIPS 2025): the proxy imitates the online spiking actor, replaces the spiking
target actor in TD3's target values when asked, works for stacked seeds, and resumes exactly."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
import torch

from ilcsan.config import RunConfig, TrainingConfig, actor_config
from ilcsan.errors import UserError
from ilcsan.methods.proxy_target import PROXY_HIDDEN
from ilcsan.rl.agent_settings import ComputeSettings, TaskSpace
from ilcsan.rl.algorithms import TD3
from ilcsan.rl.algorithms.td3 import PolyakTarget
from ilcsan.rl.methods.proxy_target import ProxyTarget
from ilcsan.rl.training import train

SMALL_ACTOR = actor_config("ilc-san", hidden=(16, 16))
PROXY_TRAINING = TrainingConfig(target_actor="proxy", target_noise=0.0)


def _agent(training: TrainingConfig, seeds=(0,), actor=SMALL_ACTOR) -> TD3:
    return TD3(actor, training, TaskSpace(3, 2, [2.0, 1.0], [0.0, 0.5]), seeds)


def _states(rng, seeds: int, batch: int = 64) -> torch.Tensor:
    return torch.as_tensor(rng.normal(size=(seeds, batch, 3)), dtype=torch.float32)


def _manual_target(agent: TD3, target_actor, next_obs, reward, terminal):
    """y = r + γ(1 − d) min_j Q'_j(s', π'(s')) without smoothing noise (target_noise = 0), bounds applied."""
    with torch.no_grad():
        action = target_actor(next_obs)
        action = torch.maximum(torch.minimum(action, agent.offset + agent.scale), agent.offset - agent.scale)
        q = agent.critic_target(next_obs, action).min(dim=1).values
    return reward + 0.99 * (1 - terminal) * q


def test_the_proxy_is_a_continuous_mlp_and_the_spiking_target_is_gone():
    agent = _agent(PROXY_TRAINING)
    assert isinstance(agent.target_method, ProxyTarget) and agent.actor_target is agent.target_method.module
    assert [layer.out_features for layer in agent.target_method.module.mlp.layers] == [*PROXY_HIDDEN, 2]
    assert all(p.requires_grad for p in agent.target_method.module.parameters())
    assert isinstance(_agent(TrainingConfig()).target_method, PolyakTarget)


def test_the_proxy_learns_to_imitate_the_spiking_actor_and_leaves_it_unchanged():
    agent = _agent(PROXY_TRAINING)
    actor_before = copy.deepcopy(agent.actor.state_dict())
    rng = np.random.default_rng(0)
    held_out = _states(rng, 1, 256)
    with torch.no_grad():
        goal = agent.actor(held_out)
    first = float(agent.target_method.loss(held_out, goal).detach())
    for _ in range(100):
        agent.target_method.fit(agent.actor, torch.stack([_states(rng, 1) for _ in range(3)]))
    last = float(agent.target_method.loss(held_out, goal).detach())
    assert last < 0.1 * first, (first, last)
    for name, value in agent.actor.state_dict().items():
        assert torch.equal(value, actor_before[name]), name


def _batch(next_obs, noise, reward, terminal) -> dict[str, torch.Tensor]:
    return {"next_obs": next_obs, "smoothing_noise": noise, "reward": reward, "terminal": terminal}


def test_target_values_use_the_proxy_when_asked():
    rng = np.random.default_rng(1)
    next_obs, reward = _states(rng, 1, 8), torch.ones(1, 8)
    terminal, noise = torch.zeros(1, 8), torch.zeros(1, 8, 2)
    proxy_agent = _agent(PROXY_TRAINING)
    expected = _manual_target(proxy_agent, proxy_agent.target_method.module, next_obs, reward, terminal)
    with torch.no_grad():
        got = proxy_agent.target_values(_batch(next_obs, noise, reward, terminal))
        assert torch.allclose(got, expected)
        assert not torch.allclose(got, _manual_target(proxy_agent, proxy_agent.actor, next_obs, reward, terminal))
        proxy_agent.target_method.module.mlp.layers[-1].bias.add_(0.3)  # a changed proxy changes the targets
        assert not torch.allclose(proxy_agent.target_values(_batch(next_obs, noise, reward, terminal)), got)


def test_target_values_use_the_soft_updated_spiking_target_otherwise():
    rng = np.random.default_rng(2)
    next_obs, reward = _states(rng, 1, 8), torch.ones(1, 8)
    terminal, noise = torch.zeros(1, 8), torch.zeros(1, 8, 2)
    agent = _agent(TrainingConfig(target_noise=0.0))
    assert type(agent.actor_target) is type(agent.actor)
    spiking_copy = copy.deepcopy(agent.actor)
    with torch.no_grad():
        got = agent.target_values(_batch(next_obs, noise, reward, terminal))
    assert torch.allclose(got, _manual_target(agent, spiking_copy, next_obs, reward, terminal))


def _random_batch(rng, seeds: int, iterations: int) -> dict[str, np.ndarray]:
    arrays = {"obs": rng.normal(size=(seeds, 32, 3)), "action": rng.uniform(-1, 1, (seeds, 32, 2)),
              "reward": rng.normal(size=(seeds, 32)), "next_obs": rng.normal(size=(seeds, 32, 3)),
              "terminal": rng.uniform(size=(seeds, 32)) < 0.1,
              "proxy_obs": rng.normal(size=(iterations, seeds, 32, 3))}
    return {k: v.astype(np.float32) for k, v in arrays.items()}


def test_each_seed_of_a_stacked_proxy_updates_like_a_single_run():
    training = TrainingConfig(target_actor="proxy", proxy_iterations=2)
    many, single = _agent(training, seeds=(4, 11)), _agent(training, seeds=(11,))
    rng = np.random.default_rng(3)
    for _ in range(4):
        arrays = _random_batch(rng, 2, 2)
        many.update(many.to_batch(arrays))
        single.update(single.to_batch({k: v[:, 1:] if k == "proxy_obs" else v[1:] for k, v in arrays.items()}))
    for module in ("actor", "actor_target", "critic"):
        factor = 2 if module == "critic" else 1
        for (name, p_many), (_, p_single) in zip(getattr(many, module).named_parameters(),
                                                 getattr(single, module).named_parameters(), strict=True):
            assert torch.allclose(p_many[factor:], p_single, atol=1e-5), f"{module}.{name}"


def test_the_proxy_is_refused_for_dan(tmp_path):
    config = RunConfig(task="Pendulum-v1", steps=10, actor=actor_config("dan", hidden=(8,)),
                       training=TrainingConfig(target_actor="proxy"), threads=1)
    with pytest.raises(UserError, match="DAN"):
        train(config, tmp_path / "dan", progress=False, log=lambda *_: None)


def test_the_options_parse_and_are_saved_in_config_json(tmp_path):
    from ilcsan.cli import build_parser
    from ilcsan.cli.train import build_run_config

    args = build_parser().parse_args(["train", "--task", "Pendulum-v1", "--target-actor", "proxy",
                                      "--proxy-iterations", "1", "--proxy-lr", "3e-3"])
    config = build_run_config(args)
    training = config.training
    assert (training.target_actor, training.proxy_iterations, training.proxy_lr) == ("proxy", 1, 3e-3)
    saved = json.loads(json.dumps(config.for_seed(0)))
    assert RunConfig.from_dict(saved).training == config.training
    with pytest.raises(UserError, match="target-actor"):
        build_run_config(build_parser().parse_args(["train", "--target-actor", "ann"]))


def test_an_interrupted_proxy_run_resumes_to_the_same_curve(tmp_path, monkeypatch):
    from test_training import assert_resumes_to_the_same_curve, tiny_method_run

    config = tiny_method_run(target_actor="proxy", proxy_iterations=2)
    checkpoints = assert_resumes_to_the_same_curve(config, tmp_path, monkeypatch)
    resumed = checkpoints[1][1]
    assert resumed["config"]["training"]["target_actor"] == "proxy" and resumed["proxy_optimizer"]


def test_a_compiled_proxy_agent_updates_like_the_eager_one():
    """The compiled target values read the proxy's current weights (it trains between calls), and the compiled
    regression steps leave the proxy and its Adam state as the same functions run uncompiled do. Few updates: Adam
    turns the float rounding of the 512-wide proxy's near-zero gradients into visible differences after some 36
    steps."""
    config = actor_config("ilc-san", hidden=(16,), population_in=4, population_out=4, timesteps=3)
    training = TrainingConfig(target_actor="proxy", proxy_iterations=2)
    task = TaskSpace(3, 2, [1.0, 1.0], [0.0, 0.0])
    eager = TD3(config, training, task, (7,))
    compiled = TD3(config, training, task, (7,), ComputeSettings(compile=True))
    from test_training import assert_same_updates

    rng = np.random.default_rng(4)
    assert_same_updates(eager, compiled, [_random_batch(rng, 1, 2) for _ in range(4)], atol=1e-4)
    assert compiled.target_method.program.direct, "the regression steps run as one program, called directly"
    assert compiled.critic_step.direct and compiled.delayed_step.direct
    for before, after in zip(eager.target_method.adam.tensors(), compiled.target_method.adam.tensors(), strict=True):
        for ours, theirs in zip(before, after, strict=True):  # the proxy's Adam state too
            torch.testing.assert_close(ours, theirs, atol=1e-6, rtol=1e-4)


def test_ilcsan_actors_lists_the_training_methods_with_their_papers(capsys):
    from ilcsan.cli import main

    assert main(["actors"]) == 0
    out = capsys.readouterr().out
    assert "--target-actor proxy" in out and "arXiv 2505.24161" in out and "--target-actor polyak" in out
    assert "--algorithm sac" in out and "--algorithm ddpg" in out and "--normalization care-bn" in out
