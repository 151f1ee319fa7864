"""CaRe-BN on the spiking actor (Xu et al., ICLR 2026): statistics, the Kalman update, folding, both engines."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from ilcsan.actors import build_actor
from ilcsan.config import ActorConfig, actor_config
from ilcsan.deploy.state import export_state
from ilcsan.errors import UserError
from ilcsan.rl.methods.care_bn import kalman_update, kalman_update_, pool_statistics, recalibrated_statistics
from ilcsan.runs.checkpoint import module_state
from ilcsan.snn.actor import SpikingActor
from ilcsan.snn.normalization import (
    EPSILON,
    NormStatistics,
    RunningStatistics,
    batch_statistics,
    fold_into_linear,
    normalize,
)
from ilcsan.snn.output import PassOptions

SPIKING_PRESETS = ("ilc-san", "popsan", "mdc-san", "akl")


def care_bn_actor(preset: str = "ilc-san", seeds=(0, 1), state_dim=3, action_dim=2, **overrides):
    overrides.setdefault("hidden", (24, 16))
    config = actor_config(preset, normalization="care-bn", **overrides)
    return build_actor(config, state_dim, action_dim, [1.0] * action_dim, seeds=seeds)


def randomise_running_statistics(actor, generator_seed: int = 1) -> None:
    """Running statistics and γ, β away from their initial values, so that a test sees them used."""
    generator = torch.Generator().manual_seed(generator_seed)
    with torch.no_grad():
        for norm in actor.norms:
            shape = norm.running_mean.shape
            norm.running_mean.copy_(0.3 * torch.randn(shape, generator=generator))
            norm.running_var.copy_(0.05 + torch.rand(shape, generator=generator))
            norm.gamma.mul_(1.0 + torch.rand(shape, generator=generator))
            norm.beta.add_(0.2 * torch.randn(shape, generator=generator))


# ------------------------------------------------------------------------------ the pure functions
def test_kalman_update_matches_a_hand_computed_case():
    """m = 0.8, B = 4 states (B − 1 = 3). Three neurons:

    0: δμ = 1 − 0 = 1, P_μ = .8·0 + .2·1 = .2, R_μ = 3/3 = 1, K = .2/1.2 = 1/6, μ̂ = 1/6;
       δσ² = 3 − 1 = 2, P_σ² = .2·4 = .8, R_σ² = 2·9/3 = 6, K = .8/6.8 = 2/17, σ̂² = 1 + 4/17 = 21/17.
    1: δμ = 0, P_μ = .8·.5 = .4 (decays), μ̂ stays 1; δσ² = 0, P_σ² = 0, σ̂² stays 1.
    2: a silent neuron, σ_B² = 0: R = 0. δμ = 0 and P_μ = 0: P + R = 0, no gain, μ̂ stays 2 (no NaN);
       δσ² = −.5, P_σ² = .2·.25 = .05, K = 1: σ̂² = 0.
    """
    running = RunningStatistics(mean=torch.tensor([[0.0, 1.0, 2.0]]), var=torch.tensor([[1.0, 1.0, 0.5]]),
                                mean_innovation=torch.tensor([[0.0, 0.5, 0.0]]),
                                var_innovation=torch.tensor([[0.0, 0.0, 0.0]]))
    before = [tensor.clone() for tensor in running]
    batch = NormStatistics(mean=torch.tensor([[1.0, 1.0, 2.0]]), var=torch.tensor([[3.0, 1.0, 0.0]]))
    updated = kalman_update(running, batch, samples=4, momentum=0.8)
    torch.testing.assert_close(updated.mean, torch.tensor([[1 / 6, 1.0, 2.0]]))
    torch.testing.assert_close(updated.var, torch.tensor([[21 / 17, 1.0, 0.0]]))
    torch.testing.assert_close(updated.mean_innovation, torch.tensor([[0.2, 0.4, 0.0]]))
    torch.testing.assert_close(updated.var_innovation, torch.tensor([[0.8, 0.0, 0.05]]))
    for tensor, old in zip(running, before, strict=True):  # pure: the inputs are not written
        assert torch.equal(tensor, old)


def test_kalman_update_needs_batches_of_two_states():
    running = RunningStatistics(*(torch.zeros(1, 2) for _ in range(4)))
    with pytest.raises(UserError, match="at least 2 states"):
        kalman_update(running, NormStatistics(torch.zeros(1, 2), torch.ones(1, 2)), samples=1)


def test_batch_statistics_pool_over_steps_and_states_per_seed_and_neuron():
    currents = torch.randn(2, 5, 7, 3, dtype=torch.float64)
    statistics = batch_statistics(currents)
    values = currents.numpy()
    np.testing.assert_allclose(statistics.mean.numpy(), values.mean(axis=(1, 2)), rtol=1e-12)
    np.testing.assert_allclose(statistics.var.numpy(), values.var(axis=(1, 2)), rtol=1e-12)  # biased (ddof 0)
    # an analog input's current, the same at every step, has the statistics of its T copies
    constant = currents[:, 0]
    repeated = batch_statistics(constant.unsqueeze(1).expand(-1, 5, -1, -1))
    torch.testing.assert_close(batch_statistics(constant).mean, repeated.mean)
    torch.testing.assert_close(batch_statistics(constant).var, repeated.var)


def test_pooled_statistics_are_those_of_all_batches_together():
    batches = [torch.randn(2, 5, size, 3, dtype=torch.float64) * scale + shift
               for size, scale, shift in ((4, 1.0, 0.0), (9, 2.0, 1.0), (1, 0.5, -3.0))]
    pooled = pool_statistics([batch_statistics(batch) for batch in batches], [batch.shape[2] for batch in batches])
    together = np.concatenate([batch.numpy() for batch in batches], axis=2)
    np.testing.assert_allclose(pooled.mean.numpy(), together.mean(axis=(1, 2)), rtol=1e-12)
    np.testing.assert_allclose(pooled.var.numpy(), together.var(axis=(1, 2)), rtol=1e-12)


def test_normalize_hand_case():
    """Currents 1 and 3 of one neuron: μ = 2, σ² = 1; γ = β = .25: X̂ = .25 (X − 2)/√(1 + ε) + .25 = 0 and .5."""
    currents = torch.tensor([[[1.0], [3.0]]], dtype=torch.float64)  # (K=1, B=2, D=1)
    statistics = batch_statistics(currents)
    assert statistics.mean.item() == 2.0 and statistics.var.item() == 1.0
    gamma = beta = torch.full((1, 1), 0.25, dtype=torch.float64)
    normalised = normalize(currents, statistics, gamma, beta)
    expected = [0.25 - 0.25 / math.sqrt(1 + EPSILON), 0.25 + 0.25 / math.sqrt(1 + EPSILON)]
    np.testing.assert_allclose(normalised.flatten().numpy(), expected, rtol=1e-15)


def test_fold_into_linear_is_the_normalised_layer():
    weight, bias = torch.randn(2, 4, 6, dtype=torch.float64), torch.randn(2, 4, dtype=torch.float64)
    statistics = NormStatistics(torch.randn(2, 4, dtype=torch.float64), torch.rand(2, 4, dtype=torch.float64))
    gamma, beta = torch.randn(2, 4, dtype=torch.float64), torch.randn(2, 4, dtype=torch.float64)
    spikes = (torch.rand(2, 5, 6, dtype=torch.float64) > 0.5).to(torch.float64)
    currents = torch.einsum("kbi,koi->kbo", spikes, weight) + bias.unsqueeze(1)
    folded_weight, folded_bias = fold_into_linear(weight, bias, statistics, gamma, beta)
    folded = torch.einsum("kbi,koi->kbo", spikes, folded_weight) + folded_bias.unsqueeze(1)
    torch.testing.assert_close(folded, normalize(currents, statistics, gamma, beta), rtol=1e-12, atol=1e-12)


# ------------------------------------------------------------------------------------- the actor
def test_gamma_beta_and_buffers_start_at_the_authors_values_with_the_seed_dimension_first():
    actor = care_bn_actor(v_th=0.7)
    plain = build_actor(actor_config("ilc-san", hidden=(24, 16), v_th=0.7), 3, 2, [1.0, 1.0], seeds=(0, 1))
    widths = [24, 16, 20]
    state = actor.state_dict()
    for index, (norm, width) in enumerate(zip(actor.norms, widths, strict=True)):
        assert torch.equal(norm.gamma, torch.full((2, width), 0.35))
        assert torch.equal(norm.beta, torch.full((2, width), 0.35))
        assert torch.equal(norm.running_mean, torch.zeros(2, width))
        assert torch.equal(norm.running_var, torch.ones(2, width))
        for name in ("running_mean", "running_var", "mean_innovation", "var_innovation"):
            assert state[f"norms.{index}.{name}"].shape == (2, width)  # persistent, K first
    # CaRe-BN draws nothing: every other tensor is that of the same actor without normalisation
    plain_state = plain.state_dict()
    assert all(torch.equal(tensor, plain_state[name]) for name, tensor in state.items() if not name.startswith("norms"))
    assert set(plain_state) == {name for name in state if not name.startswith("norms")}


@pytest.mark.parametrize("engine", ["fast", "reference"])
def test_the_output_layer_normalises_its_feed_forward_current_only(engine):
    """One output neuron, intra-layer bias only (b_intra = .1), feed-forward W = 0, b = 0 with μ̂ = 0: the normalised
    feed-forward current is γ·0 + β = 0 (β = 0) and the intra-layer current .1 arrives from t = 2 unscaled. CLIF
    (α_C = .5, α_V = .75): C = 0, .1, .15, .175, .1875 and H = 0, .1, .225, .34375, .4453125 — never a spike. Were
    the intra-layer current normalised too, γ = 4 would make it .4 and the neuron fire from t = 3."""
    actor = care_bn_actor(seeds=(0,), state_dim=1, action_dim=1, hidden=(1,), population_out=1, intra="bias")
    output_norm = actor.norms[-1]
    with torch.no_grad():
        actor.layers[-1].weight.zero_()
        actor.layers[-1].bias.zero_()
        actor.intra.bias.fill_(0.1)
        output_norm.gamma.fill_(4.0)
        output_norm.beta.zero_()
        output_norm.running_var.fill_(0.5)
    output = actor.run(torch.zeros(1, 1, 1), engine=engine, membranes=True)
    np.testing.assert_allclose(output.membranes.flatten().tolist(), [0.0, 0.1, 0.225, 0.34375, 0.4453125], atol=1e-6)
    assert output.output_spikes.sum().item() == 0.0


@pytest.mark.parametrize("preset", SPIKING_PRESETS)
def test_engines_agree_with_running_statistics(preset):
    actor = care_bn_actor(preset)
    randomise_running_statistics(actor)
    state = torch.randn(2, 9, 3)
    fast = actor.run(state, membranes=True)
    reference = actor.run(state, engine="reference", membranes=True)
    torch.testing.assert_close(reference.action, fast.action, rtol=0, atol=1e-6)
    torch.testing.assert_close(reference.membranes, fast.membranes, rtol=0, atol=1e-6)
    assert torch.equal(reference.output_spikes, fast.output_spikes)
    for used, norm in zip(fast.norm_statistics, actor.norms, strict=True):
        assert used.mean is norm.running_mean and used.var is norm.running_var


@pytest.mark.parametrize("preset", SPIKING_PRESETS)
def test_engines_agree_with_batch_statistics_values_statistics_and_gradients(preset):
    """The reference engine finds each layer's batch statistics by its own time loop (one pass per layer), not from
    the layer-major pass: agreeing statistics check the fast engine's pooling over T and B."""
    actor = care_bn_actor(preset)
    state = torch.randn(2, 9, 3)
    results = {}
    for engine in ("fast", "reference"):
        output = actor.run(state, engine=engine, options=PassOptions(statistics="batch"), membranes=True)
        actor.zero_grad()
        (output.action.square().sum() + output.membranes.square().mean()).backward()
        results[engine] = output, [parameter.grad.clone() for parameter in actor.parameters()]
    (fast, fast_grads), (reference, reference_grads) = results["fast"], results["reference"]
    torch.testing.assert_close(reference.action, fast.action, rtol=0, atol=1e-6)
    torch.testing.assert_close(reference.membranes, fast.membranes, rtol=0, atol=1e-6)
    for ours, theirs in zip(fast.norm_statistics, reference.norm_statistics, strict=True):
        torch.testing.assert_close(theirs.mean, ours.mean, rtol=1e-6, atol=1e-6)
        torch.testing.assert_close(theirs.var, ours.var, rtol=1e-6, atol=1e-6)
    for ours, theirs in zip(fast_grads, reference_grads, strict=True):
        torch.testing.assert_close(theirs, ours, rtol=1e-4, atol=1e-5)
    # and batch statistics are not the running ones: the pass differs from acting
    assert not torch.equal(actor.run(state, membranes=True).membranes, fast.membranes)


