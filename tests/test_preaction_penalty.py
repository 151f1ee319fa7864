"""The penalty λ·mean(O²) on the actor's pre-tanh output (``--preaction-penalty``, docs/fidelity-hopper/): its value
computed by hand from the actor's own readout, its gradient on a saturated actor, and the compiled update's."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ilcsan.config import TrainingConfig, actor_config
from ilcsan.rl.agent_settings import ComputeSettings, TaskSpace
from ilcsan.rl.algorithms import SAC, TD3
from ilcsan.snn.output import PassOptions

SMALL = {"ilc-san": dict(hidden=(16,), population_in=4, population_out=4, timesteps=3), "dan": dict(hidden=(8,))}


def _agent(preset: str, penalty: float, compile: bool = False) -> TD3:
    return TD3(actor_config(preset, **SMALL[preset]), TrainingConfig(critic_hidden=(16, 16), preaction_penalty=penalty),
               TaskSpace(3, 2, [1.0, 2.0], [0.0, 0.5]), (7, 8), ComputeSettings(compile=compile))


def _batch(agent: TD3, seed: int = 1) -> dict[str, torch.Tensor]:
    rng = np.random.default_rng(seed)
    arrays = {"obs": rng.normal(size=(2, 32, 3)), "action": rng.uniform(-1, 1, (2, 32, 2)),
              "reward": rng.normal(size=(2, 32)), "next_obs": rng.normal(size=(2, 32, 3)),
              "terminal": (rng.uniform(size=(2, 32)) < 0.1)}
    return agent.to_batch({name: value.astype(np.float32) for name, value in arrays.items()})


@pytest.mark.parametrize("preset", ["ilc-san", "dan"])
def test_the_penalty_adds_lambda_times_the_mean_squared_readout_of_each_seed(preset):
    plain, penalised = _agent(preset, 0.0), _agent(preset, 0.25)
    batch = _batch(plain)
    with torch.no_grad():
        readout = penalised.actor.run(batch["obs"]).readout  # (K, B, M), the pre-tanh output O
        expected = sum(0.25 * float((readout[k] ** 2).mean()) for k in range(2))
        difference = penalised.actor_loss(batch) - plain.actor_loss(batch)
    assert expected > 0.01
    assert float(difference) == pytest.approx(expected, rel=1e-5)


def test_a_saturated_actor_gets_a_gradient_back_into_tanhs_range_only_from_the_penalty():
    """O = Σ_t (W_D S_t + b_D): with b_D = +8 every action is saturated, tanh′(O) < 1e-5 and −Q's gradient on b_D is
    nearly nothing; the penalty's, 2λ T mean O / M per seed, points down (a descent step lowers O)."""
    grads = {}
    for penalty in (0.0, 0.1):
        agent = _agent("ilc-san", penalty)
        with torch.no_grad():
            agent.actor.decoder.bias.fill_(8.0)
        batch = _batch(agent)
        agent.actor_loss(batch).backward()
        grads[penalty] = agent.actor.decoder.bias.grad.clone()
        readout = agent.actor.run(batch["obs"]).readout.detach()
    assert float(torch.tanh(readout).abs().min()) > 0.99999
    assert float(grads[0.0].abs().max()) < 1e-3
    timesteps, actions = 3, 2
    expected = 2 * 0.1 * timesteps * readout.mean(dim=1) / actions
    torch.testing.assert_close(grads[0.1], expected, rtol=1e-3, atol=1e-3)
    assert float(grads[0.1].min()) > 1.0


@pytest.mark.parametrize("preset", ["ilc-san", "dan"])
def test_the_compiled_update_with_the_penalty_equals_the_eager_one(preset):
    eager, compiled = _agent(preset, 0.1), _agent(preset, 0.1, compile=True)
    plain = _agent(preset, 0.0)
    for step in range(6):
        for agent in (eager, compiled, plain):
            agent.update(agent.to_batch({k: v.numpy() for k, v in _batch(eager, seed=step).items()}))
    for ours, theirs in zip(eager.actor.parameters(), compiled.actor.parameters(), strict=True):
        torch.testing.assert_close(ours, theirs, atol=2e-5, rtol=1e-4)
    moved = [float((ours - other).detach().abs().max()) for ours, other in zip(eager.actor.parameters(),
                                                                       plain.actor.parameters(), strict=True)]
    assert max(moved) > 1e-5  # the penalty changed the actor's steps


def test_sac_adds_the_penalty_of_its_mean_through_the_same_loss_term():
    """SAC's actor loss gets λ·mean(μ²) of its pre-tanh mean μ from the same loss term as TD3's, and only when λ > 0."""
    config = actor_config("ilc-san", **SMALL["ilc-san"])
    plain, penalised = (SAC(config, TrainingConfig(critic_hidden=(16, 16), preaction_penalty=penalty),
                            TaskSpace(3, 2, [1.0, 2.0], [0.0, 0.5]), (7, 8)) for penalty in (0.0, 0.25))
    terms = [type(term).__name__ for term in penalised.actor_methods.loss_terms]
    assert not plain.actor_methods.loss_terms and terms == ["PreactionPenalty"]
    batch = {**_batch(plain), "noise": plain.standard_noise(32)}
    losses = []
    with torch.no_grad():
        for agent in (plain, penalised):
            tensors = agent.tensors()
            losses.append(agent.actor_loss(tensors["actor"], tensors["actor_buffers"], tensors["critic"],
                                           tensors["entropy"][0].exp(), batch)[0])
        mean = penalised.actor(batch["obs"], options=PassOptions(preaction=True))[1][..., :2]
    expected = sum(0.25 * float((mean[k] ** 2).mean()) for k in range(2))
    assert expected > 0.01
    assert float(losses[1] - losses[0]) == pytest.approx(expected, rel=1e-5)
