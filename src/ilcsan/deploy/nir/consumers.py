"""Load an exported graph into a third-party NIR consumer and run it for T steps (optional extra ``.[nir]``).

Measured with nir 1.0.8, nirtorch 2.6, snnTorch 1.0.0, Norse 1.1.0 and SpikingJelly 2.0.0 on torch 2.13
(tests/test_nir_consumers.py):

* Norse: ``norse.torch.from_nir(graph, dt=graph.metadata["dt"])`` runs every target-``portable`` graph as
  written (its CubaLIF is LIBox + LIFBox: zero lag, Euler; NIRTorch delays the recurrent edge one step).
* snnTorch: ``snntorch.import_nir.import_from_nir(graph)`` runs graphs without intra-layer connections
  (PopSAN). For the recurrent lif ↔ intra pair its importer rewrites the pair into a sub-graph whose input
  feeds the recurrent Linear instead of the neuron (``_create_rnn_subgraph``'s edge (input, w_rec)), so the
  neuron receives W_intra·(fc output) — a wrong function (docs/nir-snntorch-recurrent-bug.md). The
  workaround, :func:`snntorch_module`, maps the same nodes with snnTorch's own converter and lets NIRTorch
  execute the recurrent edge, skipping that rewrite.
* SpikingJelly: ``spikingjelly.activation_based.nir_exchange.import_from_nir(graph, dt=graph.metadata["dt"])``
  runs every target-``portable`` graph as written in its single-step mode (``step_mode="s"``, its default; its
  multi-step mode refuses recurrent graphs). It maps CubaLIF only when the parameters are uniform over the
  neurons and R = τ_mem/dt, w_in = τ_syn/dt, v_leak = 0, which ours are.
* Sinabs 3.1.3 (its own environment: it pins nir ≤ 1.0.4 and, through it, nirtorch 2.0.2): the target-``sinabs``
  graph (:mod:`.sinabs`) with :func:`sinabs_module`, ``sinabs.from_nir`` with each LIF layer switched to one spike
  per step and a reset to 0. Its layers keep their voltages between calls: load the graph again, or call
  ``sinabs.reset_states(module)``, before the next observation (:func:`run_module` is given a fresh module).

All four return NIRTorch graph modules called as ``output, state = module(spikes_t, state)``; the state carries
the recurrent edge's previous value, so it must be threaded through the T steps (:func:`run_module`).
"""

from __future__ import annotations

import numpy as np


def snntorch_module(graph):
    """The graph as snnTorch modules (Affine/Linear → torch.nn.Linear, CubaLIF → snntorch.Synaptic), wired by
    NIRTorch: snnTorch's converter without its recurrent sub-graph rewrite."""
    import nir
    import nirtorch
    from snntorch.import_nir import _nir_to_snntorch_module

    def convert(node):
        return _nir_to_snntorch_module(node, init_hidden=True)

    return nirtorch.nir_to_torch(graph, {nir.Affine: convert, nir.Linear: convert, nir.CubaLIF: convert})


def norse_module(graph):
    """The graph as Norse modules, with the graph's time step: ``norse.torch.from_nir(graph, dt=dt)``."""
    from norse.torch import from_nir

    return from_nir(graph, dt=float(graph.metadata["dt"]))


def spikingjelly_module(graph):
    """The graph as SpikingJelly modules, single-step, with the graph's time step."""
    from spikingjelly.activation_based.nir_exchange import import_from_nir

    return import_from_nir(graph, dt=float(graph.metadata["dt"]))


def sinabs_module(graph):
    """The target-``sinabs`` graph as Sinabs layers, one step per call: ``sinabs.from_nir(graph, num_timesteps=1)``
    with every spiking LIF layer set to ``SingleSpike`` and ``MembraneReset`` (one spike per step, reset to 0:
    CLIF's; Sinabs's defaults are several spikes and a reset by subtraction)."""
    import sinabs
    from sinabs.activation import MembraneReset, SingleSpike

    module = sinabs.from_nir(graph, num_timesteps=1)
    for layer in module.modules():
        if isinstance(layer, sinabs.layers.LIF) and layer.spike_fn is not None:  # ExpLeak is a LIF without spikes
            layer.spike_fn, layer.reset_fn = SingleSpike, MembraneReset()
    return module


def run_module(module, spikes: np.ndarray) -> np.ndarray:
    """Drive a NIRTorch graph module with spikes (T, D) or (T, B, D), one step per call, threading its state →
    the outputs (T, …) float32."""
    import torch

    inputs = torch.from_numpy(np.asarray(spikes, np.float32))
    state, outputs = None, []
    with torch.no_grad():
        for step in inputs:
            output, state = module(step, state)
            outputs.append(output.numpy())
    return np.stack(outputs)
