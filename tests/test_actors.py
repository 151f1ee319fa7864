"""Actor family: intra-layer timing and masks, decoders, engines, ensembles (Algorithm 1, Eq. (8)-(10))."""

from __future__ import annotations

import itertools

import pytest
import torch

from ilcsan.actors import build_actor
from ilcsan.config import INTRA_MASKS as INTRA_VARIANTS
from ilcsan.config import PRESETS, actor_config
from ilcsan.errors import UserError
from ilcsan.snn.actor import SpikingActor
from ilcsan.snn.decoders import select_statistic


def small(preset: str = "ilc-san", **overrides):
    overrides.setdefault("hidden", (24, 16))
    return actor_config(preset, **overrides)


def make(config, state_dim=3, action_dim=2, seeds=(0,)):
    return build_actor(config, state_dim, action_dim, [1.0] * action_dim, seeds=seeds)


def output_layer_spikes(actor: SpikingActor, currents: torch.Tensor) -> torch.Tensor:
    return actor.layer_spikes(currents, output_layer=True)


def test_intra_current_arrives_one_step_late_and_never_at_t1():
    actor = make(small(intra="bias", population_out=2), action_dim=1)
    with torch.no_grad():
        actor.intra.bias.fill_(1.0)
    zeros = torch.zeros(1, 5, 1, 2)
    spikes = output_layer_spikes(actor, zeros)[0, :, 0]
    # no feed-forward input: t = 1 silent; from t = 2 on I = b = 1 -> H = C >= .5 -> spike every step
    assert spikes[:, 0].tolist() == [0.0, 1.0, 1.0, 1.0, 1.0]


def test_lateral_spike_reaches_the_neighbour_at_the_next_step_only():
    actor = make(small(intra="lateral", population_out=2), action_dim=1)
    with torch.no_grad():
        actor.intra.weight.zero_()
        actor.intra.weight[0, 0, 1, 0] = 0.8  # neuron 0 -> neuron 1
        actor.intra.weight[0, 0, 0, 0] = 5.0  # a self weight: masked out by 'lateral'
    currents = torch.zeros(1, 5, 1, 2)
    currents[0, 0, 0, 0] = 0.6  # neuron 0 fires at t = 1 only
    spikes = output_layer_spikes(actor, currents)[0, :, 0]
    assert spikes[:, 0].tolist() == [1.0, 0.0, 0.0, 0.0, 0.0]
    # neuron 1: I_2 = .8 -> H_2 = .8 spike; then C_3 = .4, H_3 = .4 no spike; C_4 = .2, H_4 = .5 spike
    assert spikes[:, 1].tolist() == [0.0, 1.0, 0.0, 1.0, 0.0]


@pytest.mark.parametrize("variant", [v for v in INTRA_VARIANTS if v != "none"])
def test_masked_weights_stay_zero_and_kept_weights_train(variant):
    actor = make(small(intra=variant))
    with torch.no_grad():  # keep the output neurons near threshold so every synapse sees spikes and gradient
        actor.layers[-1].weight.mul_(0.1)
        actor.layers[-1].bias.fill_(0.4)
    optimizer = torch.optim.Adam(actor.parameters(), lr=1e-2)
    before_w, before_b = actor.intra.weight.detach().clone(), actor.intra.bias.detach().clone()
    mask = INTRA_VARIANTS[variant]
    eye = torch.eye(10, dtype=torch.bool)
    keep = (eye & mask.self_weights) | (~eye & mask.lateral_weights)
    for step in range(5):
        optimizer.zero_grad()
        state = torch.randn(1, 64, 3, generator=torch.Generator().manual_seed(step)) * 2
        actor(state).pow(2).sum().backward()
        optimizer.step()
    w, b = actor.intra.weight.detach(), actor.intra.bias.detach()
    assert torch.all(w[..., ~keep] == 0.0)
    if keep.any():
        assert (w[..., keep] != before_w[..., keep]).float().mean() >= 0.7
    if mask.bias:
        assert (b != before_b).float().mean() >= 0.7
    else:
        assert torch.all(b == 0.0)


def test_no_intra_variant_has_no_intra_parameters():
    actor = make(small(intra="none"))
    assert actor.intra is None
    assert not any("intra" in name for name, _ in actor.named_parameters())


def test_decoder_statistics():
    voltages = torch.tensor([0.1, -0.7, 0.5, 0.2, 0.3]).reshape(1, 5, 1, 1)
    assert float(select_statistic(voltages, "last")) == pytest.approx(0.3)
    assert float(select_statistic(voltages, "max")) == pytest.approx(-0.7)  # signed value of max |V|
    assert float(select_statistic(voltages, "mean")) == pytest.approx(0.08)


