"""The actor's spiking part as a NIR graph (``nir`` package), in seconds, for third-party consumers.

Layout: ``input`` (D_0 = N·P_in spikes per step) → ``layer1_fc`` Affine → ``layer1_lif`` CubaLIF → … →
``layer{L+1}_fc`` → ``layer{L+1}_lif`` (the M·P_out output population) → ``decoder`` Affine (block-diagonal: row m
holds W_D^m on population m, bias b_D) → [``li``: target ``generic`` only] → ``output``. The intra-layer
connections (Eq. (10)) are ``layer{L+1}_intra``, a block-diagonal nir.Linear on the recurrent edge lif ↔ intra. For
the ``fr`` decoder (PopSAN) the graph ends at the output population's spikes; the group FC stays on the host.
Norse 1.1.0 and snnTorch 1.0.0 (through NIRTorch 2.6) order the nodes by the edges, not by name (``nir.read``
returns them alphabetically; tests/test_nir_consumers.py runs both).

Targets. ``portable`` (default): the decoder's LI neuron (Eq. (7)) runs on the host — snnTorch 1.0.0, Norse 1.1.0
and SpikingJelly 2.0.0 map neither nir.LI nor nir.I — and the graph's output is its input X_t = W_D S_t + b_D per
step. ``generic``: the LI neuron is in the graph (nir.LI, or nir.I for α = 1) and the output is V_t. ``sinabs``: the
portable graph in the dialect Sinabs 3.1.3 reads (each CubaLIF as nir.LI then nir.LIF with τ in steps, the intra
Linear as an Affine, nir 1.0.4-readable; :mod:`.sinabs`). A target only adds a branch: the others' graphs stay as
they were (tests/data, test_nir_export.py).

CLIF → CubaLIF, from NIR's definition (nir 1.0.8): τ_syn dI/dt = −I + w_in S, τ_mem dv/dt = (v_leak − v) + R I,
z = [v > v_threshold], v ← v_reset on z. Forward Euler with step dt, the voltage using this step's current:
I_t = (1 − dt/τ_syn) I_{t−1} + (dt/τ_syn) w_in S_t, v_t = (1 − dt/τ_mem) v_{t−1} + (dt/τ_mem) R I_t. Matching
Eqs. (2)–(3), C_t = α_C C_{t−1} + X_t and H_t = α_V V_{t−1} + C_t, gives τ_syn = dt/(1 − α_C),
w_in = 1/(1 − α_C), τ_mem = dt/(1 − α_V), R = 1/(1 − α_V), v_leak = 0, hard reset to v_reset = 0. With
dt = 1e-4 s (``metadata["dt"]``; the step snnTorch's importer fixes): α_C = 0.5, α_V = 0.75 ⇔ τ_syn = 0.2 ms,
τ_mem = 0.4 ms, w_in = 2, R = 4 = τ_mem/dt (snnTorch asserts this). Time constants are computed in float32
as dt/(1 − α), so dt/τ is exactly 1 − α for the paper's values. The LI neuron V_t = α V_{t−1} + X_t is
nir.LI(τ = dt/(1 − α), R = 1/(1 − α)) and, for α = 1, nir.I(R = 1/dt).

With Algorithm 1's timing (``intra_timing`` "paper") b_intra acts from t = 2 on (no intra current at t = 1); a
recurrent Affine would add it at t = 1 too. A "clock" neuron at the end of the output population (zero weights,
bias V_th + 1 in the last fc: it spikes at every step) carries b_intra in its column of the intra matrix, so
through the recurrent edge's one-step delay b_intra arrives from t = 2 on, exactly. Present only when the mask
keeps the bias. With the authors' timing (``intra_timing`` "authors") b_intra acts at every step from t = 1, so it
is simply added to the output layer's fc bias and no clock is needed.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ...config import INTRA_MASKS, NIR_TARGETS
from ...errors import UserError
from ...files import atomic_write_file
from ..bundle import bundle_arrays, bundle_meta

FORMAT = "ilcsan-nir/2"
DT = 1e-4  # seconds per simulation step, graph.metadata["dt"]
TARGETS = tuple(NIR_TARGETS)
INPUT, DECODER, INTEGRATOR, OUTPUT = "input", "decoder", "li", "output"
"""The graph's input and output are named as NIR's own examples and consumers expect."""


def layer_names(index: int) -> tuple[str, str, str]:
    """Names of layer ``index`` (1-based): its Affine, its CubaLIF, its recurrent intra Linear."""
    return f"layer{index}_fc", f"layer{index}_lif", f"layer{index}_intra"


def _time_constant(alpha: float, dt: float, size: int) -> np.ndarray:
    return np.full(size, np.float32(dt) / np.float32(1.0 - alpha), np.float32)


def cubalif_parameters(alpha_current: float, alpha_voltage: float, threshold: float, size: int,
                       dt: float = DT) -> dict[str, np.ndarray]:
    """CubaLIF parameters whose Euler step (zero lag) is CLIF's (Eqs. (2)–(3)): τ_syn = dt/(1−α_C),
    w_in = 1/(1−α_C), τ_mem = dt/(1−α_V), R = 1/(1−α_V), v_leak = 0, v_reset = 0."""
    for name, alpha in (("alpha_c", alpha_current), ("alpha_v", alpha_voltage)):
        if not 0.0 <= alpha < 1.0:
            raise UserError(f"--{name.replace('_', '-')} {alpha} has no finite NIR time constant (needs 0 ≤ α < 1)")
    ones = np.ones(size, np.float32)
    return {"tau_syn": _time_constant(alpha_current, dt, size), "tau_mem": _time_constant(alpha_voltage, dt, size),
            "r": ones / np.float32(1 - alpha_voltage), "v_leak": 0 * ones, "v_threshold": ones * threshold,
            "v_reset": 0 * ones, "w_in": ones / np.float32(1 - alpha_current)}


def leaky_integrator(alpha: float, size: int, dt: float = DT):
    """Eq. (7), V_t = α V_{t−1} + X_t, as nir.LI(τ = dt/(1−α), R = 1/(1−α)), or nir.I(R = 1/dt) when α = 1."""
    import nir

    ones = np.ones(size, np.float32)
    if alpha == 1.0:
        return nir.I(r=ones / np.float32(dt))
    if not 0.0 <= alpha < 1.0:
        raise UserError(f"--alpha-v-li {alpha} must be in [0, 1]")
    return nir.LI(tau=_time_constant(alpha, dt, size), r=ones / np.float32(1 - alpha), v_leak=0 * ones)


def block_diagonal(blocks: np.ndarray) -> np.ndarray:
    """(M, a, b) blocks → (M·a, M·b) block-diagonal matrix."""
    populations, rows, cols = blocks.shape
    out = np.zeros((populations * rows, populations * cols), np.float32)
    for m in range(populations):
        out[m * rows:(m + 1) * rows, m * cols:(m + 1) * cols] = blocks[m]
    return out


def _check_exportable(policy, target: str) -> None:
    config = policy.actor_config
    if target not in TARGETS:
        raise UserError(f"--target {target!r} is not one of: {', '.join(TARGETS)}")
    if config.network != "spiking":
        raise UserError("a deep actor (DAN) has no spiking part to export to NIR; use --format npz")
    if config.neuron != "clif":
        raise UserError(f"neuron {config.neuron!r} (MDC-SAN's dynamic neuron) has no NIR primitive; NIR export "
                        "supports CLIF actors (CubaLIF)")


def build_graph(policy, target: str = "portable", dt: float = DT):
    """The actor's spiking part as a ``nir.NIRGraph`` (layout and targets: the module docstring)."""
    import nir

    _check_exportable(policy, target)
    config, actor = policy.actor_config, policy.actor
    if target == "sinabs":  # Sinabs's steps: the portable layout with dt = 1, rewritten (sinabs.py)
        from .sinabs import sinabs_dialect

        return sinabs_dialect(build_graph(policy, "portable", dt=1.0), config.alpha_c, config.alpha_v)
    arrays = bundle_arrays(policy)  # the actor's whole state, as every export reads it
    weights = [arrays[f"layers.{index}.weight"] for index in range(len(actor.layers))]
    biases = [arrays[f"layers.{index}.bias"] for index in range(len(actor.layers))]
    intra_bias = actor.intra is not None and INTRA_MASKS[config.intra].bias
    clock = intra_bias and not actor.intra.bias_at_first_step
    if intra_bias and not clock:  # the authors' timing: b_intra at every step, i.e. part of the output fc's bias
        biases[-1] = biases[-1] + arrays["intra.bias"].reshape(-1)
    if clock:  # the clock neuron: zero weights, bias V_th + 1 → spikes at every step
        weights[-1] = np.vstack([weights[-1], np.zeros((1, weights[-1].shape[1]), np.float32)])
        biases[-1] = np.append(biases[-1], np.float32(config.v_th + 1.0))
    nodes: dict[str, Any] = {INPUT: nir.Input(input_type=np.array([weights[0].shape[1]]))}
    edges, previous = [], INPUT
    for index, (weight, bias) in enumerate(zip(weights, biases, strict=True), start=1):
        fc, lif, _ = layer_names(index)
        nodes[fc] = nir.Affine(weight=weight, bias=bias)
        nodes[lif] = nir.CubaLIF(**cubalif_parameters(config.alpha_c, config.alpha_v, config.v_th, weight.shape[0], dt))
        edges += [(previous, fc), (fc, lif)]
        previous = lif
    width = weights[-1].shape[0]
    if actor.intra is not None:
        intra = layer_names(len(weights))[2]
        recurrent = np.zeros((width, width), np.float32)
        size = policy.action_dim * config.population_out
        recurrent[:size, :size] = block_diagonal(arrays["intra.weight"])
        if clock:
            recurrent[:size, size] = arrays["intra.bias"].reshape(-1)
        nodes[intra] = nir.Linear(weight=recurrent)
        edges += [(previous, intra), (intra, previous)]
    if config.decoder == "fr":
        nodes[OUTPUT] = nir.Output(output_type=np.array([width]))
        edges.append((previous, OUTPUT))
    else:
        decoder = block_diagonal(arrays["decoder.weight"][:, None, :])
        decoder = np.hstack([decoder, np.zeros((decoder.shape[0], width - decoder.shape[1]), np.float32)])
        nodes[DECODER] = nir.Affine(weight=decoder, bias=arrays["decoder.bias"])
        edges.append((previous, DECODER))
        previous = DECODER
        if target == "generic":
            nodes[INTEGRATOR] = leaky_integrator(config.alpha_v_li, policy.action_dim, dt)
            edges.append((DECODER, INTEGRATOR))
            previous = INTEGRATOR
        nodes[OUTPUT] = nir.Output(output_type=np.array([policy.action_dim]))
        edges.append((previous, OUTPUT))
    return nir.NIRGraph(nodes=nodes, edges=edges, metadata=host_metadata(policy, arrays, clock, target, dt))


