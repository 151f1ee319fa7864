"""NoisySAN exploration (Chen et al. 2024): the noise enters the neurons where the paper puts it, has the
documented time correlation, is off at evaluation, carries the noise penalty, compiles, stacks and resumes."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from ilcsan.actors import build_actor
from ilcsan.config import RunConfig, TrainingConfig, actor_config
from ilcsan.errors import UserError
from ilcsan.rl.agent_settings import ComputeSettings, TaskSpace
from ilcsan.rl.algorithms import TD3
from ilcsan.rl.methods.coloured_noise import autocorrelation, fft_length, window_covariance
from ilcsan.rl.training import train
from ilcsan.snn.noise import NeuronNoise
from ilcsan.snn.output import PassOptions

SMALL_ACTOR = actor_config("ilc-san", hidden=(16, 16))
NOISY = TrainingConfig(exploration="noisy", noisy_return_reference=100.0)


def _agent(training: TrainingConfig = NOISY, seeds=(0,), actor=SMALL_ACTOR, **options) -> TD3:
    return TD3(actor, training, TaskSpace(3, 2, [2.0, 1.0], [0.0, 0.5], episode_steps=50), seeds,
               ComputeSettings(**options))


def _random_noise(actor, batch: int, seed: int, scale: float = 0.3) -> NeuronNoise:
    generator = torch.Generator().manual_seed(seed)
    k, t = 1, actor.config.timesteps

    def draw(width):
        return scale * torch.randn(k, t, batch, width, generator=generator)

    widths = actor.noise_widths()
    return NeuronNoise(tuple(draw(w) for w in widths), tuple(draw(w) for w in widths), draw(actor.action_dim))


@pytest.mark.parametrize("preset", ["ilc-san", "popsan", "mdc-san"])
def test_the_layer_major_pass_adds_the_noise_where_algorithm_1_would(preset):
    """Fast engine = the literal time loop with the same noise (values and gradients), for the LI decoder with
    intra-layer connections, PopSAN's firing-rate decoder, and MDC-SAN's dynamic neuron with an analog encoder."""
    actor = build_actor(actor_config(preset, hidden=(12, 10)), 4, 2, [1.0, 1.0], seeds=(3,))
    state = torch.randn(1, 5, 4, generator=torch.Generator().manual_seed(0))
    noise = _random_noise(actor, 5, 1)
    leaves = [tensor.requires_grad_() for tensor in (*noise.charge, *noise.transmission, noise.decoder)]
    fast = actor.run(state, options=PassOptions(noise=noise)).action
    grads_fast = torch.autograd.grad(fast.sum(), leaves)
    slow = actor.run(state, engine="reference", options=PassOptions(noise=noise)).action
    grads_slow = torch.autograd.grad(slow.sum(), leaves)
    assert torch.allclose(fast, slow, atol=1e-6)
    for a, b in zip(grads_fast, grads_slow, strict=True):
        assert torch.allclose(a, b, atol=1e-5)
    with torch.no_grad():
        assert not torch.allclose(fast, actor(state), atol=1e-3)  # the noise changes the action
        zero = NeuronNoise(*(tuple(torch.zeros_like(x) for x in part) for part in noise[:2]),
                           torch.zeros_like(noise.decoder))
        assert torch.equal(actor(state, options=PassOptions(noise=zero)), actor(state))


def test_transmission_noise_reaches_the_intra_layer_connections_and_not_the_reset():
    """One population of P = 2 output neurons, T = 2, hand-computed with Algorithm 1's CLIF (α_C = 0.5,
    α_V = 0.75, V_th = 0.5, hard reset) and Eq. (10), I_2 = W_intra S̃_1 + b_intra with S̃ the noisy spikes."""
    actor = build_actor(actor_config("ilc-san", hidden=(3,), population_out=2, timesteps=2), 1, 1, [1.0])
    with torch.no_grad():
        actor.intra.weight.copy_(torch.tensor([[[[0.5, 1.0], [2.0, 0.25]]]]))
        actor.intra.bias.copy_(torch.tensor([[[0.1, -0.2]]]))
    currents = torch.tensor([[1.0, 0.1], [0.0, 0.0]]).reshape(1, 2, 1, 2)
    transmission = torch.tensor([[0.2, -0.1], [0.05, 0.3]]).reshape(1, 2, 1, 2)
    spikes = actor.layer_spikes(currents, output_layer=True, transmission=transmission)
    # t = 1: neuron 0 C = V' = 1.0 ≥ 0.5 fires (V → 0); neuron 1 C = V = 0.1, silent.
    #        passed on: [1 + 0.2, 0 − 0.1];
    #        I_2 = [0.5·1.2 + 1.0·(−0.1) + 0.1, 2.0·1.2 + 0.25·(−0.1) − 0.2] = [0.6, 2.175]
    # t = 2: neuron 0 C = 0.5 + 0.6 = 1.1, V' = 0 + 1.1 → fires; neuron 1 C = 0.05 + 2.175, V' = 0.075 + 2.225 → fires
    expected = torch.tensor([[1.2, -0.1], [1.05, 1.3]]).reshape(1, 2, 1, 2)
    assert torch.allclose(spikes, expected, atol=1e-6)
    # without the noise, neuron 1 sees I_2 = 2.0·1 − 0.2 = 1.8 and fires too, neuron 0 I_2 = 0.6: same spikes, clean
    assert torch.equal(actor.layer_spikes(currents, output_layer=True), torch.tensor([[1.0, 0.0], [1.0, 1.0]])
                       .reshape(1, 2, 1, 2))


def test_acting_noise_is_one_coloured_series_per_episode_read_t_samples_per_action():
    agent = _agent()
    exploration = agent.exploration.module
    timesteps, channels = SMALL_ACTOR.timesteps, exploration.channels
    assert channels == 2 * (16 + 16 + 2 * SMALL_ACTOR.population_out) + 2
    assert exploration.layer_sigmas == pytest.approx([0.5 / 4, 0.5 / 4, 0.5 / np.sqrt(20)])
    assert torch.allclose(exploration.decoder_sigma, torch.full((1, 2), 0.5 / np.sqrt(2)))
    windows = torch.cat([exploration.acting_noise()[0, 0] for _ in range(40)])  # (40·T, C)
    series = exploration.series[0]
    assert series.shape == (fft_length((50 + 1) * timesteps), channels) == (256, channels)  # 255 = 3·5·17 → 2^8
    assert torch.equal(windows, series[:40 * timesteps])  # consecutive actions read consecutive samples
    pink = windows.T.numpy().astype(np.float64)
    assert 0.55 < autocorrelation(pink, 1) < 0.9  # pink: strongly correlated over one simulation step
    assert autocorrelation(pink, timesteps) > 0.35  # and across successive actions
    exploration.end_episode(0)
    assert not torch.equal(exploration.acting_noise()[0, 0], series[:timesteps])  # a new episode, a new series
    white = _agent(TrainingConfig(exploration="noisy", noisy_beta=0.0, noisy_return_reference=1.0)).exploration.module
    noise = torch.cat([white.acting_noise()[0, 0] for _ in range(40)]).T.numpy().astype(np.float64)
    assert abs(autocorrelation(noise, 1)) < 0.05


def test_the_update_noise_has_the_window_covariance_of_the_exploration_series():
    exploration = _agent().exploration.module
    draws = exploration.update_noise(4000)[0].reshape(-1, 5, exploration.channels)  # (B, T, C)
    windows = draws.permute(0, 2, 1).reshape(-1, 5).double().numpy()
    expected = window_covariance(1.0, fft_length(51 * 5), 5)
    assert np.abs(windows.T @ windows / len(windows) - expected).max() < 0.03
    assert expected[0, 4] > 0.5  # five steps of one action stay correlated


def test_evaluation_is_deterministic_and_unchanged_while_exploring_is_not():
    noisy, plain = _agent(), _agent(TrainingConfig())
    states = np.random.default_rng(0).normal(size=(1, 3)).astype(np.float32)
    before = noisy.act(states)
    explored = [noisy.explore(states, []) for _ in range(3)]
    assert np.array_equal(noisy.act(states), before)  # exploring leaves the deterministic policy alone
    assert np.array_equal(before, plain.act(states))  # same actor as without NoisySAN
    assert all(np.abs(a - before).max() > 1e-4 for a in explored)
    assert np.abs(explored[0] - explored[1]).max() > 1e-5


def test_the_actor_loss_adds_the_noise_penalty_weighted_by_the_return():
    agent = _agent()
    exploration = agent.exploration.module
    exploration.set_returns([[{"eval_return_mean": 30.0}, {"eval_return_mean": 50.0}]])
    assert float(exploration.weights[0]) == pytest.approx(0.5)  # latest return / R* = 50 / 100
    exploration.set_returns([[{"eval_return_mean": -20.0}]])
    assert float(exploration.weights[0]) == 0.0  # max(0, R)
    batch = {"obs": torch.randn(1, 8, 3), "actor_noise": torch.zeros(1, 8, 5, exploration.channels),
             "penalty_weights": torch.tensor([0.5])}
    plain = -agent.critic(batch["obs"], agent.actor(batch["obs"]), first_only=True).mean()
    sigma = exploration.decoder_sigma
    loss = agent.actor_loss(batch)
    assert float(loss.detach()) == pytest.approx(float(plain.detach()) + 0.5 * float(sigma.detach().mean()) ** 2,
                                                 rel=1e-6)
    (gradient,) = torch.autograd.grad(loss, sigma)  # zero noise: only the penalty depends on σ_d
    assert torch.allclose(gradient, torch.full_like(sigma, 2 * 0.5 * float(sigma.detach().mean()) / 2))


def test_an_update_steps_the_decoder_noise_scale_with_the_actor():
    agent = _agent()
    agent.exploration.module.weights = torch.tensor([1.0])
    sigma = agent.exploration.module.decoder_sigma.detach().clone()
    rng = np.random.default_rng(0)
    for _ in range(2):  # policy delay 2: the second update moves the actor and σ_d
        agent.update(agent.to_batch(_random_batch(rng, 1)))
    assert not torch.equal(agent.exploration.module.decoder_sigma, sigma)
    assert float(agent.exploration.adam.steps[0]) == 1


def _random_batch(rng, seeds: int) -> dict[str, np.ndarray]:
    arrays = {"obs": rng.normal(size=(seeds, 32, 3)), "action": rng.uniform(-1, 1, (seeds, 32, 2)),
              "reward": rng.normal(size=(seeds, 32)), "next_obs": rng.normal(size=(seeds, 32, 3)),
              "terminal": rng.uniform(size=(seeds, 32)) < 0.1}
    return {k: v.astype(np.float32) for k, v in arrays.items()}


def test_a_compiled_noisy_agent_updates_like_the_eager_one():
    from test_training import assert_same_updates

    config = actor_config("ilc-san", hidden=(16,), population_in=4, population_out=4, timesteps=3)
    task = TaskSpace(3, 2, [1.0, 1.0], [0.0, 0.0], episode_steps=20)
    eager = TD3(config, NOISY, task, (7,))
    compiled = TD3(config, NOISY, task, (7,), ComputeSettings(compile=True))
    for agent in (eager, compiled):
        agent.exploration.module.weights = torch.tensor([0.8])
    rng = np.random.default_rng(4)
    assert_same_updates(eager, compiled, [_random_batch(rng, 1) for _ in range(4)], atol=1e-4)
    sigmas = [agent.exploration.module.decoder_sigma for agent in (eager, compiled)]
    assert torch.allclose(*sigmas, atol=1e-6)
    assert not torch.allclose(sigmas[0], torch.full((1, 2), 0.5 / np.sqrt(2)))
    states = rng.normal(size=(1, 3)).astype(np.float32)
    for _ in range(3):  # exploring: the same noise windows, the learned σ_d read in place by the compiled program
        assert np.allclose(eager.explore(states, []), compiled.explore(states, []), atol=1e-5)
    (program,) = compiled.exploration.exploring_fn.programs.values()
    assert program.direct  # called directly, its inputs resolved to the agent's own tensors


def test_each_seed_of_a_stacked_noisy_run_explores_and_updates_like_a_single_run():
    many, single = _agent(seeds=(4, 11)), _agent(seeds=(11,))
    for agent in (many, single):
        agent.exploration.module.weights = torch.ones(len(agent.seeds))
    states = np.random.default_rng(2).normal(size=(2, 3)).astype(np.float32)
    assert np.allclose(many.explore(states, [])[1:], single.explore(states[1:], []), atol=1e-5)
    rng = np.random.default_rng(3)
    for _ in range(4):
        arrays = _random_batch(rng, 2)
        many.update(many.to_batch(arrays))
        single.update(single.to_batch({k: v[1:] for k, v in arrays.items()}))
    assert torch.allclose(many.exploration.module.decoder_sigma[1:], single.exploration.module.decoder_sigma,
                          atol=1e-6)
    for (name, p_many), (_, p_single) in zip(many.actor.named_parameters(), single.actor.named_parameters(),
                                             strict=True):
        assert torch.allclose(p_many[1:], p_single, atol=1e-5), name


def test_noisy_exploration_is_refused_for_dan_and_needs_a_reference_return_off_the_paper_tasks(tmp_path):
    dan = RunConfig(task="Pendulum-v1", steps=10, actor=actor_config("dan", hidden=(8,)),
                    training=TrainingConfig(exploration="noisy", noisy_return_reference=1.0), threads=1)
    with pytest.raises(UserError, match="DAN"):
        train(dan, tmp_path / "dan", progress=False, log=lambda *_: None)
    unknown = RunConfig(task="Pendulum-v1", steps=10, actor=SMALL_ACTOR, training=TrainingConfig(exploration="noisy"))
    with pytest.raises(UserError, match="--noisy-return-reference"):
        train(unknown, tmp_path / "pendulum", progress=False, log=lambda *_: None)
    assert not (tmp_path / "pendulum").exists()


def test_the_options_parse_are_saved_in_config_json_and_bad_values_are_one_line(tmp_path, capsys):
    from ilcsan.cli import build_parser, main
    from ilcsan.cli.train import build_run_config

    args = build_parser().parse_args(["train", "--task", "Hopper", "--exploration", "noisy", "--noisy-sigma", "0.3",
                                      "--noisy-beta", "2", "--noisy-return-reference", "3000"])
    config = build_run_config(args)
    assert (config.training.exploration, config.training.noisy_sigma, config.training.noisy_beta,
            config.training.noisy_return_reference) == ("noisy", 0.3, 2.0, 3000.0)
    assert RunConfig.from_dict(json.loads(json.dumps(config.for_seed(0)))).training == config.training
    assert main(["train", "--task", "Hopper", "--exploration", "noisy", "--noisy-beta", "-1", "--steps", "10",
                 "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err
    assert "--noisy-beta" in err and "Traceback" not in err
    assert main(["train", "--task", "Hopper", "--preset", "dan", "--exploration", "noisy", "--steps", "10",
                 "--out", str(tmp_path / "dan")]) == 2


def test_an_interrupted_noisy_run_resumes_to_the_same_curve_and_noise(tmp_path, monkeypatch):
    """Interrupted mid-episode: the resumed run draws the same series again and reads on from the same sample. The
    checkpoint it resumes from keeps its module state under ``parameters``, as checkpoints written before that key
    was named ``module`` did: they resume as well."""
    from test_training import assert_resumes_to_the_same_curve, tiny_method_run

    def as_written_before(checkpoint: dict) -> dict:
        checkpoint["exploration"]["parameters"] = checkpoint["exploration"].pop("module")
        return checkpoint

    config = tiny_method_run(start_steps=100, exploration="noisy", noisy_return_reference=1000.0)
    for straight, resumed in assert_resumes_to_the_same_curve(config, tmp_path, monkeypatch, as_written_before):
        assert torch.equal(straight["exploration"]["module"]["decoder_sigma"],
                           resumed["exploration"]["module"]["decoder_sigma"])
        assert straight["exploration"]["streams"]["cursor"] == resumed["exploration"]["streams"]["cursor"] > 0


def test_the_series_length_is_the_next_one_with_prime_factors_up_to_seven():
    # Hopper's 1 001 actions × T = 5: 5 005 = 5·7·11·13 → 5 040 = 2^4·3^2·5·7; 5 041 = 71² → 5 103 = 3^6·7
    assert [fft_length(n) for n in (1, 255, 5005, 5040, 5041)] == [1, 256, 5040, 5040, 5103]
