"""All of a module's state in its files: parameters and persistent buffers in checkpoints and policy.pt, per seed;
the constants (action bounds, intra-layer masks) in none; exports that fold a buffer or refuse it.

No actor keeps a persistent buffer yet, so :class:`RunningMeanActor` adds one, as batch-normalisation statistics
will: the running mean of the observations the actor sees, updated whenever it runs in training mode, subtracted
from its input."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
from spiking_policies import observations, random_policy

import ilcsan.actors
from ilcsan.actors import build_actor
from ilcsan.cli import main
from ilcsan.compute.programs import module_tensors
from ilcsan.config import ActorConfig, TrainingConfig, actor_config
from ilcsan.deploy import DeployedActor
from ilcsan.deploy.bundle import bundle_arrays, bundle_meta, export_npz
from ilcsan.deploy.policy import load
from ilcsan.errors import UserError
from ilcsan.rl.agent_settings import TaskSpace
from ilcsan.rl.algorithms import TD3
from ilcsan.runs.checkpoint import load_state, module_state, slice_state
from ilcsan.snn.actor import SpikingActor
from ilcsan.snn.output import PLAIN_PASS, PassOptions


class RunningMeanActor(SpikingActor):
    """The spiking actor with ``running_mean`` (K, N), a per-seed persistent buffer: the exponential average of
    the observations it ran on in training mode, subtracted from each observation before the encoder."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.register_buffer("running_mean", torch.zeros(self.layers[0].weight.shape[0], self.state_dim))

    def forward(self, state: torch.Tensor, options: PassOptions = PLAIN_PASS):
        if self.training:
            with torch.no_grad():
                self.running_mean.lerp_(state.mean(dim=1), 0.25)
        return super().forward(state - self.running_mean.unsqueeze(1), options)


@pytest.fixture
def running_mean_actors(monkeypatch):
    """Every spiking actor ``build_actor`` builds (in the agent, in a loaded policy) is a :class:`RunningMeanActor`."""
    monkeypatch.setattr(ilcsan.actors, "SpikingActor", RunningMeanActor)


def _agent(seeds) -> TD3:
    return TD3(actor_config("ilc-san", hidden=(8, 8)), TrainingConfig(), TaskSpace(3, 2, [1.0, 1.0], [0.0, 0.0]), seeds)


def _train_once(agent: TD3) -> None:
    """Two updates on a batch whose observations differ per seed (their means too)."""
    rng = np.random.default_rng(0)
    k = len(agent.seeds)
    shift = np.arange(k, dtype=float)[:, None, None]
    arrays = {"obs": rng.normal(size=(k, 8, 3)) + shift, "action": rng.uniform(-1, 1, (k, 8, 2)),
              "reward": rng.normal(size=(k, 8)), "next_obs": rng.normal(size=(k, 8, 3)) - shift,
              "terminal": np.zeros((k, 8))}
    for _ in range(2):
        agent.update(agent.to_batch({name: value.astype(np.float32) for name, value in arrays.items()}))


# ------------------------------------------------------------------------------------- the convention
@pytest.mark.parametrize("preset, overrides", [("ilc-san", {}), ("ilc-san", {"intra": "self+bias"}),
                                               ("popsan", {}), ("mdc-san", {}), ("dan", {})])
def test_todays_actors_keep_their_parameters_and_rebuild_their_constants(preset, overrides):
    actor = build_actor(actor_config(preset, **overrides), 3, 2, [2.0, 1.0], [0.0, 0.5], seeds=(0, 1))
    assert list(module_state(actor)) == [name for name, _ in actor.named_parameters()]
    constants = {name: buffer for name, buffer in actor.named_buffers()}
    assert "action_scale" in constants and ("intra.weight_mask" in constants) == (getattr(actor, "intra", None)
                                                                                  is not None)
    copied = copy.deepcopy(actor).to("cpu")  # the target actor; the device the agent runs on
    for name, buffer in copied.named_buffers():
        assert torch.equal(buffer, constants[name]) and buffer is not constants[name], name
    held = {id(tensor) for tensor in module_tensors(actor)}  # what a compiled program reads as constants
    assert all(id(buffer) in held for buffer in constants.values())