def test_membrane_voltage_decoder_matches_hand_computation():
    config = small(intra="none", population_out=2, alpha_v_li=0.5)
    actor = make(config, action_dim=1)
    spikes = torch.zeros(1, 5, 1, 2)
    spikes[0, 0, 0, 0] = 1.0
    spikes[0, 2, 0, 1] = 1.0
    with torch.no_grad():
        actor.decoder.weight.copy_(torch.tensor([[[1.0, -2.0]]]))
        actor.decoder.bias.fill_(0.1)
    output, voltages = actor.decoder(spikes)
    # X = [1.1, .1, -1.9, .1, .1]; V_t = .5 V_{t-1} + X_t
    expected, v = [], 0.0
    for x in [1.1, 0.1, -1.9, 0.1, 0.1]:
        v = 0.5 * v + x
        expected.append(v)
    assert voltages[0, :, 0, 0].tolist() == pytest.approx(expected)
    assert float(output.detach()) == pytest.approx(expected[-1])


def test_firing_rate_decoder():
    actor = make(small(preset="popsan", population_out=2), action_dim=1)
    spikes = torch.zeros(1, 5, 1, 2)
    spikes[0, :2, 0, 0] = 1.0  # rate 0.4
    spikes[0, :, 0, 1] = 1.0  # rate 1.0
    with torch.no_grad():
        actor.decoder.weight.copy_(torch.tensor([[[2.0, 0.5]]]))
        actor.decoder.bias.fill_(-0.1)
    output, voltages = actor.decoder(spikes)
    assert voltages is None
    assert float(output.detach()) == pytest.approx(2.0 * 0.4 + 0.5 * 1.0 - 0.1)


SWITCHES = [
    *[dict(preset=p) for p in PRESETS],
    *[dict(intra=v) for v in INTRA_VARIANTS],
    *[dict(decoder=d, alpha_v_li=a) for d, a in itertools.product(["last", "max", "mean", "fr"], [1.0, 0.5])],
    *[dict(encoder=e) for e in ["pop-det", "pop", "layer", "two-neuron"]],
    *[dict(hidden_layers=n, hidden_width=16) for n in (1, 3, 4)],
    dict(neuron="dynamic"),
    dict(intra_timing="authors"), dict(intra_timing="authors", intra="self+bias", neuron="dynamic"),
]


@pytest.mark.parametrize("switches", SWITCHES, ids=lambda s: ",".join(f"{k}={v}" for k, v in s.items()))
def test_fast_engine_equals_reference_engine(switches):
    switches = dict(switches)
    preset = switches.pop("preset", "ilc-san")
    if "hidden_layers" not in switches:
        switches.setdefault("hidden", (24, 16))
    actor = make(actor_config(preset, **switches), state_dim=4, action_dim=3, seeds=(0, 7))
    state = torch.randn(2, 32, 4, generator=torch.Generator().manual_seed(1)) * 1.5
    fast, reference = actor.run(state, "fast", membranes=True), actor.run(state, "reference", membranes=True)
    assert torch.allclose(fast.action, reference.action, atol=1e-5)
    assert torch.allclose(fast.readout, reference.readout, atol=1e-5)
    if fast.output_spikes is not None:
        assert fast.output_spikes.mean() > 0.01, "the case should make neurons spike"
        assert torch.equal(fast.output_spikes, reference.output_spikes)
        assert torch.allclose(fast.membranes, reference.membranes, atol=1e-5)
    grads = []
    for engine in ("fast", "reference"):
        actor.zero_grad()
        (actor.run(state, engine).action ** 2).sum().backward()
        grads.append([p.grad.clone() for p in actor.parameters()])
    for g_fast, g_reference in zip(*grads, strict=True):
        assert torch.allclose(g_fast, g_reference, atol=1e-4, rtol=1e-3)


@pytest.mark.parametrize("preset", ["ilc-san", "popsan", "dan"])
def test_engine_is_a_read_only_constructor_argument(preset):
    state = torch.randn(1, 8, 3, generator=torch.Generator().manual_seed(2))
    default = make(small(preset))
    reference = build_actor(small(preset), 3, 2, [1.0, 1.0], engine="reference")
    assert default.engine == "fast" and reference.engine == "reference"
    assert torch.allclose(reference(state), default(state), atol=1e-5)  # same seed: same weights, same actions
    with pytest.raises(AttributeError):
        default.engine = "reference"
    with pytest.raises(UserError, match="--engine"):
        build_actor(small(preset), 3, 2, [1.0, 1.0], engine="slow")
    with pytest.raises(UserError, match="--engine"):
        default.run(state, "slow")


def test_reference_engine_uses_the_decoders_step_and_readout(monkeypatch):
    """The oracle has no decoder arithmetic of its own: replacing the decoder's operations changes both engines."""
    from ilcsan.snn.decoders import PopulationDecoder

    actor = make(small(decoder="mean", alpha_v_li=0.5))
    state = torch.randn(1, 8, 3, generator=torch.Generator().manual_seed(3))
    before = actor.run(state, "reference").action
    monkeypatch.setattr(PopulationDecoder, "readout",
                        lambda self, spikes, voltages, perturbation=None: voltages.sum(dim=1) + 7.0)
    after = {engine: actor.run(state, engine).action for engine in ("fast", "reference")}
    assert not torch.allclose(before, after["reference"])
    assert torch.allclose(after["fast"], after["reference"], atol=1e-5)


