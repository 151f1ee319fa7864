"""What one forward pass of an actor produced, for both engines and for analysis."""

from __future__ import annotations

from typing import NamedTuple

import torch

from .normalization import NormStatistics


class ActorOutput(NamedTuple):
    """Everything one forward pass produced.

    ``layer_inputs[l]`` is what synaptic layer l received: (K, T, B, D) spikes, or (K, B, D) for an
    analog input that is the same at every step. ``output_spikes`` (K, T, B, M·P_out) feeds the decoder
    (and the intra-layer connections at steps 1..T−1). ``voltages`` are the LI voltages (K, T, B, M).
    ``readout`` is O (K, B, M), the decoder's output before tanh (DAN: its last layer's). ``membranes``
    (K, T, B, M·P_out), only when asked for, is the potential each output neuron compared with V_th at each
    step (H_t of Eq. (5) for CLIF): where |H_t − V_th| < w the surrogate gradient passes. ``norm_statistics``,
    for a CaRe-BN actor only, holds per synaptic layer the (μ, σ²), each (K, D), its current was normalised with:
    the running statistics, given ones, or the batch's own (which carry gradients).
    """

    action: torch.Tensor
    layer_inputs: tuple[torch.Tensor, ...]
    output_spikes: torch.Tensor | None
    voltages: torch.Tensor | None
    readout: torch.Tensor | None = None
    membranes: torch.Tensor | None = None
    norm_statistics: tuple[NormStatistics, ...] | None = None