def host_metadata(policy, arrays: dict[str, np.ndarray], clock: bool, target: str, dt: float) -> dict[str, Any]:
    """What the host computes around the graph: the deploy bundle's meta (:func:`~ilcsan.deploy.bundle.bundle_meta`:
    configuration, normaliser, action bounds) plus the graph's own facts, as the JSON string ``host``; the
    encoder's receptive fields and the ``fr`` decoder's weights as arrays, taken from the policy's bundle ``arrays``.
    ``dt`` (seconds) and ``timesteps`` are top-level keys: what a consumer must be given and how many steps to run."""
    config = policy.actor_config
    integrator = "none" if config.decoder == "fr" else ("graph" if target == "generic" else "host")
    host = dict(bundle_meta(policy), action_dim=policy.action_dim, clock_neuron=bool(clock), target=target,
                integrator=integrator, graph_output=OUTPUT,
                timing="Euler steps of dt seconds; feed-forward edges zero lag; the recurrent intra edge one step")
    metadata: dict[str, Any] = {"format": FORMAT, "dt": float(dt), "timesteps": config.timesteps,
                                "host": json.dumps(host)}
    if "encoder.mu" in arrays:
        metadata["encoder_mu"], metadata["encoder_sigma"] = arrays["encoder.mu"], arrays["encoder.sigma"]
    if config.decoder == "fr":
        metadata["decoder_weight"], metadata["decoder_bias"] = arrays["decoder.weight"], arrays["decoder.bias"]
    return metadata


def export_nir(policy, path: str | Path, target: str = "portable") -> Path:
    """Write the policy's spiking part as a NIR file (atomically) and return its path."""
    import nir

    graph = build_graph(policy, target)
    path = Path(path)
    write = nir.write
    if target == "sinabs":  # nir 1.0.4, Sinabs's pin, reads no v_reset
        from .sinabs import write_sinabs_graph as write
    atomic_write_file(path, lambda temporary: write(temporary, graph))
    return path
