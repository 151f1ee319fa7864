"""The deployed neurons' state updates (the neuron core's work, not synaptic operations), numpy float32.

The same float32 operations, in the same order, as :func:`ilcsan.snn.neurons.clif_step` and
:func:`ilcsan.snn.neurons.dynamic_step`, so the deployed spikes equal the PyTorch actor's.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class CLIF(NamedTuple):
    """Current-based LIF with hard reset to 0 (Algorithm 1; PopSAN's constants by default)."""

    alpha_current: float = 0.5
    alpha_voltage: float = 0.75
    threshold: float = 0.5


class Dynamic(NamedTuple):
    """MDC-SAN's dynamic neuron (ilcsan.snn.neurons.dynamic_step), constants of the authors' comparison."""

    alpha_current: float = 0.5
    threshold: float = 0.5
    theta_v: float = -0.172
    theta_u: float = 0.529
    theta_r: float = 0.021
    theta_s: float = 0.132


def initial_state(neuron: CLIF | Dynamic, size: int) -> dict[str, np.ndarray]:
    """C_0 = 0, V_0 = V_reset = 0 (and u_0 = 0 for the dynamic neuron), float32."""
    names = ("current", "voltage") if isinstance(neuron, CLIF) else ("current", "voltage", "recovery")
    return {name: np.zeros(size, np.float32) for name in names}


def neuron_step(neuron: CLIF | Dynamic, state: dict[str, np.ndarray], drive: np.ndarray, previous: np.ndarray,
                fired: np.ndarray) -> None:
    """One step of the neurons whose state arrays (views) are ``state``, in place; writes S_t into ``fired``.

    CLIF (Algorithm 1, V_reset = 0): C = α_C C + X; H = α_V V + C; S = [H ≥ V_th]; V = H (1 − S).
    Dynamic (same operation order as the PyTorch step): ``previous`` holds S_{t−1}.
    """
    current, voltage = state["current"], state["voltage"]
    if isinstance(neuron, CLIF):
        current *= np.float32(neuron.alpha_current)
        current += drive
        voltage *= np.float32(neuron.alpha_voltage)
        voltage += current
        np.greater_equal(voltage, np.float32(neuron.threshold), out=fired)
        voltage[fired] = 0.0
        return
    recovery = state["recovery"]
    current[...] = np.float32(neuron.alpha_current) * current + drive
    reset_voltage = np.where(previous, np.float32(neuron.theta_r), voltage)
    reset_recovery = np.where(previous, recovery + np.float32(neuron.theta_s), recovery)
    voltage[...] = reset_voltage + (reset_voltage * reset_voltage - reset_voltage - reset_recovery + current)
    recovery[...] = reset_recovery + (np.float32(neuron.theta_v) * reset_voltage
                                      - np.float32(neuron.theta_u) * reset_recovery)
    np.greater_equal(voltage, np.float32(neuron.threshold), out=fired)
