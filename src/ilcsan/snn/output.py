"""What one forward pass of an actor produced, for both engines and for analysis."""

from __future__ import annotations

from typing import NamedTuple

import torch

from .noise import NeuronNoise
from .normalization import NormStatistics, StatisticsChoice


class PassOptions(NamedTuple):
    """What a training method asks of one forward pass of an actor, beyond the states, in one object: the actor knows
    the kinds of request, not the methods that make them.

    ``noise``: perturbations of the neurons (:class:`~ilcsan.snn.noise.NeuronNoise`, NoisySAN's exploration; None:
    none), added after the normalisation. ``statistics``: which statistics a normalising actor's layers use
    (:data:`~ilcsan.snn.normalization.StatisticsChoice`: the running ones by default, CaRe-BN's actor loss the
    batch's own). ``record``: a list that receives the statistics each layer was normalised with
    (:attr:`ActorOutput.norm_statistics`): how the actor's loss hands its batch statistics to the update that follows
    it, since a functional call of the module reaches its ``forward`` only. ``preaction``: ``forward`` also returns the
    pre-tanh output O (K, B, M) (a loss term's input; SAC's mean and log-std)."""

    noise: NeuronNoise | None = None
    statistics: StatisticsChoice = "running"
    record: list | None = None
    preaction: bool = False


PLAIN_PASS = PassOptions()
"""A pass as the actor acts: no noise, running statistics, nothing recorded, the action alone."""


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
