"""The backbone's L spiking layers, run pipelined over T + L − 1 ticks on preallocated buffers."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .neurons import CLIF, Dynamic, initial_state, neuron_step
from .synapses import Synapses, dense_accumulator


class Tick(NamedTuple):
    """What one tick of the pipelined backbone touches: views into the :class:`Workspace` buffers.

    ``synapses``: (accumulate, presynaptic spikes, drive slice) for every active layer; ``intra``: (output
    spikes of the previous step, output drive slice) when the intra-layer current applies.
    """

    synapses: tuple
    drive: np.ndarray
    bias: np.ndarray
    state: dict[str, np.ndarray]
    previous: np.ndarray
    fired: np.ndarray
    intra: tuple[np.ndarray, np.ndarray] | None


class Workspace:
    """Preallocated buffers of one actor and the plan of its T + L − 1 ticks (so an action allocates little).

    Pipelining: at tick τ, layer l (0-based) computes its step t = τ − l. Layer l at step t needs only
    layer l−1 at step t (computed at tick τ − 1) and its own state, so the result is Algorithm 1's; the
    neuron updates of all active layers are one vector operation per tick. ``history`` row τ holds the
    spikes every active layer emitted at tick τ; layer l's train is rows l .. l+T−1 of its columns.
    """

    def __init__(self, timesteps: int, layers: tuple[Synapses, ...], neuron: CLIF | Dynamic,
                 intra: Synapses | None):
        widths = [layer.out_dim for layer in layers]
        self.offsets = np.concatenate([[0], np.cumsum(widths)]).astype(int)
        last, total = len(layers) - 1, int(self.offsets[-1])
        self.encoded = np.zeros((timesteps, layers[0].weights.shape[0]), dtype=bool)
        self.history = np.zeros((timesteps + last, total), dtype=bool)
        self.neuron, self.intra_bias = neuron, (intra.bias if intra is not None else None)
        self.state = initial_state(neuron, total)
        drive = np.empty(total, np.float32)
        bias = np.concatenate([layer.bias for layer in layers]).astype(np.float32)
        accumulators = [dense_accumulator(layer) for layer in layers]
        columns = [slice(self.offsets[index], self.offsets[index + 1]) for index in range(last + 1)]
        self.ticks = []
        for tick in range(timesteps + last):
            first, final = max(0, tick - timesteps + 1), min(tick, last)
            synapses = tuple(
                (accumulators[index],
                 self.encoded[tick] if index == 0 else self.history[tick - 1, columns[index - 1]],
                 drive[columns[index]])
                for index in range(first, final + 1))
            window = slice(self.offsets[first], self.offsets[final + 1])
            recurrence = None
            if intra is not None and final == last and tick > last:
                recurrence = (self.history[tick - 1, columns[last]], drive[columns[last]])
            self.ticks.append(Tick(synapses, drive[window], bias[window],
                                   {name: value[window] for name, value in self.state.items()},
                                   self.history[tick - 1, window], self.history[tick, window], recurrence))
        self.trains = [self.encoded] + [self.history[index:index + timesteps, columns[index]]
                                        for index in range(last + 1)]
        self.intra_current = np.empty(widths[-1], np.float32)
        self.add_intra = dense_accumulator(intra) if intra is not None else None

    def reset(self) -> None:
        """V_0 = C_0 = 0, no spikes yet."""
        self.history.fill(False)
        for value in self.state.values():
            value.fill(0.0)

    def run(self) -> None:
        """Run the L spiking layers tick by tick from the spikes in ``encoded``: accumulate the spikes of the
        previous layer into each active layer's drive, add the biases and the intra-layer current, update
        the neurons. Every layer's spike train is then in :attr:`trains`."""
        self.reset()
        for tick in self.ticks:
            for add, presynaptic, layer_drive in tick.synapses:
                add(presynaptic, layer_drive)
            drive = tick.drive
            drive += tick.bias
            if tick.intra is not None:  # I_t = W_intra S_{t−1} + b_intra (Eq. (10)), then X_t + I_t
                previous_output, output_drive = tick.intra
                self.add_intra(previous_output, self.intra_current)
                self.intra_current += self.intra_bias
                output_drive += self.intra_current
            neuron_step(self.neuron, tick.state, drive, tick.previous, tick.fired)
