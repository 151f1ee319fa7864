"""Neuron dynamics against hand-computed cases from the paper's equations (Eq. (1)-(7), Algorithm 1)."""

from __future__ import annotations

import math

import pytest
import torch

from ilcsan.config import ActorConfig
from ilcsan.snn.neurons import (
    CLIFParams,
    DynamicParams,
    EncoderParams,
    clif_initial_state,
    clif_step,
    clif_train,
    dynamic_initial_state,
    dynamic_step,
    heaviside_spike,
    li_step,
    neuron_model,
    soft_reset_if_step,
)

PAPER = ActorConfig()
"""The paper's constants: α_C 0.5, α_V 0.75, V_th 0.5, w 0.5 (ActorConfig's defaults), V_reset 0."""
CLIF = CLIFParams(PAPER.alpha_c, PAPER.alpha_v, PAPER.v_th, 0.0, PAPER.surrogate_width)
DYNAMIC = DynamicParams(PAPER.alpha_c, PAPER.v_th, PAPER.surrogate_width)


def run_clif(inputs: list[float], params: CLIFParams | None = None) -> tuple[list[float], list[float]]:
    params = CLIF if params is None else params
    state = clif_initial_state(torch.zeros(1), params)
    spikes, voltages = [], []
    for x in inputs:
        s, state = clif_step(torch.tensor([x]), state, params)
        spikes.append(float(s))
        voltages.append(float(state.voltage))
    return spikes, voltages


def test_clif_spikes_exactly_when_the_arithmetic_says():
    # X = 0.3 each step: C1 = .3, H1 = .3 (no spike, V1 = .3); C2 = .45, H2 = .75*.3 + .45 = .675 (spike,
    # V2 = 0); C3 = .525, H3 = .525 (spike); C4 = .5625 -> spike; ...
    spikes, voltages = run_clif([0.3, 0.3, 0.3])
    assert spikes == [0.0, 1.0, 1.0]
    assert voltages[0] == pytest.approx(0.3)
    assert voltages[1:] == [0.0, 0.0]


def test_clif_current_and_voltage_decay():
    # One pulse X1 = 0.2 then silence: C = .2, .1, .05; H = .2, .15 + .1 = .25, .1875 + .05 = .2375
    spikes, voltages = run_clif([0.2, 0.0, 0.0])
    assert spikes == [0.0, 0.0, 0.0]
    assert voltages == pytest.approx([0.2, 0.25, 0.2375])


def test_heaviside_fires_at_threshold_exactly():
    spikes, _ = run_clif([0.5])  # H = V_th: Θ(0) = 1 (paper: Θ(x) = 1 for x >= 0)
    assert spikes == [1.0]
    spikes, _ = run_clif([0.4999])
    assert spikes == [0.0]


def test_rectangular_surrogate_window():
    h = torch.tensor([-0.1, 0.01, 0.3, 0.5, 0.99, 1.0, 1.2], requires_grad=True)
    heaviside_spike(h - 0.5, 0.5).sum().backward()
    # ∂S/∂H = 1 iff |H - V_th| < 0.5
    assert h.grad.tolist() == [0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0]


def test_clif_hard_reset_to_custom_reset_voltage():
    params = CLIF._replace(reset=-0.2)
    state = clif_initial_state(torch.zeros(1), params)
    assert float(state.voltage) == pytest.approx(-0.2)
    s, state = clif_step(torch.tensor([1.0]), state, params)
    # H = .75 * (-.2 + .2) - .2 + 1.0 = .8 -> spike, V = V_reset
    assert float(s) == 1.0 and float(state.voltage) == pytest.approx(-0.2)


def test_clif_train_backward_by_hand():
    # X = (.3, .3), L = S_1 + S_2. Forward: H_1 = .3 (S_1 = 0, V_1 = .3), C_2 = .45, H_2 = .675 (S_2 = 1).
    # Both H within the surrogate window (|H - .5| < .5), so σ_1 = σ_2 = 1. Backward:
    # δH_2 = 1, δC_2 = 1, δV_1 = α_V δH_2 = .75; δH_1 = 1 + .75 ((1 - S_1) + (0 - H_1)) = 1.525,
    # δC_1 = δH_1 + α_C δC_2 = 2.025.
    currents = torch.tensor([0.3, 0.3]).reshape(1, 2, 1, 1).requires_grad_()
    spikes = clif_train(currents, CLIF)
    assert spikes.flatten().tolist() == [0.0, 1.0]
    spikes.sum().backward()
    assert currents.grad.flatten().tolist() == pytest.approx([2.025, 1.0])


