"""A new algorithm is a declaration and one class behind the seam, registered with one line: the command line, the
training loop, checkpoints and resuming take it without a line of the package knowing of it.

The toy below exists only in this test. It evaluates the actor it is given and never improves it: the twin critics
learn y = r + γ(1 − d) min_j Q'_j(s', π(s')) with the actor as it is, exploring with uniform noise on its action.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ilcsan import methods
from ilcsan.cli import build_parser
from ilcsan.cli.train import build_run_config
from ilcsan.compute.programs import as_function, as_program, module_tensors
from ilcsan.methods import Declared
from ilcsan.rl.algorithms import OffPolicyAlgorithm
from ilcsan.rl.training import train


class PolicyEvaluation(OffPolicyAlgorithm):
    """Critics fitted to the actor's own values; the actor stays as it was initialised."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        constants = [tensor for module in (self.actor, self.critic, self.critic_target)
                     for tensor in module_tensors(module)]
        self.critic_program = as_program(self._critic_update, constants, self.compiled)

    def explore(self, normalized_state: np.ndarray, rngs) -> np.ndarray:
        noise = np.stack([rng.uniform(-0.5, 0.5, self.action_dim) for rng in rngs]) * self.action_scale
        low, high = self.action_offset - self.action_scale, self.action_offset + self.action_scale
        return np.clip(self.act(normalized_state) + noise, low, high)

    def update(self, batch):
        self.updates += 1
        return {"critic_loss": self.run(self.critic_program, batch), "actor_loss": None}

    def _critic_update(self, tensors, batch):
        with torch.no_grad():
            actor = self.update_tensors.stateful(self.actor, tensors["actor"], tensors["actor_buffers"])
            critic = as_function(self.critic_target, tensors["critic_target"], self.critic_names)
            next_q = critic(batch["next_obs"], actor(batch["next_obs"])).min(dim=1).values
            target = batch["reward"] + self.training.gamma * (1.0 - batch["terminal"]) * next_q
        loss = self.step_critics(tensors, batch, target)
        self.follow_critics(tensors)
        return loss


class Evaluation(Declared):
    kind, name, title = "algorithm", "evaluation", "policy evaluation"
    paper = "a toy algorithm of tests/test_toy_algorithm.py"
    option_help = "evaluation, critics of a fixed actor (tests only)"
    own_exploration = "it explores with its own uniform noise and has no target actor"
    training = PolicyEvaluation


@pytest.fixture
def evaluation():
    with methods.while_registered(Evaluation) as name:
        yield name


def test_a_registered_algorithm_is_a_choice_of_the_command_line(evaluation, monkeypatch):
    monkeypatch.setenv("COLUMNS", "1000")
    parser = build_parser()
    train_help = parser._subparsers._group_actions[0].choices["train"].format_help()
    assert "evaluation, critics of a fixed actor (tests only)" in train_help
    config = build_run_config(parser.parse_args(["train", "--algorithm", "evaluation", "--task", "Pendulum-v1"]))
    assert config.algorithm == "evaluation"


def test_a_registered_algorithm_trains_checkpoints_and_resumes_exactly(evaluation, tmp_path, monkeypatch):
    from test_training import assert_resumes_to_the_same_curve, tiny_run, tiny_training

    training = tiny_training()  # the settings as made now that the toy is registered (made before, they lack it)
    config = tiny_run(seeds=(0, 1), steps=450, algorithm=evaluation, training=training)
    checkpoints = assert_resumes_to_the_same_curve(config, tmp_path, monkeypatch)
    for straight, resumed in checkpoints:
        assert straight["updates"] > 0 and straight["updates"] == resumed["updates"]
        for name, tensor in straight["critic"].items():
            assert torch.equal(tensor, resumed["critic"][name]), name
    untrained = train(tiny_run(steps=100, eval_every=100, algorithm=evaluation, training=training),
                      tmp_path / "untrained",
                      progress=False, log=lambda *_: None)
    trained_actor = torch.load(tmp_path / "straight" / "seed0" / "policy.pt", weights_only=True)["actor"]
    fresh_actor = torch.load(untrained[0]["directory"] + "/policy.pt", weights_only=True)["actor"]
    assert all(torch.equal(tensor, fresh_actor[name]) for name, tensor in trained_actor.items()), \
        "the toy never steps the actor: it is the actor it was initialised with"
