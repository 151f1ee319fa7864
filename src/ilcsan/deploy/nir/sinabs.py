"""Target ``sinabs``: the portable graph in the dialect Sinabs 3.1.3 reads (``sinabs.from_nir``, nir ≤ 1.0.4).

Sinabs 3.1.3 pins nir ≤ 1.0.4, which cannot read a node with ``v_reset`` (nir 1.0.8 writes one on every CubaLIF and
LIF), and maps neither nir.CubaLIF nor nir.Linear. Its layers step in whole steps: ExpLeak (from nir.LI) is
v_t = α v_{t−1} + x_t, LIF (from nir.LIF) the same followed by a spike at v ≥ θ, with α = exp(−1/τ), τ in steps and
the input not scaled (its importer requires r = 1 on nir.LI). So, from the ``portable`` graph, each CubaLIF
``layer{l}_lif`` becomes two nodes in a row:

* ``layer{l}_syn``: nir.LI(τ = −1/ln α_C, r = 1, v_leak = 0), Sinabs's C_t = α_C C_{t−1} + X_t (Eq. (2));
* ``layer{l}_lif``: nir.LIF(τ = −1/ln α_V, r = 1, v_leak = 0, v_threshold = V_th), H_t = α_V V_{t−1} + C_t
  (Eq. (3)), written without ``v_reset``;

the intra-layer nir.Linear becomes an nir.Affine with zero bias on the same recurrent edge (now into
``layer{L+1}_syn``), and ``metadata["dt"]`` is 1 (one step). Everything else — the Affine layers, the clock neuron,
the decoder, the LI integrator on the host, the host metadata — is the portable graph's, so the host side
(:func:`~.host.read_host`, :func:`~.host.host_encode`, :func:`~.host.host_decode`) is the same.

This is Sinabs's reading, not NIR's ODEs (under which the LI would be v += (x − v)/τ per step), and Sinabs's own
defaults differ from CLIF: a LIF layer emits floor(v/θ) spikes per step and resets by subtraction. The loader
(:func:`~.consumers.sinabs_module`) switches each LIF layer to one spike per step and a reset to 0
(``SingleSpike``, ``MembraneReset``), which is CLIF's Eq. (3)–(4); :func:`~.consumers.run_module` steps it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

SYNAPSE_SUFFIX = "_syn"
TIMING = ("Sinabs's whole steps (alpha = exp(-1/tau), tau in steps); feed-forward edges zero lag; the recurrent "
          "intra edge one step")


def steps_time_constant(alpha: float, size: int) -> np.ndarray:
    """τ in steps with exp(−1/τ) = α (Sinabs's decay), float32; α = 0 gives τ = 0 (Sinabs: exp(−inf) = 0)."""
    with np.errstate(divide="ignore"):
        tau = np.float32(-1.0) / np.log(np.float32(alpha)) if alpha > 0 else np.float32(0.0)
    return np.full(size, tau, np.float32)


def sinabs_dialect(portable, alpha_current: float, alpha_voltage: float):
    """The ``portable`` graph (written with dt = 1) rewritten for Sinabs: CubaLIF → LI + LIF, Linear → Affine
    with zero bias, host target ``sinabs`` (module docstring)."""
    import nir

    nodes, synapse = {}, {}
    for name, node in portable.nodes.items():
        if isinstance(node, nir.CubaLIF):
            size = node.v_threshold.shape[0]
            ones = np.ones(size, np.float32)
            synapse[name] = name.removesuffix("_lif") + SYNAPSE_SUFFIX
            nodes[synapse[name]] = nir.LI(tau=steps_time_constant(alpha_current, size), r=ones, v_leak=0 * ones)
            nodes[name] = nir.LIF(tau=steps_time_constant(alpha_voltage, size), r=ones, v_leak=0 * ones,
                                  v_threshold=node.v_threshold.astype(np.float32))
        elif isinstance(node, nir.Linear):
            nodes[name] = nir.Affine(weight=node.weight, bias=np.zeros(node.weight.shape[0], np.float32))
        else:
            nodes[name] = node
    edges = []
    for source, target in portable.edges:
        if target in synapse:
            edges.append((source, synapse[target]))
            if (synapse[target], target) not in edges:
                edges.append((synapse[target], target))
        else:
            edges.append((source, target))
    metadata = dict(portable.metadata)
    host = json.loads(metadata["host"])
    host.update(target="sinabs", timing=TIMING)
    metadata["host"] = json.dumps(host)
    return nir.NIRGraph(nodes=nodes, edges=edges, metadata=metadata)


def write_sinabs_graph(path: str | Path, graph) -> None:
    """``nir.write``, then the ``v_reset`` of every LIF node removed, so that nir 1.0.4 (Sinabs's pin) reads the
    file; nir 1.0.8 reads it back with v_reset = 0 (its default)."""
    import h5py
    import nir

    nir.write(path, graph)
    with h5py.File(path, "r+") as file:
        for group in file["node"]["nodes"].values():
            if group["type"][()] in (b"LIF", "LIF") and "v_reset" in group:
                del group["v_reset"]