@pytest.mark.parametrize("switches", [dict(), dict(preset="akl"), dict(encoder="layer"), dict(preset="dan")],
                         ids=lambda s: ",".join(f"{k}={v}" for k, v in s.items()) or "ilc-san")
def test_layer_widths_come_from_the_config(switches):
    switches = dict(switches)
    config = actor_config(switches.pop("preset", "ilc-san"), **switches)
    actor = make(config, state_dim=5, action_dim=2)
    layers = actor.mlp.layers if config.network == "deep" else actor.layers
    widths = [layers[0].in_features, *(layer.out_features for layer in layers)]
    assert widths == config.layer_sizes(5, 2)


def test_seed_slice_of_an_ensemble_equals_a_single_seed_actor():
    config = small()
    many, single = make(config, seeds=(3, 5, 9)), make(config, seeds=(5,))
    for (name, p_many), (_, p_single) in zip(many.named_parameters(), single.named_parameters(), strict=True):
        assert torch.equal(p_many[1], p_single[0]), name
    state = torch.randn(1, 8, 3)
    assert torch.allclose(many(state.expand(3, 8, 3))[1], single(state)[0], atol=1e-6)
    assert not torch.equal(many.layers[0].weight[0], many.layers[0].weight[1])


def test_actions_respect_asymmetric_bounds():
    actor = build_actor(small(), 3, 2, action_scale=[2.0, 0.5], action_offset=[1.0, -1.0])
    actions = actor(torch.randn(1, 256, 3) * 3)[0]
    assert torch.all(actions[:, 0] >= -1.0) and torch.all(actions[:, 0] <= 3.0)
    assert torch.all(actions[:, 1] >= -1.5) and torch.all(actions[:, 1] <= -0.5)


def test_dan_is_an_mlp_with_tanh():
    actor = make(actor_config("dan"), state_dim=5, action_dim=2)
    assert [tuple(layer.weight.shape[1:]) for layer in actor.mlp.layers] == [(256, 5), (256, 256), (2, 256)]
    state = torch.randn(1, 4, 5)
    hidden = state
    for index, layer in enumerate(actor.mlp.layers):
        hidden = hidden @ layer.weight[0].T + layer.bias[0]
        hidden = torch.relu(hidden) if index < 2 else torch.tanh(hidden)
    assert torch.allclose(actor(state), hidden, atol=1e-6)


@pytest.mark.parametrize("overrides, message", [
    (dict(intra="diagonal"), "--intra"),
    (dict(decoder="median"), "--decoder"),
    (dict(encoder="rate"), "--encoder"),
    (dict(hidden_width=0), "at least 1"),
    (dict(hidden_layers=5), "1 to 4"),
    (dict(alpha_v_li=1.5), "decay factor"),
    (dict(timesteps=0), "at least 1"),
])
def test_bad_switch_values_are_user_errors(overrides, message):
    with pytest.raises(UserError, match=message):
        actor_config("ilc-san", **overrides)


def test_unknown_preset():
    with pytest.raises(UserError, match="unknown actor preset"):
        actor_config("snn")


@pytest.mark.parametrize("bias", [True, False])
def test_ensemble_linear_gradients_equal_autograds_generic_rule_in_the_weights_layout(bias):
    from ilcsan.snn.ensemble import EnsembleLinear

    layer = EnsembleLinear(3, 5, 4, bias=bias)
    layer.reset_parameters([torch.Generator().manual_seed(seed) for seed in range(3)])
    inputs = torch.randn(3, 2, 6, 5, generator=torch.Generator().manual_seed(4), requires_grad=True)
    upstream = torch.randn(3, 2, 6, 4, generator=torch.Generator().manual_seed(5))
    (layer(inputs) * upstream).sum().backward()
    weight = layer.weight.detach().clone().requires_grad_()
    bias_copy = layer.bias.detach().clone().requires_grad_() if bias else None
    inputs_copy = inputs.detach().clone().requires_grad_()
    flat = inputs_copy.reshape(3, -1, 5)
    generic = torch.bmm(flat, weight.transpose(1, 2)) + (bias_copy.unsqueeze(1) if bias else 0)
    (generic.reshape(3, 2, 6, 4) * upstream).sum().backward()
    torch.testing.assert_close(layer(inputs), generic.reshape(3, 2, 6, 4))
    torch.testing.assert_close(inputs.grad, inputs_copy.grad)
    torch.testing.assert_close(layer.weight.grad, weight.grad)
    assert layer.weight.grad.is_contiguous()  # no transposed view for AccumulateGrad to copy
    if bias:
        torch.testing.assert_close(layer.bias.grad, bias_copy.grad)
