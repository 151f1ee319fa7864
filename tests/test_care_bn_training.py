"""CaRe-BN's training (:mod:`ilcsan.rl.methods.care_bn`): batch statistics in the actor's loss, the Kalman update
after each actor step, the target actor following the running statistics, the recalibration, compiled = eager,
resuming, the deployed policy and its exports."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_care_bn import SPIKING_PRESETS, randomise_running_statistics

import ilcsan.rl.methods.care_bn as care_bn
from ilcsan.config import RunConfig, TrainingConfig, actor_config
from ilcsan.deploy import DeployedActor
from ilcsan.deploy.bundle import bundle_arrays, bundle_meta
from ilcsan.deploy.policy import load
from ilcsan.errors import UserError
from ilcsan.rl.agent_settings import ComputeSettings, TaskSpace
from ilcsan.rl.algorithms import DDPG, SAC, TD3
from ilcsan.rl.methods.care_bn import kalman_update
from ilcsan.rl.training import Trainer
from ilcsan.rl.validation import validate_run
from ilcsan.runs.checkpoint import first_readout, module_state
from ilcsan.snn.output import PassOptions

SMALL = dict(hidden=(16,), population_in=4, population_out=4, timesteps=3)
CRITIC = TrainingConfig(critic_hidden=(16, 16))


def _agent(cls=TD3, preset="ilc-san", seeds=(0, 1), training=CRITIC, **options):
    config = actor_config(preset, normalization="care-bn", **SMALL)
    return cls(config, training, TaskSpace(3, 2, [1.0, 2.0], [0.0, 0.5]), seeds, ComputeSettings(**options))


def _batch(agent, size: int = 16, seed: int = 0) -> dict[str, torch.Tensor]:
    rng, k = np.random.default_rng(seed), len(agent.seeds)
    arrays = {"obs": rng.normal(size=(k, size, 3)), "action": rng.uniform(-1, 1, (k, size, 2)),
              "reward": rng.normal(size=(k, size)), "next_obs": rng.normal(size=(k, size, 3)),
              "terminal": rng.uniform(size=(k, size)) < 0.1}
    return agent.to_batch({name: value.astype(np.float32) for name, value in arrays.items()})


def _running(actor) -> list[torch.Tensor]:
    """Every layer's μ̂, σ̂², P_μ, P_σ², copied."""
    return [tensor.clone() for norm in actor.norms for tensor in norm.running_state()]


# ----------------------------------------------------------------------------------------- the update
def test_the_actor_loss_normalises_with_the_batch_statistics():
    """The loss's gradient is that of −Q_1(s, π(s)) with π normalising by the minibatch's statistics (gradients
    through them), not by the running ones (made far from the batch's here)."""
    agent = _agent()
    randomise_running_statistics(agent.actor)
    batch = _batch(agent)

    def actor_gradients(loss: torch.Tensor) -> list[torch.Tensor]:
        agent.actor.zero_grad()
        loss.backward()
        return [parameter.grad.clone() for parameter in agent.actor.parameters()]

    def minus_q(action: torch.Tensor) -> torch.Tensor:
        return -agent.critic(batch["obs"], action, first_only=True).mean(dim=-1).sum()

    ours = actor_gradients(agent.actor_loss(batch))
    with_batch = actor_gradients(minus_q(agent.actor(batch["obs"], options=PassOptions(statistics="batch"))))
    with_running = actor_gradients(minus_q(agent.actor(batch["obs"])))
    for mine, theirs in zip(ours, with_batch, strict=True):
        torch.testing.assert_close(mine, theirs)
    difference = max(float((mine - theirs).abs().max()) for mine, theirs in zip(ours, with_running, strict=True))
    assert difference > 1e-2 * max(float(grad.abs().max()) for grad in ours)


STEP_CASES = ([(TD3, preset, "fast") for preset in SPIKING_PRESETS]
              + [(TD3, "ilc-san", "reference"), (DDPG, "ilc-san", "fast"), (SAC, "ilc-san", "fast"),
                 (SAC, "popsan", "reference")])


@pytest.mark.parametrize("cls, preset, engine", STEP_CASES,
                         ids=[f"{cls.__name__}-{preset}-{engine}" for cls, preset, engine in STEP_CASES])
