"""The reference engine: Algorithm 1 of the paper, literally, one time step at a time.

for t = 1..T: for l = 1..L+1: X_t^l = W^l S_t^{l−1} + b^l (+ I_t on the output layer), then the neuron
step (Eq. (1)-(3)); then the intra-layer current I_{t+1} of Eq. (10) and the decoder's LI neuron V_t
(Eq. (7)); finally O = Stat(V_1..V_T) (Eq. (8)) and action = offset + scale · tanh(O).

``actor`` is a :class:`~ilcsan.snn.actor.SpikingActor`, whose ``run`` calls this function for
``engine="reference"``. This is the oracle its layer-major forward pass is tested against (equal up to float
rounding, values and gradients). It owns no arithmetic of its own: it calls the actor's synaptic layers, neuron
step, intra-layer module and the decoder's
:meth:`~ilcsan.snn.decoders.PopulationDecoder.voltage_step` and
:meth:`~ilcsan.snn.decoders.PopulationDecoder.readout`, only in Algorithm 1's order.
"""

from __future__ import annotations

import torch

from .noise import NeuronNoise
from .output import ActorOutput


def run_reference(actor, state: torch.Tensor, noise: NeuronNoise | None = None,
                  membranes: bool = False) -> ActorOutput:
    """Normalised state (K, B, N) → :class:`ActorOutput` by Algorithm 1's time loop; ``noise`` adds NoisySAN's
    perturbations at each step where :class:`~ilcsan.snn.noise.NeuronNoise` says; ``membranes`` records the
    output layer's potentials."""
    encoded = actor.encoder(state)
    neuron, decoder, intra = actor.neuron, actor.decoder, actor.intra
    last = len(actor.layers) - 1
    timesteps = actor.config.timesteps
    layer_states: list = [None] * len(actor.layers)
    inputs: list[list[torch.Tensor]] = [[] for _ in actor.layers]
    output_spikes, voltages, recorded = [], [], []
    intra_current = voltage = None
    for t in range(timesteps):
        spikes = encoded.values if encoded.constant else encoded.values[:, t]
        for index, layer in enumerate(actor.layers):
            inputs[index].append(spikes)
            current = layer(spikes)
            if index == last and t == 0 and intra is not None:
                intra_current = intra.first_current(current)
            if index == last and intra_current is not None:
                current = current + intra_current
            if noise is not None:
                current = current + noise.charge[index][:, t]
            if layer_states[index] is None:
                layer_states[index] = neuron.initial_state(current, neuron.params)
            if index == last and membranes:
                recorded.append(neuron.membrane(current, layer_states[index], neuron.params))
            spikes, layer_states[index] = neuron.step(current, layer_states[index], neuron.params)
            if noise is not None:
                spikes = spikes + noise.transmission[index][:, t]
        if intra is not None and t < timesteps - 1:
            intra_current = intra(spikes)
        output_spikes.append(spikes)
        if decoder.uses_voltages:
            voltage = decoder.voltage_step(spikes, voltage, None if noise is None else noise.decoder[:, t])
            voltages.append(voltage)
    spike_train = torch.stack(output_spikes, dim=1)
    voltage_trace = torch.stack(voltages, dim=1) if voltages else None
    layer_inputs = tuple(
        per_layer[0] if (index == 0 and encoded.constant) else torch.stack(per_layer, dim=1)
        for index, per_layer in enumerate(inputs)
    )
    readout = decoder.readout(spike_train, voltage_trace, None if noise is None else noise.decoder)
    return ActorOutput(actor.squash(readout), layer_inputs, spike_train, voltage_trace, readout,
                       torch.stack(recorded, dim=1) if membranes else None)
