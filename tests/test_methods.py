"""Training methods as strategies (:mod:`ilcsan.rl.methods`): a new method is one class and one registration.

The toy method below exists only in this test. It explores with uniform noise on the action and learns one number per
seed that its own loss term pulls toward 1: registered, it trains (eager and compiled alike), checkpoints and resumes
exactly, without a line of the package knowing about it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch
from torch import nn

from ilcsan.config import EXPLORATION_PAPERS, TD3Config, actor_config
from ilcsan.errors import UserError
from ilcsan.rl.adam import Adam
from ilcsan.rl.algorithms import TD3
from ilcsan.rl.methods import EXPLORATION_METHODS, Exploration, MethodContext, register_exploration, relative_cost
from ilcsan.rl.training import train


class Level(nn.Module):
    def __init__(self, seeds: int):
        super().__init__()
        self.level = nn.Parameter(torch.zeros(seeds))


class UniformNoiseWithALevel(Exploration):
    """Explores with π(s) + 0.3·scale·U(−1, 1); its loss term (level − 1)² trains one number per seed."""

    def __init__(self, context: MethodContext):
        self.module = Level(len(context.seeds))
        self.adam = Adam(self.module, context.actor_config.learning_rate)
        self.scale, self.offset = context.action_scale, context.action_offset
        self.explored = 0

    @classmethod
    def relative_cost(cls, td3: TD3Config) -> float:
        return 1.5

    def explore(self, agent, states: np.ndarray, rngs) -> np.ndarray:
        self.explored += 1
        noise = np.stack([rng.uniform(-1.0, 1.0, len(self.scale)) for rng in rngs])
        return np.clip(agent.act(states) + 0.3 * noise * self.scale, self.offset - self.scale, self.offset + self.scale)

    def loss_terms(self, parameters, batch) -> torch.Tensor:
        return ((parameters[0] - 1.0) ** 2).sum()

    def seed_state(self, index: int) -> dict[str, Any]:
        return {"level": self.module.level.detach()[index:index + 1].clone(), "adam": self.adam.seed_state(index, 1)}

    def load_seed_states(self, states) -> None:
        with torch.no_grad():
            self.module.level.copy_(torch.cat([state["level"] for state in states]))
        self.adam.load_seed_states([state["adam"] for state in states])


@pytest.fixture
def toy():
    register_exploration("toy", UniformNoiseWithALevel, paper="a toy method of tests/test_methods.py")
    yield "toy"
    del EXPLORATION_METHODS["toy"], EXPLORATION_PAPERS["toy"]


def test_registering_makes_the_name_a_setting_and_a_method(toy):
    td3 = TD3Config(exploration="toy")
    assert relative_cost(td3) == 1.5
    from ilcsan.config import check_settings

    check_settings(td3)  # a valid choice now
    with pytest.raises(UserError, match="--exploration 'toys' is not one of: gaussian, noisy, toy"):
        check_settings(TD3Config(exploration="toys"))
    with pytest.raises(ValueError, match="needs the paper"):
        register_exploration("nameless", UniformNoiseWithALevel)


def test_a_registered_method_trains_checkpoints_and_resumes_exactly(toy, tmp_path, monkeypatch):
    from test_training import assert_resumes_to_the_same_curve, tiny_method_run

    config = tiny_method_run(exploration="toy")
    checkpoints = assert_resumes_to_the_same_curve(config, tmp_path, monkeypatch)
    for straight, resumed in checkpoints:
        level = float(straight["exploration"]["level"][0])
        assert 0.0 < level < 1.0, "its loss term moved its parameter toward 1, one Adam step per actor update"
        assert float(straight["exploration"]["adam"]["level"]["step"]) == straight["updates"] // 2
        assert torch.equal(straight["exploration"]["level"], resumed["exploration"]["level"])


def test_its_loss_term_runs_inside_the_compiled_update_as_it_does_uncompiled(toy):
    from test_training import _random_batch, assert_same_updates

    config = actor_config("ilc-san", hidden=(16,), population_in=4, population_out=4, timesteps=3)
    td3 = TD3Config(exploration="toy", critic_hidden=(16, 16))
    eager = TD3(config, td3, 3, 2, [1.0, 1.0], [0.0, 0.0], seeds=(7, 8))
    compiled = TD3(config, td3, 3, 2, [1.0, 1.0], [0.0, 0.0], seeds=(7, 8), compile=True)
    rng = np.random.default_rng(5)
    assert_same_updates(eager, compiled, [_random_batch(rng, 2, 16, 3, 2) for _ in range(6)], atol=2e-5)
    levels = [agent.exploration.module.level.detach() for agent in (eager, compiled)]
    assert torch.allclose(*levels, atol=1e-7) and bool((levels[0] > 0).all())
    explored = eager.explore(np.zeros((2, 3), np.float32), [np.random.default_rng(0), np.random.default_rng(1)])
    assert eager.exploration.explored == 1 and explored.shape == (2, 2)


def test_a_run_uses_the_registered_method(toy, tmp_path, monkeypatch):
    from test_training import tiny_run

    calls = []
    original = UniformNoiseWithALevel.explore
    monkeypatch.setattr(UniformNoiseWithALevel, "explore",
                        lambda self, *args: calls.append(1) or original(self, *args))
    config = tiny_run(steps=200, eval_every=200, td3=TD3Config(start_steps=150, update_after=100, update_every=25,
                                                               batch_size=16, exploration="toy"))
    train(config, tmp_path / "run", progress=False, log=lambda *_: None)
    assert len(calls) == 200 - 150  # every step after the random phase explores through the method