def test_an_actor_step_moves_the_running_statistics_by_the_kalman_update_of_its_pass(cls, preset, engine):
    """Critic-only updates leave the statistics alone; the actor step moves them by
    :func:`~ilcsan.rl.methods.care_bn.kalman_update` toward the batch statistics of its loss pass (the actor's
    before the step, on the minibatch's B = 16 states). The normalised layers' biases, cancelled by the batch mean,
    stay exactly; the weights move."""
    agent = _agent(cls, preset, engine=engine)
    randomise_running_statistics(agent.actor)
    batch = _batch(agent)
    before = _running(agent.actor)
    for _ in range(cls.policy_delay(agent.training) - 1):
        assert agent.update(batch)["actor_loss"] is None
    assert all(torch.equal(now, then) for now, then in zip(_running(agent.actor), before, strict=True))
    with torch.no_grad():
        statistics = agent.actor.run(batch["obs"], options=PassOptions(statistics="batch")).norm_statistics
    expected = [value for norm, layer in zip(agent.actor.norms, statistics, strict=True)
                for value in kalman_update(norm.running_state(), layer, samples=16)]
    biases = [layer.bias.clone() for layer in agent.actor.layers]
    weights = [layer.weight.clone() for layer in agent.actor.layers]
    assert agent.update(batch)["actor_loss"] is not None
    for now, want, then in zip(_running(agent.actor), expected, before, strict=True):
        torch.testing.assert_close(now, want, rtol=1e-5, atol=1e-6)
        assert not torch.equal(now, then)
    for layer, bias, weight in zip(agent.actor.layers, biases, weights, strict=True):
        assert torch.equal(layer.bias, bias) and not torch.equal(layer.weight, weight)


@pytest.mark.parametrize("cls", [TD3, DDPG])
def test_the_target_actor_follows_the_running_statistics_at_its_steps(cls):
    """b' ← b' + τ (b − b') for μ̂ and σ̂², with b the online actor's after its Kalman update, at every actor step
    (TD3: the second update; DDPG: each); P_μ, P_σ² of the target are never read and stay."""
    agent = _agent(cls, training=TrainingConfig(critic_hidden=(16, 16), tau=0.25))
    randomise_running_statistics(agent.actor)
    batch = _batch(agent)
    target_before = _running(agent.actor_target)
    if cls is TD3:
        agent.update(batch)
        assert all(torch.equal(now, then) for now, then in zip(_running(agent.actor_target), target_before,
                                                                strict=True))
    agent.update(batch)
    online = _running(agent.actor)
    for index, (now, then) in enumerate(zip(_running(agent.actor_target), target_before, strict=True)):
        if index % 4 < 2:  # μ̂, σ̂²
            torch.testing.assert_close(now, then + 0.25 * (online[index] - then), rtol=1e-6, atol=1e-7)
            assert not torch.equal(now, then)
        else:
            assert torch.equal(now, then)


@pytest.mark.parametrize("cls", [TD3, SAC])
def test_the_compiled_update_equals_the_eager_one(cls):
    """Over 6 updates (TD3: 3 actor steps) the compiled program leaves the same parameters and buffers (the
    Kalman update and the target's Polyak average run in place inside it) as the eager update."""
    eager, compiled = _agent(cls, seeds=(7, 8)), _agent(cls, seeds=(7, 8), compile=True)
    for step in range(6):
        losses = [agent.update(_batch(agent, seed=step)) for agent in (eager, compiled)]
        for key in ("critic_loss", "actor_loss"):
            if losses[0][key] is not None:
                assert float(losses[1][key]) == pytest.approx(float(losses[0][key]), rel=1e-4, abs=1e-5)
    networks = ("actor", "critic", "critic_target") + (("actor_target",) if cls is TD3 else ())
    for network in networks:
        theirs = module_state(getattr(compiled, network))
        for name, ours in module_state(getattr(eager, network)).items():
            torch.testing.assert_close(theirs[name], ours, rtol=1e-4, atol=2e-5, msg=f"{network}.{name}")
    assert not torch.equal(eager.actor.norms[0].running_mean, torch.zeros_like(eager.actor.norms[0].running_mean))
    programs = (compiled.update_step,) if cls is SAC else (compiled.critic_step, compiled.delayed_step)
    assert all(program.direct for program in programs)


@pytest.mark.parametrize("training", [
    TrainingConfig(critic_hidden=(16, 16), exploration="noisy", noisy_return_reference=100.0),
    TrainingConfig(critic_hidden=(16, 16), target_actor="proxy", proxy_iterations=1)],
                         ids=["noisysan", "proxy-target"])
