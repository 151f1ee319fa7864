"""Event-driven synaptic layers: a spike selects its neuron's outgoing weights, which are added (SOP).

FC1 … FC(L+1) (Algorithm 1, W^l S_t^{l−1}) and the intra FC (Eq. (10)) use :func:`dense_accumulator`, one
step at a time; the population decoder's group FC (X_t^m = W_D^m S_t^{L,m} + b_D^m) uses
:func:`accumulate_steps` over the whole spike train. Nothing is multiplied by a spike.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np


class Synapses(NamedTuple):
    """An event-driven synaptic layer: presynaptic neuron i projects with the weights in row ``weights[i]``.

    ``weights`` is (Din, F) float32 (or int8 with ``scale``): row i holds neuron i's outgoing weights.
    ``targets`` is None for a row over all ``out_dim`` postsynaptic neurons in order (F = out_dim), else
    (Din, F) postsynaptic indices. ``fan_out`` is the number of synapses a spike drives — one spike =
    ``fan_out`` SOP. It is F, except for the intra-layer connections, whose rows are the block-diagonal
    columns over the whole output layer (zeros outside the population and outside the ablation mask) while
    ``fan_out`` counts only the kept synapses of the population.
    """

    name: str
    weights: np.ndarray
    targets: np.ndarray | None
    scale: float | None
    bias: np.ndarray
    out_dim: int
    fan_out: int


def dense_accumulator(synapses: Synapses) -> Callable[[np.ndarray, np.ndarray], None]:
    """``add(spikes, out)``: out ← Σ_{i: spikes[i]} weights[i] for a dense layer, spikes a 0/1 (bool) vector.

    The weight rows of the neurons that spiked are selected (``compress``) and added; nothing is
    multiplied by a spike. int8 rows are added in int32 (exact) and the sum scaled once.
    """
    weights = synapses.weights
    if synapses.scale is None:
        def add(spikes: np.ndarray, out: np.ndarray) -> None:
            np.add.reduce(weights.compress(spikes, axis=0), axis=0, out=out)
        return add
    scale = np.float32(synapses.scale)
    integer_sum = np.empty(synapses.out_dim, np.int32)

    def add_int8(spikes: np.ndarray, out: np.ndarray) -> None:
        np.add.reduce(weights.compress(spikes, axis=0), axis=0, dtype=np.int32, out=integer_sum)
        np.multiply(integer_sum, scale, out=out, casting="same_kind")
    return add_int8


def accumulate_steps(synapses: Synapses, spikes: np.ndarray) -> tuple[np.ndarray, int]:
    """Sparse layer over all T steps at once: (T, Din) 0/1 spikes → ((T, out_dim) float32 incl. bias, SOP).

    Every event (t, i) adds each of neuron i's weights into bin (t, target); one ``bincount`` serves the
    whole spike train (used for the population decoder's Group FC).
    """
    timesteps = spikes.shape[0]
    step_index, neuron_index = np.nonzero(spikes)
    bins = (step_index[:, None] * synapses.out_dim + synapses.targets[neuron_index]).ravel()
    sums = np.bincount(bins, weights=synapses.weights[neuron_index].ravel(),
                       minlength=timesteps * synapses.out_dim)
    if synapses.scale is not None:
        sums = sums * synapses.scale
    currents = sums.astype(np.float32).reshape(timesteps, synapses.out_dim) + synapses.bias
    return currents, int(neuron_index.size) * synapses.fan_out
