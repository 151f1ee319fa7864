"""Event-driven synaptic layers: a spike selects its neuron's outgoing weights, which are added (SOP).

FC1 … FC(L+1) (Algorithm 1, W^l S_t^{l−1}) and the intra FC (Eq. (10)) use :func:`dense_accumulator`, one
step at a time; the population decoder's group FC (X_t^m = W_D^m S_t^{L,m} + b_D^m) uses
:func:`steps_accumulator` (or :func:`accumulate_steps`) over the whole spike train. Nothing is multiplied by a
spike.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

GROUP_FC = "Group FC"
"""The population decoder's synaptic layer (X_t^m = W_D^m S_t^{L,m} + b_D^m), named as in the paper's Tables fr and op
(also the energy analysis's name: :mod:`ilcsan.analysis.energy`)."""
INTRA_FC = "Intra FC"
"""The intra-layer connections' synaptic layer (Eq. (10)), named as in the paper's Tables fr and op."""


def fc_name(index: int) -> str:
    """The paper's name of the backbone's synaptic layer ``index`` (counted from 0): FC1 … FC(L+1)."""
    return f"FC{index + 1}"


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



def steps_accumulator(synapses: Synapses) -> Callable[[np.ndarray], tuple[np.ndarray, int]]:
    """``add(spikes)`` = ``accumulate_steps(synapses, spikes)``, faster for the population decoder's layout (neuron
    j of Din = M·P projects with one weight onto target j // P): each spike selects its weight (``where``, no
    multiply) in a (T, P, M) float64 table, and the P slots of every population are added in neuron order, as
    ``bincount`` adds the events (a silent neuron's 0.0 changes no sum). Any other layout uses
    :func:`accumulate_steps`."""
    din, out_dim = synapses.weights.shape[0], synapses.out_dim
    size = din // out_dim if out_dim else 0
    layout = (synapses.targets is not None and synapses.weights.shape[1] == 1 and size * out_dim == din
              and np.array_equal(synapses.targets[:, 0], np.repeat(np.arange(out_dim), size)))
    if not layout:
        return lambda spikes: accumulate_steps(synapses, spikes)
    table = np.ascontiguousarray(synapses.weights[:, 0].astype(np.float64).reshape(out_dim, size).T)  # (P, M)
    scale, bias, fan_out = synapses.scale, synapses.bias, synapses.fan_out

    def add(spikes: np.ndarray) -> tuple[np.ndarray, int]:
        selected = np.where(spikes.reshape(spikes.shape[0], out_dim, size).transpose(0, 2, 1), table, 0.0)
        sums = np.add.reduce(selected, axis=1)  # over the P slots, in order
        if scale is not None:
            sums *= scale
        currents = sums.astype(np.float32)
        currents += bias
        return currents, int(np.count_nonzero(spikes)) * fan_out
    return add