def test_batch_statistics_of_the_first_layer_are_those_of_its_currents():
    actor = care_bn_actor()
    state = torch.randn(2, 9, 3)
    output = actor.run(state, options=PassOptions(statistics="batch"))
    first = batch_statistics(actor.layers[0](output.layer_inputs[0]))
    torch.testing.assert_close(output.norm_statistics[0].mean, first.mean)
    torch.testing.assert_close(output.norm_statistics[0].var, first.var)


def test_gradients_flow_through_the_batch_statistics():
    actor = care_bn_actor()
    state = torch.randn(2, 9, 3)
    grads = {}
    for mode in ("batch", "detached"):
        if mode == "batch":
            output = actor.run(state, options=PassOptions(statistics="batch"))
        else:  # the very same statistics as constants
            statistics = actor.run(state, options=PassOptions(statistics="batch")).norm_statistics
            detached = tuple(type(s)(s.mean.detach(), s.var.detach()) for s in statistics)
            output = actor.run(state, options=PassOptions(statistics=detached))
        actor.zero_grad()
        output.action.square().sum().backward()
        grads[mode] = output.action.detach(), actor.layers[0].weight.grad.clone()
    assert torch.equal(grads["batch"][0], grads["detached"][0])  # same forward values
    difference = (grads["batch"][1] - grads["detached"][1]).abs().max().item()
    assert difference > 1e-3 * grads["batch"][1].abs().max().item()


