"""A new normalisation is a declaration, a layer module and its training hooks, registered with one line: the actor,
the training update and every export take it without a line of ``snn/``, ``rl/`` or ``deploy/`` knowing of it.

The toy below exists only in this test: each synaptic layer's current is shifted by a per-seed, per-neuron amount m
kept in a persistent buffer, X̂ = X − m, and its export folds the shift into the layer's bias, b' = b − m.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from spiking_policies import deployed, observations, random_policy
from torch import nn

from ilcsan import methods
from ilcsan.actors import build_actor
from ilcsan.config import TrainingConfig, actor_config
from ilcsan.deploy.state import export_state
from ilcsan.methods import Declared
from ilcsan.rl.agent_settings import TaskSpace
from ilcsan.rl.algorithms import TD3
from ilcsan.rl.methods import Normalization
from ilcsan.snn.normalization import NormStatistics


class ShiftLayer(nn.Module):
    """X̂ = X − m for one synaptic layer of K seeds and D neurons; m is the persistent buffer ``shift`` (K, D)."""

    def __init__(self, ensemble: int, features: int, threshold: float):
        super().__init__()
        self.register_buffer("shift", torch.zeros(ensemble, features))

    def reset_parameters(self) -> None:
        with torch.no_grad():
            self.shift.zero_()

    def running(self) -> NormStatistics:
        return NormStatistics(self.shift, torch.ones_like(self.shift))

    def forward(self, currents: torch.Tensor, statistics: NormStatistics) -> torch.Tensor:
        return currents - statistics.mean.reshape(statistics.mean.shape[0], *([1] * (currents.dim() - 2)), -1)

    def folded_linear(self, tensors, weight, bias):
        return weight, bias - tensors["shift"]


class Shift(Declared):
    kind, name, title = "normalization", "toy-shift", "the toy shift"
    paper = "a toy normalisation of tests/test_toy_normalization.py"
    option_help = "toy-shift, a fixed shift of each current (tests only)"
    spiking_only = True
    spiking_reason = "it shifts the currents of spiking neurons"
    training = Normalization  # nothing to do while training: the hooks' defaults
    actor_layer = ShiftLayer


@pytest.fixture
def toy_shift():
    with methods.while_registered(Shift) as name:
        yield name


def shifted(actor, seed: int = 3) -> None:
    """Each layer's shift away from zero, so that a test sees it used."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for norm in actor.norms:
            norm.shift.copy_(0.5 * torch.randn(norm.shift.shape, generator=generator))


def test_the_actor_normalises_with_the_declared_layer(toy_shift):
    config = actor_config("ilc-san", hidden=(16,), normalization=toy_shift)
    actor = build_actor(config, 3, 2, [1.0, 1.0], seeds=(0, 1))
    assert [type(norm) for norm in actor.norms] == [ShiftLayer, ShiftLayer]
    plain = build_actor(actor_config("ilc-san", hidden=(16,)), 3, 2, [1.0, 1.0], seeds=(0, 1))
    state = torch.randn(2, 5, 3)
    assert torch.equal(actor(state), plain(state)), "a zero shift is no shift; the other weights are the same"
    shifted(actor)
    assert not torch.equal(actor(state), plain(state))
    torch.testing.assert_close(actor.run(state, "reference").action, actor.run(state, "fast").action)


def test_the_update_trains_it_and_keeps_its_buffer_in_checkpoints(toy_shift):
    agent = TD3(actor_config("ilc-san", hidden=(8,), normalization=toy_shift), TrainingConfig(policy_delay=1),
                TaskSpace(3, 2, [1.0, 1.0], [0.0, 0.0]), (0,))
    shifted(agent.actor)
    before = agent.actor.layers[0].weight.detach().clone()
    rng = np.random.default_rng(0)
    arrays = {"obs": rng.normal(size=(1, 8, 3)), "action": rng.uniform(-1, 1, (1, 8, 2)),
              "reward": rng.normal(size=(1, 8)), "next_obs": rng.normal(size=(1, 8, 3)), "terminal": np.zeros((1, 8))}
    losses = agent.update(agent.to_batch({name: value.astype(np.float32) for name, value in arrays.items()}))
    assert losses["actor_loss"] is not None and not torch.equal(agent.actor.layers[0].weight, before)
    assert torch.equal(agent.seed_state(0)["actor"]["norms.0.shift"], agent.actor.norms[0].shift[0:1])


def test_every_export_folds_it_as_it_declares(toy_shift):
    policy = random_policy("ilc-san", state_dim=3, hidden=(16, 16), normalization=toy_shift)
    shifted(policy.actor)
    arrays = export_state(policy.actor)
    assert not any(name.startswith("norms.") for name in arrays)
    batch = observations(policy, 12)
    expected = policy.predict(batch)
    assert np.abs(deployed(policy).act(batch) - expected).max() < 1e-4
    with torch.no_grad():
        for norm in policy.actor.norms:
            norm.shift.zero_()
    assert np.abs(policy.predict(batch) - expected).max() > 1e-2, "the shift changes the actions"
