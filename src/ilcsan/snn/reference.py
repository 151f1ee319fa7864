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

CaRe-BN (:mod:`ilcsan.snn.normalization`) normalises X_t^l = W^l S_t^{l−1} + b^l at each step with statistics fixed
for the whole pass (the intra-layer current and NoisySAN's charge come after it). The running or given statistics
are known before t = 1; a batch's own are not: they pool layer l's currents over all T steps, which the time loop
has produced only at its end. So with batch statistics this engine runs Algorithm 1 once per layer first: pass l
takes layer l's currents over t = 1..T, its layers before l normalised with the statistics the earlier passes found
(layer l's currents do not depend on layer l's statistics or any later layer's, which meanwhile use their running
ones), and pools them (:func:`~ilcsan.snn.normalization.batch_statistics`); a last pass uses them all. The
statistics are the time loop's own, not the layer-major engine's.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from .noise import NeuronNoise
from .normalization import NormStatistics, batch_statistics
from .output import ActorOutput


class _Pass(NamedTuple):
    """One run of Algorithm 1's time loop: its output and each layer's (un-normalised) currents X_t^l (K, B, D) in
    order of t."""

    output: ActorOutput
    currents: list[list[torch.Tensor]]


def run_reference(actor, state: torch.Tensor, noise: NeuronNoise | None = None, membranes: bool = False,
                  statistics: str | tuple[NormStatistics, ...] = "running") -> ActorOutput:
    """Normalised state (K, B, N) → :class:`ActorOutput` by Algorithm 1's time loop; ``noise`` adds NoisySAN's
    perturbations at each step where :class:`~ilcsan.snn.noise.NeuronNoise` says; ``membranes`` records the
    output layer's potentials; ``statistics`` (checked by the actor: "running" or the given statistics of
    the first layers, the others their batch's own) as in the module docstring."""
    encoded = actor.encoder(state)
    used = None
    if actor.norms is not None:
        used = [norm.running() for norm in actor.norms] if statistics == "running" else list(statistics)
        for index in range(len(used), len(actor.layers)):
            placeholders = used + [norm.running() for norm in list(actor.norms)[index:]]
            currents = _algorithm_1(actor, encoded, noise, False, placeholders).currents[index]
            used.append(batch_statistics(torch.stack(currents, dim=1)))
    return _algorithm_1(actor, encoded, noise, membranes, used).output


def _algorithm_1(actor, encoded, noise: NeuronNoise | None, membranes: bool,
                 statistics: list[NormStatistics] | None) -> _Pass:
    """One pass of the time loop; ``statistics`` normalise each layer's current (None: the actor has no CaRe-BN)."""
    neuron, decoder, intra = actor.neuron, actor.decoder, actor.intra
    last = len(actor.layers) - 1
    timesteps = actor.config.timesteps
    layer_states: list = [None] * len(actor.layers)
    inputs: list[list[torch.Tensor]] = [[] for _ in actor.layers]
    currents: list[list[torch.Tensor]] = [[] for _ in actor.layers]
    output_spikes, voltages, recorded = [], [], []
    intra_current = voltage = None
    for t in range(timesteps):
        spikes = encoded.values if encoded.constant else encoded.values[:, t]
        for index, layer in enumerate(actor.layers):
            inputs[index].append(spikes)
            current = layer(spikes)
            currents[index].append(current)
            if statistics is not None:
                current = actor.norms[index](current, statistics[index])
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
    output = ActorOutput(actor.squash(readout), layer_inputs, spike_train, voltage_trace, readout,
                         torch.stack(recorded, dim=1) if membranes else None,
                         tuple(statistics) if statistics is not None else None)
    return _Pass(output, currents)
