"""Neuron dynamics of the paper as pure step functions.

Each neuron is a function ``step(input_current, state, params) -> (spikes, state)`` with its parameters
and state as small typed tuples; the ``nn.Module`` actors only hold weights and call these functions.
All tensors may carry any leading shape (ensemble, batch, ...).

Equations (paper, Section III-A and Algorithm 1):

* charging   H_t = f(V_{t-1}, X_t)                                   Eq. (1)
* firing     S_t = Θ(H_t − V_th)                                     Eq. (2)
* hard reset V_t = H_t (1 − S_t) + V_reset S_t                       Eq. (3)
* soft reset V_t = H_t − V_th S_t                                    Eq. (4)
* LIF        f(V, X) = α_V (V − V_reset) + V_reset + X               Eq. (5)
* LI         V_t = α_V (V_{t-1} − V_reset) + V_reset + X_t           Eq. (7)
* CLIF       C_t = α_C C_{t-1} + X_t, then LIF with X_t = C_t         (Algorithm 1)

Θ is the Heaviside step (Θ(x) = 1 for x ≥ 0); its gradient is replaced by the rectangular surrogate
Θ'(x) = 1 if |x| < w else 0 (Section III-D, w = 0.5).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import torch

from ..config import ActorConfig


class _RectangularSpike(torch.autograd.Function):
    """Heaviside forward, rectangular surrogate backward: ∂S/∂x = 1 where |x| < width."""

    @staticmethod
    def forward(x: torch.Tensor, width: float) -> torch.Tensor:  # noqa: D102
        return (x >= 0).to(x.dtype)

    @staticmethod
    def setup_context(ctx, inputs, output) -> None:  # noqa: D102
        x, width = inputs
        ctx.save_for_backward(x)
        ctx.width = width

    @staticmethod
    def backward(ctx, grad_output: torch.Tensor):  # noqa: D102
        (x,) = ctx.saved_tensors
        return grad_output * (x.abs() < ctx.width).to(grad_output.dtype), None


def heaviside_spike(x: torch.Tensor, surrogate_width: float) -> torch.Tensor:
    """Θ(x) with the rectangular surrogate gradient of window ``surrogate_width`` (Eq. (2), III-D)."""
    return _RectangularSpike.apply(x, surrogate_width)


def straight_through(hard: torch.Tensor, soft: torch.Tensor) -> torch.Tensor:
    """Value of ``hard``, gradient of ``soft`` (∂hard/∂soft := 1), as the population encoder uses."""
    return soft + (hard - soft).detach()


# --------------------------------------------------------------------------------------------- CLIF
V_RESET = 0.0
"""The reset voltage V_reset of every neuron (the paper's, Section IV-A)."""


class CLIFParams(NamedTuple):
    """Current-based LIF constants: α_C, α_V, V_th, V_reset and the surrogate window w (their values are the actor's
    configuration, :class:`~ilcsan.config.ActorConfig`; the paper's are its defaults)."""

    alpha_current: float
    alpha_voltage: float
    threshold: float
    reset: float
    surrogate_width: float


class CLIFState(NamedTuple):
    """Synaptic current C_{t-1} and membrane voltage V_{t-1}."""

    current: torch.Tensor
    voltage: torch.Tensor


def clif_initial_state(like: torch.Tensor, params: CLIFParams) -> CLIFState:
    """C_0 = 0, V_0 = V_reset (paper: V_0 = V_reset, S_0 = 0)."""
    return CLIFState(torch.zeros_like(like), torch.full_like(like, params.reset))


def clif_step(
    input_current: torch.Tensor, state: CLIFState, params: CLIFParams
) -> tuple[torch.Tensor, CLIFState]:
    """One CLIF step of Algorithm 1.

    C_t = α_C C_{t-1} + X_t        (X_t = W S_t^{l-1} + b (+ I_t on the output layer))
    H_t = α_V (V_{t-1} − V_reset) + V_reset + C_t                                     Eq. (5)
    S_t = Θ(H_t − V_th)                                                               Eq. (2)
    V_t = H_t (1 − S_t) + V_reset S_t                                                 Eq. (3)
    """
    current, charged = clif_charge(input_current, state, params)
    spikes = heaviside_spike(charged - params.threshold, params.surrogate_width)
    return spikes, CLIFState(current, clif_reset(charged, spikes, params))


def clif_charge(input_current: torch.Tensor, state: CLIFState,
                params: CLIFParams) -> tuple[torch.Tensor, torch.Tensor]:
    """C_t = α_C C_{t-1} + X_t and the charged voltage H_t = α_V (V_{t-1} − V_reset) + V_reset + C_t (Eq. (5))."""
    current = params.alpha_current * state.current + input_current
    return current, params.alpha_voltage * (state.voltage - params.reset) + params.reset + current


def clif_reset(charged: torch.Tensor, spikes: torch.Tensor, params: CLIFParams) -> torch.Tensor:
    """Hard reset, Eq. (3): V_t = H_t (1 − S_t) + V_reset S_t."""
    return charged * (1.0 - spikes) + params.reset * spikes


def _clif_train_forward(currents: torch.Tensor, params: CLIFParams) -> tuple[torch.Tensor, torch.Tensor]:
    """Currents X (K, T, B, D) → spikes S and charged voltages H, both (K, T, B, D), by :func:`clif_charge`."""
    state = clif_initial_state(currents[:, 0], params)
    spikes, charged = [], []
    for t in range(currents.shape[1]):
        current, charge = clif_charge(currents[:, t], state, params)
        fired = (charge - params.threshold >= 0).to(currents.dtype)
        state = CLIFState(current, clif_reset(charge, fired, params))
        spikes.append(fired)
        charged.append(charge)
    return torch.stack(spikes, dim=1), torch.stack(charged, dim=1)


def _clif_train_backward(grad_spikes: torch.Tensor, charged: torch.Tensor, params: CLIFParams) -> torch.Tensor:
    """∂L/∂X of a CLIF spike train, backpropagated through time from the saved H_t.

    With σ_t = 1[|H_t − V_th| < w] (the rectangular surrogate of ∂S_t/∂H_t) and, from Eq. (3),
    ∂V_t/∂H_t = (1 − S_t) + (V_reset − H_t) σ_t, going from t = T down to 1 (δV_T = δC_{T+1} = 0):
      δH_t = g_t σ_t + δV_t ∂V_t/∂H_t,   δC_t = δH_t + α_C δC_{t+1},   ∂L/∂X_t = δC_t,   δV_{t-1} = α_V δH_t.
    """
    grad_voltage = torch.zeros_like(grad_spikes[:, 0])
    grad_current = torch.zeros_like(grad_spikes[:, 0])
    grads = []
    for t in range(grad_spikes.shape[1] - 1, -1, -1):
        charge = charged[:, t]
        surrogate = ((charge - params.threshold).abs() < params.surrogate_width).to(grad_spikes.dtype)
        fired = (charge - params.threshold >= 0).to(grad_spikes.dtype)
        grad_charge = grad_spikes[:, t] * surrogate + grad_voltage * (1.0 - fired + (params.reset - charge) * surrogate)
        grad_current = grad_charge + params.alpha_current * grad_current
        grad_voltage = params.alpha_voltage * grad_charge
        grads.append(grad_current)
    grads.reverse()
    return torch.stack(grads, dim=1)


class _CLIFTrain(torch.autograd.Function):
    @staticmethod
    def forward(currents: torch.Tensor, params: CLIFParams) -> tuple[torch.Tensor, torch.Tensor]:  # noqa: D102
        return _clif_train_forward(currents, params)

    @staticmethod
    def setup_context(ctx, inputs, output) -> None:  # noqa: D102
        ctx.save_for_backward(output[1])
        ctx.params = inputs[1]
        ctx.mark_non_differentiable(output[1])

    @staticmethod
    def backward(ctx, grad_spikes: torch.Tensor, grad_charged: torch.Tensor | None):  # noqa: D102
        (charged,) = ctx.saved_tensors
        return _clif_train_backward(grad_spikes, charged, ctx.params), None


def clif_train(currents: torch.Tensor, params: CLIFParams) -> torch.Tensor:
    """T CLIF steps of one layer at once: currents (K, T, B, D) → spikes (K, T, B, D), from C_0 = 0, V_0 = V_reset.

    The same function as :func:`clif_step` applied T times (tested equal, values and surrogate gradients),
    with the backward pass written out (:func:`_clif_train_backward`) and only H_t saved, instead of autograd's
    generic graph of the step-by-step loop.
    """
    return _CLIFTrain.apply(currents, params)[0]


# ------------------------------------------------------------------------ MDC-SAN dynamic neuron
class DynamicParams(NamedTuple):
    """MDC-SAN's dynamic neuron (Zhang et al. 2022): α_C, V_th and w from the actor's configuration, and the θ
    constants of the authors' comparison."""

    alpha_current: float
    threshold: float
    surrogate_width: float
    theta_v: float = -0.172
    theta_u: float = 0.529
    theta_r: float = 0.021
    theta_s: float = 0.132


class DynamicState(NamedTuple):
    """Current C, voltage v, recovery u and last spike s of the dynamic neuron."""

    current: torch.Tensor
    voltage: torch.Tensor
    recovery: torch.Tensor
    spikes: torch.Tensor


def dynamic_initial_state(like: torch.Tensor, params: DynamicParams) -> DynamicState:
    """All state variables start at zero."""
    zeros = torch.zeros_like(like)
    return DynamicState(zeros, zeros, zeros, zeros)


def dynamic_step(
    input_current: torch.Tensor, state: DynamicState, params: DynamicParams
) -> tuple[torch.Tensor, DynamicState]:
    """One step of MDC-SAN's two-variable dynamic neuron (Zhang et al. 2022, the paper's Section V baseline).

    C_t = α_C C_{t-1} + X_t;   v̂ = v_{t-1}(1 − s_{t-1}) + θ_r s_{t-1};   û = u_{t-1} + θ_s s_{t-1}
    v_t = v̂ + (v̂² − v̂ − û + C_t);   u_t = û + (θ_v v̂ − θ_u û);   s_t = Θ(v_t − V_th)
    """
    current, reset_voltage, reset_recovery, voltage = _dynamic_charge(input_current, state, params)
    recovery = reset_recovery + (params.theta_v * reset_voltage - params.theta_u * reset_recovery)
    spikes = heaviside_spike(voltage - params.threshold, params.surrogate_width)
    return spikes, DynamicState(current, voltage, recovery, spikes)


def _dynamic_charge(input_current: torch.Tensor, state: DynamicState,
                    params: DynamicParams) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """C_t, v̂, û and the voltage v_t that :func:`dynamic_step` compares with the threshold."""
    current = params.alpha_current * state.current + input_current
    reset_voltage = state.voltage * (1.0 - state.spikes) + params.theta_r * state.spikes
    reset_recovery = state.recovery + params.theta_s * state.spikes
    voltage = reset_voltage + (reset_voltage * reset_voltage - reset_voltage - reset_recovery + current)
    return current, reset_voltage, reset_recovery, voltage


def dynamic_membrane(input_current: torch.Tensor, state: DynamicState, params: DynamicParams) -> torch.Tensor:
    """v_t of :func:`dynamic_step` for this input and state: the spike is Θ(v_t − V_th)."""
    return _dynamic_charge(input_current, state, params)[3]


def clif_membrane(input_current: torch.Tensor, state: CLIFState, params: CLIFParams) -> torch.Tensor:
    """H_t of :func:`clif_step` for this input and state (Eq. (5)): the spike is Θ(H_t − V_th)."""
    return clif_charge(input_current, state, params)[1]


# ------------------------------------------------------------------------------ the actor's neuron
NeuronParams = CLIFParams | DynamicParams
NeuronState = CLIFState | DynamicState


class NeuronModel(NamedTuple):
    """A spiking neuron as pure functions, so both engines of the actor fire by the same rule.

    ``step(X_t, state, params) -> (S_t, state)`` is one update (Eq. (1)-(3)); ``initial_state(like, params)``
    the state before t = 1; ``membrane(X_t, state, params)`` the potential that ``step`` compares with the
    threshold (H_t for CLIF), for diagnostics; ``train(X, params)`` (CLIF only, else None) runs all T steps of a
    layer at once and equals ``step`` applied T times.
    """

    step: Callable[[torch.Tensor, NeuronState, NeuronParams], tuple[torch.Tensor, NeuronState]]
    initial_state: Callable[[torch.Tensor, NeuronParams], NeuronState]
    params: NeuronParams
    membrane: Callable[[torch.Tensor, NeuronState, NeuronParams], torch.Tensor]
    train: Callable[[torch.Tensor, NeuronParams], torch.Tensor] | None = None


def neuron_model(config: ActorConfig) -> NeuronModel:
    """The neuron of ``config.neuron``: CLIF (the paper's) or MDC-SAN's dynamic neuron, with its constants."""
    if config.neuron == "dynamic":
        return NeuronModel(dynamic_step, dynamic_initial_state,
                           DynamicParams(alpha_current=config.alpha_c, threshold=config.v_th,
                                         surrogate_width=config.surrogate_width), dynamic_membrane)
    return NeuronModel(clif_step, clif_initial_state,
                       CLIFParams(config.alpha_c, config.alpha_v, config.v_th, V_RESET, config.surrogate_width),
                       clif_membrane, clif_train)


# ------------------------------------------------------------------------------------------- LI
def li_step(input_current: torch.Tensor, voltage: torch.Tensor, alpha_voltage: float,
            reset: float = 0.0) -> torch.Tensor:
    """Non-spiking leaky integrator, Eq. (7): V_t = α_V (V_{t-1} − V_reset) + V_reset + X_t."""
    return alpha_voltage * (voltage - reset) + reset + input_current


# ------------------------------------------------------------------------ soft-reset IF encoder
class EncoderParams(NamedTuple):
    """Deterministic soft-reset IF neurons of the population encoder: their threshold (``enc_v_th``)."""

    threshold: float


def soft_reset_if_step(
    stimulation: torch.Tensor, voltage: torch.Tensor, params: EncoderParams
) -> tuple[torch.Tensor, torch.Tensor]:
    """One step of E_pop_det's IF neuron: v ← v + A; S = [v > V_th]; v ← v − V_th·S (Eq. (4)).

    The spike is straight-through with respect to the stimulation strength A: ∂S_t/∂A = 1
    (Section III-D, "Population Encoder").
    """
    charged = voltage + stimulation
    hard = (charged > params.threshold).to(stimulation.dtype)
    spikes = straight_through(hard, stimulation)
    return spikes, charged - params.threshold * hard
