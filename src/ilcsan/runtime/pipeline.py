"""The backbone's L spiking layers, run pipelined over T + L − 1 ticks on preallocated buffers."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .neurons import CLIF, Dynamic, initial_state, neuron_step
from .synapses import Synapses, dense_accumulator


class Tick(NamedTuple):
    """What one tick of the pipelined backbone touches: views into the :class:`Workspace` buffers.

    ``synapses``: (accumulate, presynaptic spikes, drive slice) for every active layer; ``intra``: (output
    spikes of the previous step, output drive slice) when the intra-layer current is added separately
    (int8 bundles; float bundles fold it into the output layer's accumulate, see :class:`Workspace`).
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

    Intra-layer connections (float weights): at tick τ the output layer L needs layer L−1's spikes of its
    step t and its own spikes of step t − 1 — both in ``history`` row τ − 1, in adjacent columns. So the
    output layer's accumulate runs over the stacked rows [FC(L+1) rows; intra rows] with that one
    presynaptic slice: I_t = W_intra S_{t−1} (Eq. (10)) is added by the same event-driven accumulate,
    and b_intra joins the output layer's bias from t = 2 on. At t = 1 the output spikes of step 0 are
    all zero (``reset``), so nothing is added — unless ``intra_bias_at_first_step`` (the authors' timing,
    :data:`INTRA_TIMINGS`), which adds b_intra from t = 1 on. int8 bundles keep a separate intra accumulate (its
    own scale; ``fold_intra=False`` keeps it separate for float weights too, for comparison).
    """

    def __init__(self, timesteps: int, layers: tuple[Synapses, ...], neuron: CLIF | Dynamic,
                 intra: Synapses | None, fold_intra: bool = True, intra_bias_at_first_step: bool = False):
        widths = [layer.out_dim for layer in layers]
        self.offsets = np.concatenate([[0], np.cumsum(widths)]).astype(int)
        last, total = len(layers) - 1, int(self.offsets[-1])
        self.encoded = np.zeros((timesteps, layers[0].weights.shape[0]), dtype=bool)
        self.history = np.zeros((timesteps + last, total), dtype=bool)
        self.neuron, self.intra_bias = neuron, (intra.bias if intra is not None else None)
        self.state = initial_state(neuron, total)
        drive = np.empty(total, np.float32)
        bias = np.concatenate([layer.bias for layer in layers]).astype(np.float32)
        columns = [slice(self.offsets[index], self.offsets[index + 1]) for index in range(last + 1)]
        accumulators = [dense_accumulator(layer) for layer in layers]
        folded = fold_intra and intra is not None and intra.scale is None and layers[last].scale is None
        intra_bias = bias
        if folded:  # one accumulate over [FC(L+1) rows; intra rows], presynaptic = columns L−1 and L
            stacked = np.ascontiguousarray(np.vstack([layers[last].weights, intra.weights]))
            accumulators[last] = dense_accumulator(layers[last]._replace(weights=stacked))
            intra_bias = bias.copy()
            intra_bias[columns[last]] += intra.bias
        first_intra_tick = last if intra_bias_at_first_step else last + 1  # the output layer's step t = 1 or 2
        self.ticks = []
        for tick in range(timesteps + last):
            first, final = max(0, tick - timesteps + 1), min(tick, last)
            synapses = tuple(
                (accumulators[index],
                 self._presynaptic(tick, index, columns, folded and index == last), drive[columns[index]])
                for index in range(first, final + 1))
            window = slice(self.offsets[first], self.offsets[final + 1])
            recurrence, tick_bias = None, bias
            if intra is not None and final == last and tick >= first_intra_tick:
                if folded:
                    tick_bias = intra_bias
                else:
                    recurrence = (self.history[tick - 1, columns[last]], drive[columns[last]])
            self.ticks.append(Tick(synapses, drive[window], tick_bias[window],
                                   {name: value[window] for name, value in self.state.items()},
                                   self.history[tick - 1, window], self.history[tick, window], recurrence))
        self.trains = [self.encoded] + [self.history[index:index + timesteps, columns[index]]
                                        for index in range(last + 1)]
        self.intra_current = np.empty(widths[-1], np.float32)
        self.add_intra = dense_accumulator(intra) if intra is not None and not folded else None
        self._clif, self._inline = None, all(layer.scale is None for layer in layers)
        if isinstance(neuron, CLIF):  # the ticks as plain tuples for the loop in run
            self._clif = (np.float32(neuron.alpha_current), np.float32(neuron.alpha_voltage),
                          np.float32(neuron.threshold), np.float32(0.0))
            # float weights: each layer's bound ``compress``, so that run adds the rows without a call per layer
            compress = [layer.weights.compress for layer in layers]
            if folded:
                compress[last] = stacked.compress
            self._plan = []
            for tick_index, tick in enumerate(self.ticks):
                first = max(0, tick_index - timesteps + 1)
                synapses = tick.synapses
                if self._inline:
                    synapses = tuple((compress[first + index], presynaptic, layer_drive)
                                     for index, (_, presynaptic, layer_drive) in enumerate(tick.synapses))
                self._plan.append((synapses, tick.drive, tick.bias, tick.state["current"], tick.state["voltage"],
                                   tick.fired, tick.intra))

    def _presynaptic(self, tick: int, index: int, columns: list[slice], folded: bool) -> np.ndarray:
        """Layer ``index``'s input at ``tick``: the encoder's spikes, or row tick − 1 of the layer below
        (and, folded, of the output layer itself: its previous step)."""
        if index == 0:
            return self.encoded[tick]
        if folded:
            return self.history[tick - 1, columns[index - 1].start:columns[index].stop]
        return self.history[tick - 1, columns[index - 1]]

    def reset(self) -> None:
        """V_0 = C_0 = 0, no spikes yet."""
        self.history.fill(False)
        for value in self.state.values():
            value.fill(0.0)

    def run(self) -> None:
        """Run the L spiking layers tick by tick from the spikes in ``encoded``: accumulate the spikes of the
        previous layer (and the intra-layer spikes) into each active layer's drive, add the biases, update
        the neurons. Every layer's spike train is then in :attr:`trains`."""
        self.reset()
        if self._clif is None:
            self._run_any_neuron()
            return
        alpha_current, alpha_voltage, threshold, zero = self._clif
        multiply, add, greater_equal, copyto, reduce = np.multiply, np.add, np.greater_equal, np.copyto, np.add.reduce
        inline = self._inline
        for synapses, drive, bias, current, voltage, fired, intra in self._plan:
            if inline:
                for compress, presynaptic, layer_drive in synapses:  # Σ of the spiking neurons' weight rows
                    reduce(compress(presynaptic, 0), 0, None, layer_drive)
            else:
                for accumulate, presynaptic, layer_drive in synapses:
                    accumulate(presynaptic, layer_drive)
            add(drive, bias, drive)
            if intra is not None:
                self._add_intra(*intra)
            # CLIF (Algorithm 1, V_reset = 0): C = α_C C + X; H = α_V V + C; S = [H ≥ V_th]; V = H (1 − S)
            multiply(current, alpha_current, current)
            add(current, drive, current)
            multiply(voltage, alpha_voltage, voltage)
            add(voltage, current, voltage)
            greater_equal(voltage, threshold, fired)
            copyto(voltage, zero, where=fired)

    def _run_any_neuron(self) -> None:
        for tick in self.ticks:
            for accumulate, presynaptic, layer_drive in tick.synapses:
                accumulate(presynaptic, layer_drive)
            drive = tick.drive
            drive += tick.bias
            if tick.intra is not None:
                self._add_intra(*tick.intra)
            neuron_step(self.neuron, tick.state, drive, tick.previous, tick.fired)

    def _add_intra(self, previous_output: np.ndarray, output_drive: np.ndarray) -> None:
        """I_t = W_intra S_{t−1} + b_intra (Eq. (10)), then X_t + I_t (the unfolded, int8 path)."""
        self.add_intra(previous_output, self.intra_current)
        self.intra_current += self.intra_bias
        output_drive += self.intra_current
