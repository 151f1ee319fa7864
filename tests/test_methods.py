"""Training methods as declarations and strategies: a new method is one declaration, its hooks and one registration.

The toy method below exists only in this test. It explores with uniform noise on the action, as wide as its one
setting says, and learns one number per seed that its own loss term pulls toward 1. Registered, it is a flag of
``ilcsan train``, a key of a grid row, part of a run's identity in reports and a cost in ``reproduce --list``, and it
trains (eager and compiled alike), checkpoints and resumes exactly, without a line of the package knowing about it.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
import torch
from torch import nn

from ilcsan import methods
from ilcsan.config import actor_config, check_settings, training_config_class
from ilcsan.errors import UserError
from ilcsan.methods import Declared
from ilcsan.rl.adam import Adam
from ilcsan.rl.agent_settings import ComputeSettings, TaskSpace
from ilcsan.rl.algorithms import TD3
from ilcsan.rl.methods import Exploration, MethodContext
from ilcsan.rl.training import train
from ilcsan.settings import setting


class Level(nn.Module):
    def __init__(self, seeds: int):
        super().__init__()
        self.level = nn.Parameter(torch.zeros(seeds))


class UniformNoiseWithALevel(Exploration):
    """Explores with π(s) + width·scale·U(−1, 1); its loss term (level − 1)² trains one number per seed."""

    def __init__(self, context: MethodContext):
        self.module = Level(len(context.seeds))
        self.adam = Adam(self.module, context.actor_config.learning_rate)
        self.scale, self.offset = context.task.action_scale, context.task.action_offset
        self.width = context.training.toy_width
        self.explored = 0

    def explore(self, agent, states: np.ndarray, rngs) -> np.ndarray:
        self.explored += 1
        noise = np.stack([rng.uniform(-1.0, 1.0, len(self.scale)) for rng in rngs])
        return np.clip(agent.act(states) + self.width * noise * self.scale, self.offset - self.scale,
                       self.offset + self.scale)

    def loss_terms(self, parameters, batch) -> torch.Tensor:
        return ((parameters[0] - 1.0) ** 2).sum()

    def seed_state(self, index: int) -> dict[str, Any]:
        return {"level": self.module.level.detach()[index:index + 1].clone(), "adam": self.adam.seed_state(index, 1)}

    def load_seed_states(self, states) -> None:
        with torch.no_grad():
            self.module.level.copy_(torch.cat([state["level"] for state in states]))
        self.adam.load_seed_states([state["adam"] for state in states])


class ToyNoise(Declared):
    """The toy method as declared: what the package learns of it from the registry."""

    kind, name, title = "exploration", "toy", "the toy noise"
    paper = "a toy method of tests/test_methods.py"
    option_help = "toy, uniform noise with a level (tests only)"
    step_cost = 1.5
    training = UniformNoiseWithALevel

    @dataclass(frozen=True)
    class Settings:
        toy_width: float = setting(0.3, "the toy's noise width, relative to the action half-range",
                                   bounds="positive")


@pytest.fixture
def toy():
    with methods.while_registered(ToyNoise) as name:
        yield name


def toy_training(**options):
    """The small runs' training settings (:func:`test_training.tiny_training`) with the toy's exploration."""
    from test_training import tiny_training

    return tiny_training(exploration="toy", **options)


def test_registering_makes_the_name_a_setting_and_a_method(toy):
    training = training_config_class()(exploration="toy")
    assert methods.relative_cost(training) == 1.5 and training.toy_width == 0.3
    assert ToyNoise.cost_note == "1.5", "the phrase of reproduce --list comes from the declared step cost"
    check_settings(training)  # a valid choice now
    with pytest.raises(UserError, match="--exploration 'toys' is not one of: gaussian, noisy, toy"):
        check_settings(training_config_class()(exploration="toys"))
    with pytest.raises(UserError, match="--toy-width must be a positive number"):
        check_settings(training_config_class()(exploration="toy", toy_width=0.0))
    with pytest.raises(ValueError, match="needs the paper"):
        methods.register(type("Nameless", (ToyNoise,), {"name": "nameless", "paper": ""}))
    with pytest.raises(ValueError, match="toy_width are another method's"):
        methods.register(type("Twin", (ToyNoise,), {"name": "twin"}))


def test_unregistering_gives_back_the_same_settings_class():
    plain = training_config_class()
    with pytest.raises(RuntimeError), methods.while_registered(ToyNoise):
        assert training_config_class() is not plain and "toy_width" not in {f.name for f in dataclasses.fields(plain)}
        raise RuntimeError("the block fails: the toy is unregistered all the same")
    assert training_config_class() is plain and "toy" not in methods.registered("exploration")


def test_a_registered_method_is_a_flag_a_grid_key_an_identity_and_a_cost(toy, tmp_path, monkeypatch):
    """One declaration and one registration, and every part of the package that lists methods lists it."""
    from ilcsan.analysis.collect import configuration_key
    from ilcsan.cli import build_parser
    from ilcsan.cli.train import build_run_config
    from ilcsan.experiments.estimate import list_tables, method_step_cost
    from ilcsan.experiments.grid_files import load_grid
    from ilcsan.paper.layouts import TABLES

    monkeypatch.setenv("COLUMNS", "1000")
    parser = build_parser()
    train_help = parser._subparsers._group_actions[0].choices["train"].format_help()
    assert "--toy-width TOY_WIDTH" in train_help and "the toy's noise width" in train_help
    assert "toy, uniform noise with a level (tests only)" in train_help  # among --exploration's choices
    config = build_run_config(parser.parse_args(["train", "--exploration", "toy", "--toy-width", "0.2"]))
    assert (config.training.exploration, config.training.toy_width) == ("toy", 0.2)

    grid = tmp_path / "toy.toml"
    grid.write_text('name = "toys"\ntasks = ["Pendulum-v1"]\n[[rows]]\nslug = "toy"\npreset = "ilc-san"\n'
                    'training = { exploration = "toy", toy_width = 0.2 }\n')
    row = load_grid(grid).rows[0]
    assert row.training == {"exploration": "toy", "toy_width": 0.2} and method_step_cost(row) == 1.5

    actor = actor_config("ilc-san").to_dict()
    narrow = configuration_key(actor, {"exploration": "toy", "toy_width": 0.2})
    assert '"toy_width": 0.2' in narrow and narrow != configuration_key(actor, {"exploration": "toy"})
    assert configuration_key(actor, {"exploration": "toy"}) == configuration_key(
        actor, {"exploration": "toy", "toy_width": 0.3})  # a config saved without it: its default

    assert "the toy noise 1.5" in list_tables([TABLES["layer"]], 100.0, 2).split("\n\n")[-1]


def test_a_registered_method_trains_checkpoints_and_resumes_exactly(toy, tmp_path, monkeypatch):
    from test_training import assert_resumes_to_the_same_curve, tiny_run

    config = tiny_run(seeds=(0, 1), steps=450, training=toy_training())
    checkpoints = assert_resumes_to_the_same_curve(config, tmp_path, monkeypatch)
    for straight, resumed in checkpoints:
        level = float(straight["exploration"]["level"][0])
        assert 0.0 < level < 1.0, "its loss term moved its parameter toward 1, one Adam step per actor update"
        assert float(straight["exploration"]["adam"]["level"]["step"]) == straight["updates"] // 2
        assert torch.equal(straight["exploration"]["level"], resumed["exploration"]["level"])


def test_its_loss_term_runs_inside_the_compiled_update_as_it_does_uncompiled(toy):
    from test_training import _random_batch, assert_same_updates

    config = actor_config("ilc-san", hidden=(16,), population_in=4, population_out=4, timesteps=3)
    training = training_config_class()(exploration="toy", critic_hidden=(16, 16))
    task = TaskSpace(3, 2, [1.0, 1.0], [0.0, 0.0])
    eager = TD3(config, training, task, (7, 8))
    compiled = TD3(config, training, task, (7, 8), ComputeSettings(compile=True))
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
    config = tiny_run(steps=200, eval_every=200, training=toy_training(start_steps=150))
    train(config, tmp_path / "run", progress=False, log=lambda *_: None)
    assert len(calls) == 200 - 150  # every step after the random phase explores through the method


def test_td3s_own_methods_live_beside_td3():
    """The paper's exploration and target actor are TD3's hooks in :mod:`ilcsan.rl.algorithms.td3`."""
    from ilcsan.rl.algorithms import td3

    assert methods.declared("exploration", "gaussian").training_class() is td3.GaussianActionNoise
    assert methods.declared("target_actor", "polyak").training_class() is td3.PolyakTarget


def test_settings_made_before_a_method_was_registered_still_resume_the_run():
    """Registering a method makes a new training settings class (its fields join); a configuration made before it
    has the old class. The resume check compares values, so the same settings still match, and a changed one
    does not."""
    from ilcsan.config import RunConfig
    from ilcsan.runs.checkpoint import differing_settings

    before = RunConfig(task="Pendulum-v1", training=training_config_class()(start_steps=500))
    with methods.while_registered(ToyNoise):
        saved = RunConfig.from_dict(before.for_seed(0))  # its config.json, read now that the toy is registered
        assert type(saved.training) is not type(before.training) and saved.training.start_steps == 500
        assert differing_settings(saved, before) == []
        other = RunConfig.from_dict({**before.for_seed(0), "training": {"start_steps": 600}})
        assert differing_settings(other, before) == ["training"]
        toy = dataclasses.replace(saved, training=dataclasses.replace(saved.training, exploration="toy"))
        assert differing_settings(toy, before) == ["training"]


def test_a_run_of_a_method_read_where_it_is_not_registered_is_one_clear_error(tmp_path, capsys):
    """config.json of a run made with a user's own method holds that method's settings; read where the method is
    not registered, the run configuration is refused by a UserError that says what to do (not a TypeError), and
    `train --like` of it exits 2 with that one line."""
    from ilcsan.cli import main
    from ilcsan.config import RunConfig

    with methods.while_registered(ToyNoise):
        recorded = RunConfig(task="Pendulum-v1", training=training_config_class()(exploration="toy")).for_seed(0)
        assert RunConfig.from_dict(recorded).training.exploration == "toy"
    with pytest.raises(UserError, match=r"training settings toy_width belong to no registered method: register"):
        RunConfig.from_dict(recorded)
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "config.json").write_text(json.dumps(recorded))
    code = main(["train", "--like", str(tmp_path / "run"), "--out", str(tmp_path / "new")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "toy_width belong to no registered method" in err
