"""Input coding of the actor: the population encoder and its alternatives (Section III-D, V-B).

``pop-det``   E_pop_det: Gaussian receptive fields, then deterministic soft-reset IF neurons (Eq. (9)),
              spikes straight-through w.r.t. the stimulation A (fully spiking; the default).
``pop-prob``  PopSAN's probabilistic variant: S_t ~ Bernoulli(A), straight-through (fully spiking).
``pop``       E_pop: the stimulation A itself at every step (analog input, not fully spiking).
``layer``     E_layer: the normalised state at every step (analog input, not fully spiking).
``two-neuron``Akl et al. 2023: (max(s, 0), max(−s, 0)) / clip at every step (analog input).

An encoder maps a normalised observation (K, B, N) to the input of the backbone over T steps. Analog
encoders return one (K, B, D) tensor that is the same at every step (the caller may compute its matmul
once); spiking encoders return (K, T, B, D). D is :meth:`ilcsan.config.ActorConfig.encoded_width`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import torch
from torch import nn

from ..config import ENCODERS, SPIKING_ENCODERS
from .neurons import EncoderParams, soft_reset_if_step, straight_through

__all__ = ["ENCODERS", "SPIKING_ENCODERS", "Encoder", "EncodedInput", "gaussian_stimulation",
           "deterministic_spike_train", "bernoulli_spike_train"]


class EncodedInput(NamedTuple):
    """Backbone input: spikes (K, T, B, D) when ``constant`` is False, else one (K, B, D) tensor."""

    values: torch.Tensor
    constant: bool


def gaussian_stimulation(state: torch.Tensor, mu: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """Eq. (9): A = exp(−½((s_i − μ)/σ)²), state (K, B, N), μ/σ (K, N, P) → A (K, B, N·P)."""
    z = (state.unsqueeze(-1) - mu.unsqueeze(1)) / sigma.unsqueeze(1)
    stimulation = torch.exp(-0.5 * z * z)
    return stimulation.flatten(-2)


def deterministic_spike_train(stimulation: torch.Tensor, timesteps: int, params: EncoderParams) -> torch.Tensor:
    """E_pop_det's second stage: soft-reset IF neurons driven by A for T steps → (K, T, B, D)."""
    voltage = torch.zeros_like(stimulation).detach()
    spikes = []
    for _ in range(timesteps):
        step_spikes, voltage = soft_reset_if_step(stimulation, voltage, params)
        voltage = voltage.detach()
        spikes.append(step_spikes)
    return torch.stack(spikes, dim=1)


def bernoulli_spike_train(stimulation: torch.Tensor, timesteps: int) -> torch.Tensor:
    """PopSAN's probabilistic encoding: S_t ~ Bernoulli(A) each step, ∂S/∂A = 1 → (K, T, B, D)."""
    probabilities = stimulation.clamp(0.0, 1.0).unsqueeze(1).expand(-1, timesteps, *stimulation.shape[1:])
    return straight_through(torch.bernoulli(probabilities.detach()), probabilities)


class Encoder(nn.Module):
    """One encoder module; ``kind`` selects the coding (an option, not a subclass)."""

    def __init__(self, kind: str, ensemble: int, state_dim: int, population: int, timesteps: int,
                 threshold: float, mu_range: float = 3.0, sigma: float = math.sqrt(0.15), clip: float = 3.0):
        super().__init__()
        self.kind, self.timesteps, self.clip = kind, timesteps, clip
        self.params = EncoderParams(threshold)
        self.mu_range, self.sigma_init = mu_range, sigma
        if kind.startswith("pop"):
            self.mu = nn.Parameter(torch.empty(ensemble, state_dim, population))
            self.sigma = nn.Parameter(torch.empty(ensemble, state_dim, population))
        else:
            self.mu = self.sigma = None

    @property
    def spiking(self) -> bool:
        return self.kind in SPIKING_ENCODERS

    def reset_parameters(self, generators: Sequence[torch.Generator]) -> None:
        """μ evenly spaced over [−range, range] per state dimension, σ constant (PopSAN's init)."""
        if self.mu is None:
            return
        population = self.mu.shape[-1]
        with torch.no_grad():
            self.mu.copy_(torch.linspace(-self.mu_range, self.mu_range, population).expand_as(self.mu))
            self.sigma.fill_(self.sigma_init)

    def forward(self, state: torch.Tensor) -> EncodedInput:
        """Normalised state (K, B, N) → backbone input."""
        if self.kind == "layer":
            return EncodedInput(state, True)
        if self.kind == "two-neuron":
            return EncodedInput(torch.cat([state.clamp(min=0), (-state).clamp(min=0)], -1) / self.clip, True)
        stimulation = gaussian_stimulation(state, self.mu, self.sigma)
        if self.kind == "pop":
            return EncodedInput(stimulation, True)
        if self.kind == "pop-det":
            return EncodedInput(deterministic_spike_train(stimulation, self.timesteps, self.params), False)
        return EncodedInput(bernoulli_spike_train(stimulation, self.timesteps), False)