def test_care_bn_trains_beside_noisysan_and_proxy_target(training):
    """NoisySAN's noise enters after the normalisation and its loss pass records batch statistics; Proxy Target's
    proxy imitates the actor as it acts: both run, and the actor step moves the running statistics."""
    agent = _agent(TD3, training=training)
    before = _running(agent.actor)
    rng = np.random.default_rng(0)
    for seed in range(2):
        batch = _batch(agent, seed=seed)
        if training.target_actor == "proxy":
            batch["proxy_obs"] = torch.as_tensor(rng.normal(size=(1, 2, 16, 3)), dtype=torch.float32)
        agent.update(batch)
    assert not any(torch.equal(now, then) for now, then in zip(_running(agent.actor), before, strict=True))
    action = agent.explore(np.zeros((2, 3), np.float32), [np.random.default_rng(seed) for seed in (0, 1)])
    assert action.shape == (2, 2) and np.all(np.isfinite(action))


# --------------------------------------------------------------------------------------- runs
def _run(algorithm: str = "td3", steps: int = 450, **training_options) -> RunConfig:
    training = TrainingConfig(**{**dict(start_steps=150, update_after=100, update_every=25, batch_size=16,
                              critic_hidden=(16, 16)), **training_options})
    return RunConfig(task="Pendulum-v1", seeds=(0, 1), steps=steps, eval_every=150, eval_episodes=1,
                     actor=actor_config("ilc-san", normalization="care-bn", hidden=(16, 16)), algorithm=algorithm,
                     training=training, threads=1, compile="off")


@pytest.fixture
def often(monkeypatch):
    """Recalibrate every 100 steps from 3 batches of 8 states."""
    monkeypatch.setattr(care_bn, "RECALIBRATION_INTERVAL", 100)
    monkeypatch.setattr(care_bn, "RECALIBRATION_BATCHES", 3)
    monkeypatch.setattr(care_bn, "RECALIBRATION_BATCH_SIZE", 8)


def _stepped(config: RunConfig, out, steps: int) -> Trainer:
    trainer = Trainer(config, out, progress=False, log=lambda *_: None)
    while trainer.step < steps:
        trainer.train_step()
    return trainer


def test_recalibration_sets_the_pooled_statistics_and_leaves_the_random_streams(often, tmp_path, monkeypatch):
    """At step 100 (no update yet) the running statistics become, layer by layer, the statistics of one pass over the
    3·8 replayed states the recalibration's own generators draw ([8, seed, 100]), normalised, the layers before
    normalised with theirs. A run that never recalibrates has the same generators, replay and normaliser after it."""
    config = _run(update_after=1000, start_steps=1000)
    trainer = _stepped(config, tmp_path / "recalibrated", 100)
    try:
        monkeypatch.setattr(care_bn, "RECALIBRATION_INTERVAL", 0)
        plain = _stepped(config, tmp_path / "plain", 100)
        try:
            _check_recalibration(trainer, plain, config.seeds)
        finally:
            plain.close()  # the process settings go back in the reverse order they were taken
    finally:
        trainer.close()


