"""Population decoders (Section III-C/D): membrane-voltage coding and PopSAN's firing-rate decoder.

Each output population m (P_out spiking neurons) has a learnable group FC (P_out → 1), W_D^m, b_D^m:

* membrane-voltage coding: X_t^m = W_D^m S_t^{L,m} + b_D^m drives a non-spiking LI neuron
  V_t^m = α_V^LI (V_{t-1}^m − V_reset^LI) + V_reset^LI + X_t^m  (Eq. (7)), and the output is a statistic
  of V_1..V_T:  ``last`` O = V_T (Eq. (8a)), ``max`` O = V at argmax_t |V_t| (Eq. (8b)),
  ``mean`` O = (1/T) Σ_t V_t (Eq. (8c));
* ``fr`` (PopSAN, D_fr): O^m = W_D^m (1/T Σ_t S_t^{L,m}) + b_D^m — a floating-point matrix operation.

The action is act_limit · tanh(O) (the authors' code) — applied by the actor.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from ..config import DECODERS
from .ensemble import uniform_
from .neurons import li_step

__all__ = ["DECODERS", "PopulationDecoder", "select_statistic", "integrate_voltages"]


def select_statistic(voltages: torch.Tensor, statistic: str) -> torch.Tensor:
    """O = Stat(V_1, …, V_T) over dimension 1 of ``voltages`` (K, T, B, M) → (K, B, M)."""
    if statistic == "last":
        return voltages[:, -1]
    if statistic == "mean":
        return voltages.mean(dim=1)
    if statistic == "max":
        index = voltages.abs().argmax(dim=1, keepdim=True)
        return voltages.gather(1, index).squeeze(1)
    raise ValueError(f"unknown statistic {statistic!r}")


def integrate_voltages(inputs: torch.Tensor, alpha_voltage: float, reset: float = 0.0) -> torch.Tensor:
    """Run the LI neuron (Eq. (7)) over T steps: inputs X (K, T, B, M) → voltages V (K, T, B, M), V_0 = V_reset."""
    voltage = torch.full_like(inputs[:, 0], reset)
    voltages = []
    for t in range(inputs.shape[1]):
        voltage = li_step(inputs[:, t], voltage, alpha_voltage, reset)
        voltages.append(voltage)
    return torch.stack(voltages, dim=1)


class PopulationDecoder(nn.Module):
    """Group FC W_D (K, M, P), b_D (K, M) followed by the LI neuron or the firing rate.

    ``forward`` decodes a whole spike train; the step-by-step engine calls :meth:`voltage_step` at every t and
    :meth:`readout` at the end, the same two operations ``forward`` is made of.
    """

    def __init__(self, ensemble: int, populations: int, population_size: int, statistic: str,
                 alpha_voltage: float = 1.0, reset: float = 0.0):
        super().__init__()
        self.statistic, self.alpha_voltage, self.reset = statistic, alpha_voltage, reset
        self.weight = nn.Parameter(torch.empty(ensemble, populations, population_size))
        self.bias = nn.Parameter(torch.empty(ensemble, populations))

    @property
    def uses_voltages(self) -> bool:
        """True for the membrane-voltage decoders (Eq. (7)-(8)), False for PopSAN's firing rate."""
        return self.statistic != "fr"

    def reset_parameters(self, generators: Sequence[torch.Generator]) -> None:
        """U(−1/√P, 1/√P), like PopSAN's grouped 1-D convolution of kernel P."""
        bound = 1.0 / math.sqrt(self.weight.shape[-1])
        uniform_(self.weight, bound, generators)
        uniform_(self.bias, bound, generators)

    def group_fc(self, spikes: torch.Tensor) -> torch.Tensor:
        """X^m = W_D^m S^{L,m} + b_D^m for spikes (K, ..., M·P) → (K, ..., M)."""
        k, populations, size = self.weight.shape
        grouped = spikes.reshape(*spikes.shape[:-1], populations, size)
        weight = self.weight.reshape(k, *([1] * (spikes.dim() - 2)), populations, size)
        bias = self.bias.reshape(k, *([1] * (spikes.dim() - 2)), populations)
        return (grouped * weight).sum(-1) + bias

    def voltage_step(self, spikes: torch.Tensor, voltage: torch.Tensor | None,
                     perturbation: torch.Tensor | None = None) -> torch.Tensor:
        """One step of the LI neuron driven by the group FC, Eq. (7): spikes S_t (K, B, M·P) and V_{t−1}
        (None before t = 1, i.e. V_0 = V_reset) → V_t (K, B, M); ``perturbation`` (K, B, M) is added to the drive."""
        drive = self.group_fc(spikes)
        if perturbation is not None:
            drive = drive + perturbation
        voltage = torch.full_like(drive, self.reset) if voltage is None else voltage
        return li_step(drive, voltage, self.alpha_voltage, self.reset)

    def readout(self, spikes: torch.Tensor, voltages: torch.Tensor | None,
                perturbation: torch.Tensor | None = None) -> torch.Tensor:
        """O (K, B, M): Stat(V_1..V_T) of the voltages (Eq. (8)), or for ``fr`` the group FC of the firing
        rate of the spike train (K, T, B, M·P), plus the mean over t of the drive's ``perturbation`` (K, T, B, M)."""
        if not self.uses_voltages:
            output = self.group_fc(spikes.mean(dim=1))
            return output if perturbation is None else output + perturbation.mean(dim=1)
        return select_statistic(voltages, self.statistic)

    def forward(self, spikes: torch.Tensor,
                perturbation: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Output spikes (K, T, B, M·P) → (O (K, B, M), LI voltages (K, T, B, M) or None for ``fr``);
        ``perturbation`` (K, T, B, M) is added to the drive X_t (NoisySAN)."""
        voltages = None
        if self.uses_voltages:
            drive = self.group_fc(spikes)
            if perturbation is not None:
                drive = drive + perturbation
            voltages = integrate_voltages(drive, self.alpha_voltage, self.reset)
        return self.readout(spikes, voltages, perturbation), voltages