def test_a_persistent_buffer_without_the_ensemble_dimension_is_a_bug_said_at_once():
    actor = build_actor(actor_config("ilc-san", hidden=(8,)), 3, 2, [1.0, 1.0], seeds=(0, 1))
    actor.register_buffer("updates", torch.tensor(0))
    with pytest.raises(ValueError, match="ensemble dimension"):
        slice_state(actor, 0, 1)


# ------------------------------------------------------------------------------------------ checkpoints
def test_running_statistics_survive_a_two_seed_checkpoint_per_seed_in_order(running_mean_actors, tmp_path):
    trained = _agent((0, 1))
    _train_once(trained)
    means = trained.actor.running_mean.clone()
    assert isinstance(trained.actor, RunningMeanActor) and not torch.equal(means[0], means[1])
    assert means.abs().min() > 0 and not torch.equal(trained.actor_target.running_mean, means)
    for index in (0, 1):
        torch.save(trained.seed_state(index), tmp_path / f"seed{index}.pt")
    states = [torch.load(tmp_path / f"seed{index}.pt", weights_only=True) for index in (0, 1)]
    assert torch.equal(states[1]["actor"]["running_mean"], means[1:2])
    resumed = _agent((0, 1))
    resumed.load_seed_states(states)
    for key in ("actor", "actor_target"):
        for name, tensor in module_state(getattr(trained, key)).items():
            assert torch.equal(module_state(getattr(resumed, key))[name], tensor), (key, name)
    swapped = _agent((1, 0))
    swapped.load_seed_states(states[::-1])
    assert torch.equal(swapped.actor.running_mean, means.flip(0))
    observation = np.zeros((2, 3), np.float32)
    np.testing.assert_array_equal(resumed.act(observation), trained.act(observation))


def test_a_checkpoint_without_a_buffer_the_actor_keeps_is_one_user_error(running_mean_actors):
    trained = _agent((0,))
    states = [trained.seed_state(0)]
    states[0]["actor"].pop("running_mean")
    with pytest.raises(UserError, match="actor in the checkpoint has no 'running_mean', a persistent buffer") as caught:
        _agent((0,)).load_seed_states(states)
    assert "\n" not in str(caught.value)
    states[0]["actor"]["running_mean"] = torch.zeros(1, 4)
    with pytest.raises(UserError, match="'running_mean' has shape"):
        _agent((0,)).load_seed_states(states)


def test_checkpoint_slices_of_parameters_alone_still_load_into_todays_actors():
    trained = _agent((0, 1))
    _train_once(trained)
    old = [{name: p.detach()[index:index + 1].clone() for name, p in trained.actor.named_parameters()}
           for index in (0, 1)]  # what checkpoints held before buffers were saved
    actor = _agent((0, 1)).actor
    load_state(actor, old, "actor")
    for (name, mine), (_, theirs) in zip(actor.named_parameters(), trained.actor.named_parameters(), strict=True):
        assert torch.equal(mine, theirs), name


# ------------------------------------------------------------------------------------------- policies
def _with_actor(data: dict, actor: torch.nn.Module, index: int) -> dict:
    return {**data, "actor": slice_state(actor, index, 1)}


def test_running_statistics_survive_policy_pt_and_checkpoint_pt(running_mean_actors, trained_run, tmp_path):
    policy_file = torch.load(trained_run / "policy.pt", weights_only=True)
    checkpoint_file = torch.load(trained_run / "checkpoint.pt", weights_only=True)
    config = ActorConfig.from_dict(policy_file["actor_config"])
    actor = build_actor(config, 3, 1, [2.0], seeds=(0, 1))
    actor(torch.as_tensor(np.random.default_rng(2).normal(size=(2, 5, 3)), dtype=torch.float32))
    assert isinstance(actor, RunningMeanActor) and actor.running_mean.abs().min() > 0
    actor.eval()
    for name, data in (("policy.pt", policy_file), ("checkpoint.pt", checkpoint_file)):
        torch.save(_with_actor(data, actor, 1), tmp_path / name)
        policy = load(tmp_path / name)
        assert torch.equal(policy.actor.running_mean, actor.running_mean[1:2]), name
        batch = np.random.default_rng(3).normal(size=(4, 3))
        state = torch.as_tensor(policy.normalize(batch)).unsqueeze(0)
        with torch.no_grad():
            expected = actor(state.expand(2, -1, -1))[1].numpy()
        np.testing.assert_array_equal(policy.predict(batch), expected)