@pytest.mark.parametrize("reset", [0.0, -0.2])
def test_clif_train_equals_the_step_loop_in_values_and_surrogate_gradients(reset):
    params = CLIF._replace(reset=reset)
    generator = torch.Generator().manual_seed(0)
    currents = torch.rand(2, 5, 3, 7, generator=generator) * 0.8
    upstream = torch.randn(2, 5, 3, 7, generator=generator)
    loop_input = currents.clone().requires_grad_()
    state = clif_initial_state(loop_input[:, 0], params)
    looped = []
    for t in range(5):
        step_spikes, state = clif_step(loop_input[:, t], state, params)
        looped.append(step_spikes)
    (torch.stack(looped, dim=1) * upstream).sum().backward()
    fused_input = currents.clone().requires_grad_()
    fused = clif_train(fused_input, params)
    (fused * upstream).sum().backward()
    assert torch.equal(fused, torch.stack(looped, dim=1).detach())
    assert 0 < float(fused.detach().mean()) < 1  # some neurons fire, some do not
    torch.testing.assert_close(fused_input.grad, loop_input.grad, atol=1e-6, rtol=1e-5)


def test_li_neuron_after_t_steps():
    # α = 1: V_T = Σ X_t; α = 0.5: V_t = .5 V_{t-1} + X_t
    inputs = [1.0, 0.0, 2.0, 0.0, -1.0]
    for alpha, expected in [(1.0, 2.0), (0.5, 1 * 0.5**4 + 2 * 0.5**2 - 1)]:
        v = torch.zeros(1)
        for x in inputs:
            v = li_step(torch.tensor([x]), v, alpha)
        assert float(v) == pytest.approx(expected)


def test_encoder_soft_reset_if_and_straight_through_gradient():
    # A = 0.4: v = .4, .8, 1.2 -> spike (v = .201), .601, 1.001 -> spike
    stimulation = torch.tensor([0.4], requires_grad=True)
    v = torch.zeros(1)
    spikes = []
    for _ in range(5):
        s, v = soft_reset_if_step(stimulation, v, EncoderParams(PAPER.enc_v_th))
        spikes.append(s)
    assert [float(s.detach()) for s in spikes] == [0.0, 0.0, 1.0, 0.0, 1.0]
    assert float(v.detach()) == pytest.approx(2.0 - 2 * 0.999, abs=1e-6)
    torch.stack(spikes).sum().backward()
    assert float(stimulation.grad) == 5.0  # ∂S_t/∂A = 1 at every step, spike or not


def test_dynamic_neuron_follows_its_equations():
    params = DYNAMIC
    state = dynamic_initial_state(torch.zeros(1), params)
    s1, state = dynamic_step(torch.tensor([0.4]), state, params)
    # C = .4, v̂ = 0, û = 0 -> v = 0 + (0 - 0 - 0 + .4) = .4 < .5, u = 0
    assert float(s1) == 0.0 and float(state.voltage) == pytest.approx(0.4) and float(state.recovery) == 0.0
    s2, state = dynamic_step(torch.tensor([0.4]), state, params)
    # C = .6, v̂ = .4, û = 0 -> v = .4 + (.16 - .4 - 0 + .6) = .76 -> spike; u = 0 + (-.172 * .4) = -.0688
    assert float(s2) == 1.0
    assert float(state.voltage) == pytest.approx(0.76)
    assert float(state.recovery) == pytest.approx(-0.0688)
    s3, state = dynamic_step(torch.tensor([0.0]), state, params)
    # after a spike: v̂ = θ_r = .021, û = -.0688 + .132 = .0632; C = .3
    v_hat, u_hat = 0.021, -0.0688 + 0.132
    expected_v = v_hat + (v_hat**2 - v_hat - u_hat + 0.3)
    assert float(state.voltage) == pytest.approx(expected_v)
    assert float(state.recovery) == pytest.approx(u_hat + (-0.172 * v_hat - 0.529 * u_hat))
    assert float(s3) == float(expected_v >= 0.5)


def test_gaussian_receptive_fields():
    from ilcsan.snn.encoders import Encoder

    encoder = Encoder("pop", 1, 2, 10, 5, threshold=PAPER.enc_v_th)
    encoder.reset_parameters([torch.Generator()])
    state = torch.tensor([[[0.0, 3.0]]])
    stimulation = encoder(state).values[0, 0]
    mu = torch.linspace(-3, 3, 10)
    sigma = math.sqrt(0.15)
    expected = torch.cat([torch.exp(-0.5 * ((0.0 - mu) / sigma) ** 2), torch.exp(-0.5 * ((3.0 - mu) / sigma) ** 2)])
    assert torch.allclose(stimulation, expected)
    assert float(stimulation[19].detach()) == pytest.approx(1.0)  # s = 3 sits on the last centre


def test_neuron_model_of_a_config_carries_its_constants():
    from ilcsan.config import actor_config

    clif = neuron_model(actor_config("ilc-san", alpha_c=0.25, alpha_v=0.5, v_th=0.75, surrogate_width=0.3))
    assert clif.step is clif_step and clif.initial_state is clif_initial_state and clif.train is clif_train
    assert clif.params == CLIFParams(0.25, 0.5, 0.75, 0.0, 0.3)
    dynamic = neuron_model(actor_config("mdc-san", alpha_c=0.25, v_th=0.75))
    assert dynamic.step is dynamic_step and dynamic.initial_state is dynamic_initial_state and dynamic.train is None
    assert (dynamic.params.alpha_current, dynamic.params.threshold) == (0.25, 0.75)
    assert dynamic.params.theta_v == DYNAMIC.theta_v == -0.172