def _check_recalibration(trainer: Trainer, plain: Trainer, seeds) -> None:
    generators = [np.random.default_rng([8, seed, 100]) for seed in seeds]
    states = np.concatenate([trainer.normalizer.normalize(trainer.replay.sample_states(generators, 8))
                             for _ in range(3)], axis=1)
    together, found = torch.as_tensor(states), []
    for index, norm in enumerate(trainer.agent.actor.norms):
        with torch.no_grad():
            pass_options = PassOptions(statistics=tuple(found))
            found.append(trainer.agent.actor.run(together, options=pass_options).norm_statistics[index])
        torch.testing.assert_close(norm.running_mean, found[-1].mean, rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(norm.running_var, found[-1].var, rtol=1e-5, atol=1e-6)
        assert not torch.equal(norm.running_mean, plain.agent.actor.norms[index].running_mean)
    for ours, theirs in zip(trainer.rngs, plain.rngs, strict=True):
        assert ours.bit_generator.state == theirs.bit_generator.state
    for ours, theirs in zip(trainer.agent.noise_generators, plain.agent.noise_generators, strict=True):
        assert torch.equal(ours.get_state(), theirs.get_state())
    assert np.array_equal(trainer.replay.data["obs"], plain.replay.data["obs"])
    assert np.array_equal(trainer.normalizer.mean, plain.normalizer.mean)
    assert np.array_equal(trainer.environments.observations, plain.environments.observations)


@pytest.mark.parametrize("algorithm", ["td3", "sac"])
def test_an_interrupted_run_resumes_to_the_same_metrics(often, tmp_path, monkeypatch, algorithm):
    """Two seeds, 450 steps, recalibrations at 100, 200, 300 and 400, interrupted after the first checkpoint (step
    150): every row of metrics.csv but the timings is the same."""
    from test_training import interrupt_after_first_checkpoint, on_the_path_of, read_metrics

    config = _run(algorithm)
    interrupt_after_first_checkpoint(config, tmp_path / "cut", monkeypatch)
    Trainer(config, tmp_path / "cut", resume=True, progress=False, log=lambda *_: None).train()
    Trainer(on_the_path_of(config, tmp_path / "cut" / "seed0"), tmp_path / "straight", progress=False,
            log=lambda *_: None).train()
    for seed in ("seed0", "seed1"):
        straight, resumed = (read_metrics(tmp_path / run / seed / "metrics.csv") for run in ("straight", "cut"))
        keep = [key for key in straight[0] if key not in ("wall_seconds", "steps_per_second")]
        assert len(straight) == 3
        assert [[row[key] for key in keep] for row in straight] == [[row[key] for key in keep] for row in resumed]


@pytest.mark.parametrize("algorithm", ["td3", "sac"])
def test_the_policy_acts_as_the_trained_actor_and_every_export_as_the_policy(often, tmp_path, algorithm):
    """After 250 steps (recalibrated at 100 and 200, Kalman-updated since 100) policy.pt holds the deployed actor's
    parameters and running statistics (SAC: the mean's populations) and predicts as the agent acts, as checkpoint.pt
    read as a policy does; the npz bundle
    (the additions-only numpy runtime) and the NIR graph, with the normalisation folded into the weights, act as
    predict."""
    trainer = _stepped(_run(algorithm), tmp_path / "run", 250)
    try:
        trainer.checkpoints.save_policy(0, trainer.policy_state(0), trainer.step)
        trainer.checkpoints.save(trainer)
        policy = load(tmp_path / "run" / "seed0" / "policy.pt")
        deployed = trainer.agent.deployable_actor()
        expected_state = first_readout({name: tensor[:1] for name, tensor in module_state(trainer.agent.actor).items()},
                                       policy.actor)
        for name, tensor in module_state(policy.actor).items():
            assert torch.equal(tensor, expected_state[name]), name
        assert any(name.startswith("norms.") for name in module_state(deployed))
        normalizer = trainer.normalizer
        raw = normalizer.mean[0] + normalizer.std[0] * np.random.default_rng(5).normal(0.0, 1.5, (12, 3))
        acting = trainer.agent.act(normalizer.normalize(np.stack([raw, raw])))[0]
    finally:
        trainer.close()
    predicted = policy.predict(raw)
    np.testing.assert_allclose(predicted, acting, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(load(tmp_path / "run" / "seed0" / "checkpoint.pt").predict(raw), predicted)
    arrays, meta = bundle_arrays(policy), bundle_meta(policy)
    assert meta["normalization"] == "none" and not any(name.startswith("norms.") for name in arrays)
    runtime = DeployedActor.from_arrays(arrays, meta)
    assert np.abs(runtime.act(raw) - predicted).max() < 1e-5
    nir = pytest.importorskip("nir")
    from ilcsan.deploy.nir import export_nir, nir_action

    graph = nir.read(export_nir(policy, tmp_path / "actor.nir", target="portable"))
    nir_actions = np.stack([nir_action(graph, observation) for observation in raw])
    assert np.abs(nir_actions - predicted).max() < 1e-5
    with torch.no_grad():  # the running statistics matter: the initial ones act otherwise
        for norm in policy.actor.norms:
            norm.running_mean.zero_()
            norm.running_var.fill_(1.0)
    assert np.abs(policy.predict(raw) - predicted).max() > 1e-3


# ---------------------------------------------------------------------------------------- settings
@pytest.mark.parametrize("algorithm", ["td3", "ddpg", "sac"])
def test_every_algorithm_trains_care_bn_and_a_batch_of_one_state_is_refused_in_one_line(algorithm):
    validate_run(_run(algorithm))
    with pytest.raises(UserError, match="--batch-size must be at least 2") as caught:
        validate_run(_run(algorithm, batch_size=1))
    assert "\n" not in str(caught.value)