def test_the_kalman_update_of_the_actor_moves_its_buffers_in_place():
    actor = care_bn_actor()
    statistics = actor.run(torch.randn(2, 9, 3), options=PassOptions(statistics="batch")).norm_statistics
    expected = [kalman_update(norm.running_state(), batch, 9) for norm, batch in zip(actor.norms, statistics,
                                                                                    strict=True)]
    buffers = [norm.running_mean for norm in actor.norms]
    for norm, batch in zip(actor.norms, statistics, strict=True):
        kalman_update_(norm.running_state(), batch, samples=9)
    for norm, want, buffer in zip(actor.norms, expected, buffers, strict=True):
        assert norm.running_mean is buffer  # in place: the tensors a training program holds stay valid
        for got, value in zip(norm.running_state(), want, strict=True):
            assert torch.equal(got, value)
        assert not torch.equal(norm.running_var, torch.ones_like(norm.running_var))


def test_recalibration_gives_the_statistics_of_all_batches_in_one_pass():
    """Batches of 5, 8 and 3 states: layer l's recalibrated statistics equal the batch statistics of layer l in one
    pass over the 16 states together with layers before l normalised with their recalibrated statistics."""
    actor = care_bn_actor()
    randomise_running_statistics(actor)
    batch = actor.run(torch.randn(2, 9, 3), options=PassOptions(statistics="batch")).norm_statistics
    for norm, layer_statistics in zip(actor.norms, batch, strict=True):
        kalman_update_(norm.running_state(), layer_statistics, 9)
    before = {name: tensor.clone() for name, tensor in actor.state_dict().items()}
    assert before["norms.0.mean_innovation"].abs().sum() > 0
    batches = [torch.randn(2, size, 3) for size in (5, 8, 3)]
    recalibrated = recalibrated_statistics(actor, batches)
    assert all(torch.equal(tensor, before[name]) for name, tensor in actor.state_dict().items())
    together = torch.cat(batches, dim=1)
    for index, statistics in enumerate(recalibrated):
        direct = actor.run(together, options=PassOptions(statistics=recalibrated[:index])).norm_statistics[index]
        torch.testing.assert_close(statistics.mean, direct.mean, rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(statistics.var, direct.var, rtol=1e-5, atol=1e-6)
    actor.norms.set_running_(recalibrated)
    for norm, statistics in zip(actor.norms, recalibrated, strict=True):
        assert torch.equal(norm.running_mean, statistics.mean) and torch.equal(norm.running_var, statistics.var)
    assert torch.equal(actor.norms[0].mean_innovation, before["norms.0.mean_innovation"])  # P's kept


@pytest.mark.parametrize("encoder", ["pop-det", "layer"])
@pytest.mark.parametrize("engine", ["fast", "reference"])
def test_recalibration_stopping_at_each_layer_equals_whole_passes(encoder, engine):
    """The recalibration's pass for layer l stops at layer l's currents; the statistics are those of whole passes
    through the actor (Algorithm 1's, the chosen engine), layer l's batch statistics with the layers before it
    normalised by theirs, pooled: exactly for the fast engine, to float rounding for the reference one. Spiking
    (E_pop_det) and analog (E_layer) input, three synaptic layers."""
    config = actor_config("ilc-san", normalization="care-bn", encoder=encoder, hidden=(24, 16))
    actor = build_actor(config, 3, 2, [1.0, 1.0], seeds=(0, 1), engine=engine)
    randomise_running_statistics(actor)
    batches = [torch.randn(2, size, 3) for size in (7, 4)]
    found: list = []
    with torch.no_grad():
        for index in range(len(actor.layers)):
            parts = [actor.run(batch, options=PassOptions(statistics=tuple(found))).norm_statistics[index]
                     for batch in batches]
            found.append(pool_statistics(parts, [7, 4]))
        recalibrated = recalibrated_statistics(actor, batches)
    assert len(recalibrated) == 3
    for ours, whole in zip(recalibrated, found, strict=True):
        for got, want in ((ours.mean, whole.mean), (ours.var, whole.var)):
            if engine == "fast":
                assert torch.equal(got, want)
            else:
                torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)