def test_a_policy_without_a_buffer_the_actor_keeps_is_one_user_error(running_mean_actors, trained_run):
    with pytest.raises(UserError, match="policy.pt has no 'running_mean', a persistent buffer") as caught:
        load(trained_run / "policy.pt")
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("damage, fragment", [(lambda mean: mean[:, :2], "has shape"),
                                              (lambda mean: mean.fill_(float("nan")), "NaN or inf")])
def test_a_damaged_buffer_in_a_policy_is_refused(running_mean_actors, trained_run, tmp_path, damage, fragment):
    data = torch.load(trained_run / "policy.pt", weights_only=True)
    actor = build_actor(ActorConfig.from_dict(data["actor_config"]), 3, 1, [2.0], seeds=(0,))
    data = _with_actor(data, actor, 0)
    data["actor"]["running_mean"] = damage(data["actor"]["running_mean"])
    torch.save(data, tmp_path / "policy.pt")
    with pytest.raises(UserError, match=f"'running_mean'.*{fragment}"):
        load(tmp_path / "policy.pt")


def test_todays_files_hold_the_parameters_alone_and_load(trained_run):
    policy = load(trained_run)
    names = [name for name, _ in policy.actor.named_parameters()]
    for file in ("policy.pt", "checkpoint.pt"):
        assert list(torch.load(trained_run / file, weights_only=True)["actor"]) == names, file
        load(trained_run / file).predict(np.zeros(3))


# -------------------------------------------------------------------------------------------- exports
def _running_mean_policy():
    """A random fully spiking policy whose actor keeps running means away from zero, in multiples of 1/4."""
    policy = random_policy("ilc-san", state_dim=3, hidden=(16, 16))
    with torch.no_grad():
        policy.actor.running_mean.copy_(torch.tensor([[0.5, -0.25, 0.75]]))
    return policy


def test_every_export_refuses_a_buffer_it_cannot_fold(running_mean_actors, tmp_path):
    policy = _running_mean_policy()
    with pytest.raises(UserError, match="keeps 'running_mean', a persistent buffer that no export knows"):
        bundle_arrays(policy)
    for weights in ("float32", "int8"):  # the Lava network is built from this bundle
        with pytest.raises(UserError, match="running_mean"):
            export_npz(policy, tmp_path / "actor.npz", weights)
    assert not list(tmp_path.iterdir())
    pytest.importorskip("nir")
    from ilcsan.deploy.nir import build_graph

    for target in ("portable", "generic", "sinabs"):
        with pytest.raises(UserError, match="running_mean"):
            build_graph(policy, target)


def test_export_refuses_a_buffer_from_the_command_line_in_one_line(running_mean_actors, trained_run, tmp_path,
                                                                   capsys):
    data = torch.load(trained_run / "policy.pt", weights_only=True)
    actor = build_actor(ActorConfig.from_dict(data["actor_config"]), 3, 1, [2.0], seeds=(0,))
    torch.save(_with_actor(data, actor, 0), tmp_path / "policy.pt")
    assert main(["export", str(tmp_path / "policy.pt"), "--format", "npz"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "running_mean" in lines[0], lines
    assert not (tmp_path / "actor.npz").exists()


def test_a_fold_declared_by_the_module_that_keeps_a_buffer_makes_the_export_act_as_predict(running_mean_actors,
                                                                                           monkeypatch):
    def fold_into_receptive_fields(self, folded, prefix):
        """s − m − μ = s − (μ + m): the running mean moves the Gaussian receptive fields' centres."""
        mean = folded.pop("running_mean")
        return {**folded, "encoder.mu": folded["encoder.mu"] + mean[:, None]}

    monkeypatch.setattr(RunningMeanActor, "export_fold", fold_into_receptive_fields, raising=False)
    policy = _running_mean_policy()
    arrays = bundle_arrays(policy)
    assert "running_mean" not in arrays
    batch = observations(policy, 12)
    runtime = DeployedActor.from_arrays(arrays, bundle_meta(policy))
    expected = policy.predict(batch)
    assert np.abs(runtime.act(batch) - expected).max() < 1e-4
    with torch.no_grad():
        policy.actor.running_mean.zero_()
    assert np.abs(policy.predict(batch) - expected).max() > 1e-2, "the running mean changes the actions"
