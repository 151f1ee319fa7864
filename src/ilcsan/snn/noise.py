"""Where NoisySAN's perturbations (Chen, Peng, Huang, Tian, arXiv 2403.04162) enter a spiking actor's forward pass.

NoisySAN explores with noise inside the neurons, not on the action: :class:`NeuronNoise` carries one pass's
perturbations, already drawn and scaled, and the forward pass (:mod:`ilcsan.snn.actor`, :mod:`ilcsan.snn.reference`)
adds each where it says. The actor knows nothing of how they are drawn: the coloured series are
:mod:`ilcsan.rl.methods.coloured_noise`, their scales and their use in training :mod:`ilcsan.rl.methods.noisysan`.
"""

from __future__ import annotations

from typing import NamedTuple

import torch


class NeuronNoise(NamedTuple):
    """Additive perturbations of one forward pass of a spiking actor, already scaled, each (K, T, B, D).

    ``charge[l]`` is added to synaptic layer l's input current X_t^l before its neurons charge (on the output
    layer together with the intra-layer current); ``transmission[l]`` is added to the spikes S_t^l the layer
    passes on — to layer l + 1, to the output layer's intra-layer connections and to the decoder — while the
    neuron's own reset uses its clean spike; ``decoder`` is added to the decoder's drive X_t^m, the LI neuron's
    input (for PopSAN's firing-rate decoder, averaged over t with the drive).
    """

    charge: tuple[torch.Tensor, ...]
    transmission: tuple[torch.Tensor, ...]
    decoder: torch.Tensor