def folded_copy(actor) -> SpikingActor:
    """An actor without normalisation holding the export fold of ``actor``'s seed 0
    (:meth:`~ilcsan.snn.normalization.LayerNormalizations.export_fold`, what every export runs), in its dtype."""
    state = {name: tensor.detach()[0] for name, tensor in module_state(actor).items()}
    folded = actor.norms.export_fold(state, "norms")
    config = dataclasses.replace(actor.config, normalization="none")
    plain = build_actor(config, actor.state_dim, actor.action_dim, [1.0] * actor.action_dim)
    plain = plain.to(next(actor.parameters()).dtype)
    plain.load_state_dict({name: tensor[None] for name, tensor in folded.items()})
    return plain


@pytest.mark.parametrize("preset", SPIKING_PRESETS)
def test_the_export_fold_acts_as_the_normalised_actor(preset):
    actor = care_bn_actor(preset, seeds=(0,)).double()
    randomise_running_statistics(actor)
    folded = folded_copy(actor)
    state = torch.randn(1, 9, 3, dtype=torch.float64)
    for engine in ("fast", "reference"):
        ours, theirs = actor.run(state, engine=engine, membranes=True), folded.run(state, engine=engine, membranes=True)
        torch.testing.assert_close(theirs.action, ours.action, rtol=0, atol=1e-10)
        torch.testing.assert_close(theirs.membranes, ours.membranes, rtol=0, atol=1e-10)
    assert folded.norms is None and actor.norms is not None  # the original is unchanged
    assert set(export_state(actor)) == set(folded.state_dict())  # what every export holds: no normalisation left


def test_the_export_fold_agrees_in_float32_too():
    actor = care_bn_actor(seeds=(0,))
    randomise_running_statistics(actor)
    state = torch.randn(1, 9, 3)
    ours, theirs = actor.run(state, membranes=True), folded_copy(actor).run(state, membranes=True)
    torch.testing.assert_close(theirs.membranes, ours.membranes, rtol=0, atol=1e-5)


# ------------------------------------------------------------------------------- config and errors
def test_dan_refuses_care_bn_in_one_line():
    for make in (lambda: actor_config("dan", normalization="care-bn"),
                 lambda: ActorConfig.from_dict({**actor_config("dan").to_dict(), "normalization": "care-bn"})):
        with pytest.raises(UserError, match="--normalization") as error:
            make()
        assert "\n" not in str(error.value)


def test_an_actor_without_normalisation_refuses_batch_statistics():
    actor = build_actor(actor_config("ilc-san", hidden=(8,)), 3, 2, [1.0, 1.0])
    with pytest.raises(UserError, match="does not normalise"):
        actor.run(torch.zeros(1, 2, 3), options=PassOptions(statistics="batch"))
    with pytest.raises(UserError, match="running, batch"):
        care_bn_actor().run(torch.zeros(2, 2, 3), options=PassOptions(statistics="batches"))


def test_config_round_trip_and_a_config_saved_before_the_setting_loads_as_none():
    config = actor_config("popsan", normalization="care-bn")
    assert ActorConfig.from_dict(config.to_dict()) == config
    saved = actor_config("ilc-san").to_dict()
    saved.pop("normalization")
    assert ActorConfig.from_dict(saved).normalization == "none"
    assert all(actor_config(preset).normalization == "none" for preset in (*SPIKING_PRESETS, "dan"))
    with pytest.raises(UserError, match="--normalization"):
        actor_config("ilc-san", normalization="batch")
