"""Export the spiking part of an actor as a NIR graph, and a small NIR interpreter to check it.

``export_nir(policy, path)`` writes a NIR (Neuromorphic Intermediate Representation, ``nir`` package)
HDF5 file; ``nir.read(path)`` gives the graph back, and ``nir_action(graph, observation)`` runs it with
:func:`simulate_nir` plus the host-side parts, reproducing ``policy.predict`` (tested: max abs error
≈ 1e-7 on random actors).

Graph (names as in the file)
----------------------------
``input`` (D_0) → ``fc1`` Affine → ``lif1`` CubaLIF → … → ``fc{L+1}`` Affine → ``lif{L+1}`` CubaLIF (the
M·P_out output population) → ``decoder`` Affine (block-diagonal: row m holds W_D^m on population m,
bias b_D) → ``li`` (nir.LI for α_V^LI < 1, nir.I for α_V^LI = 1) → ``output`` (M voltages per step).
The intra-layer connections (Eq. (10)) are ``intra``, a block-diagonal nir.Linear on a recurrent edge
``lif{L+1} → intra → lif{L+1}``. For the ``fr`` decoder the graph ends at the output population
(``output`` = its spikes) and the decoder stays on the host.

CLIF → CubaLIF, derived from NIR's definition (nir 1.0.8, ``nir/ir/neuron.py``):
τ_syn dI/dt = −I + w_in S and τ_mem dv/dt = (v_leak − v) + R I, z = [v > v_threshold], v ← v_reset on z.
Forward Euler with step dt, the voltage using the current of the same step:
I_t = (1 − dt/τ_syn) I_{t−1} + (dt/τ_syn) w_in S_t,  v_t = (1 − dt/τ_mem) v_{t−1} + (dt/τ_mem) R I_t.
Matching C_t = α_C C_{t−1} + X_t and H_t = α_V V_{t−1} + C_t gives
τ_syn = dt/(1 − α_C), w_in = 1/(1 − α_C), τ_mem = dt/(1 − α_V), R = 1/(1 − α_V), v_leak = 0, hard reset
v_reset = 0: α_C = 0.5, α_V = 0.75 ⇔ τ_syn = 2, w_in = 2, τ_mem = 4, R = 4 with dt = 1 (the paper's values;
all these coefficients are powers of two, so a float32 simulation is bit-exact). Likewise the LI neuron
V_t = α V_{t−1} + X_t is nir.LI(τ = dt/(1 − α), R = 1/(1 − α)) and, for α = 1, nir.I(R = 1/dt). α = 1 in a
CLIF (no leak) has no finite τ and is refused. Our spike is Θ(H − V_th) with Θ(0) = 1, NIR's is v > v_th:
they differ only when H equals the threshold exactly.

The intra-layer bias b_intra acts from t = 2 on (Algorithm 1: no I at t = 1). A recurrent Affine would add
it at t = 1 as well (W·S_0 + b with S_0 = 0), which is the authors' released code, not the paper. We
therefore add one "clock" neuron at the end of the output population: its row of ``fc{L+1}`` has zero
weights and bias V_th + 1, so it spikes at every step; its column of ``intra`` holds b_intra and its
column of ``decoder`` is zero. Through the one-step delay of the recurrent edge it delivers b_intra from
t = 2 on, exactly. (It appears only when the mask keeps the bias; its spikes are not part of the actor.)

Kept on the host (no NIR primitive; stored in the graph's ``metadata``): the frozen observation
normaliser; the Gaussian receptive fields A = exp(−½((s − μ)/σ)²) (μ, σ as arrays ``encoder_mu``,
``encoder_sigma``); the encoder's deterministic soft-reset IF (NIR's IF resets hard to v_reset);
the statistic O = Stat(V_1..V_T) (the graph outputs V_t at every step: ``last`` reads step T); the
firing-rate decoder ``fr``; and action = offset + scale · tanh(O). Metadata key ``host`` is a JSON string
with every constant, ``dt`` = 1 (one NIR time unit = one simulation step) and ``timesteps`` = T.

Timing conventions of NIR consumers (read before deploying)
-----------------------------------------------------------
The graph assumes *zero lag* on feed-forward edges (a spike emitted at step t reaches the next layer's
current and voltage at step t, as Algorithm 1 and snnTorch's ``Synaptic`` do) and a *one-step delay on
recurrent edges* (the intra current at t comes from spikes at t − 1; NIRTorch's recurrence support
feeds a module's previous output back, zeros at the first step). :func:`simulate_nir` implements exactly
that. Consumers differ:

* Norse integrates a step's input into the synaptic current *after* the voltage update (forward Euler
  with the old current), so every LIF/CubaLIF layer delays its input by one step (norse issues #325 and
  #370 — the latter asked by the paper's first author —, PR #326 added a no-delay variant). For a
  feed-forward chain this is a pure shift by one step per layer: read the output L + 2 steps later (T + L
  + 1 steps in all for D_last). The intra-layer recurrence then acts two steps later instead of one,
  which changes the function: on such a consumer use its no-delay neurons.
* NIRTorch supports recurrent edges only since PR #34 (2025; self-loops), multi-node recurrent graphs
  were fixed in PR #48 (norse #427), and snnTorch's nested graphs were flattened until NIRTorch PR #51.
* snnTorch's import of nir.CubaLIF was faulty (snnTorch #290, fixed by PR #435: it rescaled the threshold
  whenever w_in ≠ τ_syn/dt; our export sets w_in = τ_syn/dt exactly, so that rescaling is neutral);
  its import of nir.IF used β = 0 (#416, fixed by PR #452); the ``Synaptic`` forward pass had a state bug
  fixed in 0.9.4 (#350, #358). Scalar-valued neuron parameters broke ``input_type`` (snnTorch #334, NIR
  PR #107): we write every parameter as a per-neuron array.
* Norse's ``to_nir`` multiplied time constants by dt (norse #411): check τ after a round trip through it.

We verified the NIR definitions and the write/read round trip with the installed nir 1.0.8; the
consumer behaviours above are as reported in those issue threads (Norse, snnTorch and NIRTorch are not
installed here), so test a consumer on a few observations against ``policy.predict`` before trusting it.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..config import INTRA_MASKS
from ..errors import UserError
from ..files import atomic_write_file
from .bundle import bundle_meta
from .runtime.host import encode, normalize, select_statistic, squash

FORMAT = "ilcsan-nir/1"
DT = 1.0


# ------------------------------------------------------------------------------------ neurons
def cubalif_parameters(alpha_current: float, alpha_voltage: float, threshold: float, size: int,
                       dt: float = DT) -> dict[str, np.ndarray]:
    """CubaLIF parameters whose Euler step (zero lag) is CLIF's: τ_syn = dt/(1−α_C), w_in = 1/(1−α_C),
    τ_mem = dt/(1−α_V), R = 1/(1−α_V), v_leak = 0, v_reset = 0."""
    for name, alpha in (("alpha_c", alpha_current), ("alpha_v", alpha_voltage)):
        if not 0.0 <= alpha < 1.0:
            raise UserError(f"--{name.replace('_', '-')} {alpha} has no finite NIR time constant (needs 0 ≤ α < 1)")
    ones = np.ones(size, np.float32)
    return {"tau_syn": ones * dt / (1 - alpha_current), "tau_mem": ones * dt / (1 - alpha_voltage),
            "r": ones / (1 - alpha_voltage), "v_leak": 0 * ones, "v_threshold": ones * threshold,
            "v_reset": 0 * ones, "w_in": ones / (1 - alpha_current)}


def leaky_integrator(alpha: float, size: int, dt: float = DT):
    """V_t = α V_{t−1} + X_t as nir.LI(τ = dt/(1−α), R = 1/(1−α)), or nir.I(R = 1/dt) when α = 1."""
    import nir

    ones = np.ones(size, np.float32)
    if alpha == 1.0:
        return nir.I(r=ones / dt)
    if not 0.0 <= alpha < 1.0:
        raise UserError(f"--alpha-v-li {alpha} must be in [0, 1]")
    return nir.LI(tau=ones * dt / (1 - alpha), r=ones / (1 - alpha), v_leak=0 * ones)


def block_diagonal(blocks: np.ndarray) -> np.ndarray:
    """(M, a, b) blocks → (M·a, M·b) block-diagonal matrix."""
    populations, rows, cols = blocks.shape
    out = np.zeros((populations * rows, populations * cols), np.float32)
    for m in range(populations):
        out[m * rows:(m + 1) * rows, m * cols:(m + 1) * cols] = blocks[m]
    return out


# ------------------------------------------------------------------------------------- export
def _weights(tensor) -> np.ndarray:
    return tensor.detach()[0].cpu().numpy().astype(np.float32)


def _check_exportable(policy) -> None:
    config = policy.actor_config
    if config.network != "spiking":
        raise UserError("a deep actor (DAN) has no spiking part to export to NIR; use --format npz")
    if config.neuron != "clif":
        raise UserError(f"neuron {config.neuron!r} (MDC-SAN's dynamic neuron) has no NIR primitive; NIR export "
                        "supports CLIF actors (CubaLIF)")


def build_graph(policy):
    """The actor's spiking part as a ``nir.NIRGraph`` (see the module docstring for its layout)."""
    import nir

    _check_exportable(policy)
    config, actor = policy.actor_config, policy.actor
    weights = [_weights(layer.weight) for layer in actor.layers]
    biases = [_weights(layer.bias) for layer in actor.layers]
    mask = INTRA_MASKS[config.intra]
    clock = mask.bias
    if clock:  # the clock neuron: zero weights, bias V_th + 1 → spikes at every step
        weights[-1] = np.vstack([weights[-1], np.zeros((1, weights[-1].shape[1]), np.float32)])
        biases[-1] = np.append(biases[-1], np.float32(config.v_th + 1.0))
    nodes: dict[str, Any] = {"input": nir.Input(input_type=np.array([weights[0].shape[1]]))}
    edges = [("input", "fc1")]
    count = len(weights)
    for index, (weight, bias) in enumerate(zip(weights, biases, strict=True), start=1):
        nodes[f"fc{index}"] = nir.Affine(weight=weight, bias=bias)
        nodes[f"lif{index}"] = nir.CubaLIF(**cubalif_parameters(config.alpha_c, config.alpha_v, config.v_th,
                                                                weight.shape[0]))
        edges.append((f"fc{index}", f"lif{index}"))
        if index < count:
            edges.append((f"lif{index}", f"fc{index + 1}"))
    population = f"lif{count}"
    width = weights[-1].shape[0]
    if actor.intra is not None:
        recurrent = np.zeros((width, width), np.float32)
        size = policy.action_dim * config.population_out
        recurrent[:size, :size] = block_diagonal(_weights(actor.intra.masked_weight()))
        if clock:
            recurrent[:size, size] = _weights(actor.intra.masked_bias()).reshape(-1)
        nodes["intra"] = nir.Linear(weight=recurrent)
        edges += [(population, "intra"), ("intra", population)]
    if config.decoder == "fr":
        nodes["output"] = nir.Output(output_type=np.array([width]))
        edges.append((population, "output"))
    else:
        decoder = block_diagonal(_weights(actor.decoder.weight)[:, None, :])
        decoder = np.hstack([decoder, np.zeros((decoder.shape[0], width - decoder.shape[1]), np.float32)])
        nodes["decoder"] = nir.Affine(weight=decoder, bias=_weights(actor.decoder.bias))
        nodes["li"] = leaky_integrator(config.alpha_v_li, policy.action_dim)
        nodes["output"] = nir.Output(output_type=np.array([policy.action_dim]))
        edges += [(population, "decoder"), ("decoder", "li"), ("li", "output")]
    return nir.NIRGraph(nodes=nodes, edges=edges, metadata=host_metadata(policy, clock))


def host_metadata(policy, clock: bool) -> dict[str, Any]:
    """What the host computes around the graph: the deploy bundle's meta (:func:`~ilcsan.deploy.bundle.bundle_meta`:
    configuration, normaliser, action bounds) plus the graph's own facts, as the JSON string ``host``; the
    encoder's receptive fields and the ``fr`` decoder's weights as arrays."""
    actor = policy.actor
    host = dict(bundle_meta(policy), action_dim=policy.action_dim, clock_neuron=clock,
                timing="feed-forward edges zero lag; recurrent edge intra delayed one step; Euler, dt = 1")
    metadata: dict[str, Any] = {"format": FORMAT, "dt": DT, "timesteps": policy.actor_config.timesteps,
                                "host": json.dumps(host)}
    if actor.encoder.mu is not None:
        metadata["encoder_mu"] = _weights(actor.encoder.mu)
        metadata["encoder_sigma"] = _weights(actor.encoder.sigma)
    if policy.actor_config.decoder == "fr":
        metadata["decoder_weight"] = _weights(actor.decoder.weight)
        metadata["decoder_bias"] = _weights(actor.decoder.bias)
    return metadata


def export_nir(policy, path: str | Path) -> Path:
    """Write the policy's spiking part as a NIR file (atomically) and return its path."""
    import nir

    graph = build_graph(policy)
    path = Path(path)
    atomic_write_file(path, lambda temporary: nir.write(temporary, graph))
    return path


# -------------------------------------------------------------------------------- interpreter
def _evaluation_order(nodes: Mapping[str, Any], edges: list[tuple[str, str]]) -> tuple[list[str], set]:
    """Topological order of the nodes and the set of recurrent (back) edges, found by depth-first search
    from the inputs; a back edge carries the previous step's value."""
    import nir

    successors: dict[str, list[str]] = {name: [] for name in nodes}
    for source, target in edges:
        if source not in nodes or target not in nodes:
            raise UserError(f"NIR edge {source} → {target} names a node that does not exist")
        successors[source].append(target)
    back, visited, on_stack, finished = set(), set(), set(), []

    def visit(name: str) -> None:
        visited.add(name)
        on_stack.add(name)
        for target in successors[name]:
            if target in on_stack:
                back.add((name, target))
            elif target not in visited:
                visit(target)
        on_stack.discard(name)
        finished.append(name)

    for name, node in nodes.items():
        if isinstance(node, nir.Input) and name not in visited:
            visit(name)
    for name in nodes:
        if name not in visited:
            visit(name)
    return finished[::-1], back


def simulate_nir(graph, inputs: np.ndarray | Mapping[str, np.ndarray], dt: float = DT) -> dict[str, np.ndarray]:
    """Run a NIR graph for T steps: ``inputs`` (T, D) (or a dict per Input node) → {Output name: (T, …)}.

    Semantics: Euler steps of size ``dt`` with zero lag on feed-forward edges (a node sees its
    predecessors' outputs of the same step) and a one-step delay on recurrent edges (zeros at the first
    step); several incoming edges add. Supported nodes: Input, Output, Affine, Linear, Scale, CubaLIF,
    LIF, IF, LI, I. float32 throughout, like the actor.
    """
    import nir

    nodes, edges = graph.nodes, [tuple(edge) for edge in graph.edges]
    order, back = _evaluation_order(nodes, edges)
    input_names = [name for name, node in nodes.items() if isinstance(node, nir.Input)]
    if not isinstance(inputs, Mapping):
        if len(input_names) != 1:
            raise UserError(f"the graph has inputs {input_names}; pass a dict of arrays")
        inputs = {input_names[0]: inputs}
    inputs = {name: np.asarray(value, np.float32) for name, value in inputs.items()}
    timesteps = {value.shape[0] for value in inputs.values()}
    if len(timesteps) != 1:
        raise UserError("every input needs the same number of time steps")
    steps = timesteps.pop()
    incoming: dict[str, list[tuple[str, bool]]] = {name: [] for name in nodes}
    for source, target in edges:
        incoming[target].append((source, (source, target) in back))
    state: dict[str, dict[str, np.ndarray]] = {}
    previous: dict[str, np.ndarray] = {}
    records: dict[str, list[np.ndarray]] = {name: [] for name, node in nodes.items() if isinstance(node, nir.Output)}
    for t in range(steps):
        current: dict[str, np.ndarray] = {}
        for name in order:
            node = nodes[name]
            if isinstance(node, nir.Input):
                current[name] = inputs[name][t]
                continue
            terms = [(previous.get(source) if delayed else current[source]) for source, delayed in incoming[name]]
            terms = [term for term in terms if term is not None]
            drive = np.sum(terms, axis=0, dtype=np.float32) if terms else np.float32(0.0)
            current[name] = _node_step(node, drive, state.setdefault(name, {}), dt)
            if name in records:
                records[name].append(current[name])
        previous = current
    return {name: np.stack(values) for name, values in records.items()}


def _node_step(node, drive: np.ndarray, state: dict[str, np.ndarray], dt: float) -> np.ndarray:
    """One Euler step of one node (zero lag: a neuron's voltage uses this step's current)."""
    import nir

    f32 = np.float32
    if isinstance(node, nir.Output):
        return drive
    if isinstance(node, nir.Affine):
        return (node.weight.astype(f32) @ drive + node.bias.astype(f32)).astype(f32)
    if isinstance(node, nir.Linear):
        return (node.weight.astype(f32) @ drive).astype(f32)
    if isinstance(node, nir.Scale):
        return (node.scale.astype(f32) * drive).astype(f32)
    if isinstance(node, nir.CubaLIF):
        syn = f32(dt) / node.tau_syn.astype(f32)
        mem = f32(dt) / node.tau_mem.astype(f32)
        current = state.get("current", np.zeros_like(syn))
        voltage = state.get("voltage", np.zeros_like(mem) + node.v_leak.astype(f32))
        current = (1 - syn) * current + syn * (node.w_in.astype(f32) * drive)
        voltage = (1 - mem) * voltage + mem * (node.v_leak.astype(f32) + node.r.astype(f32) * current)
        return _fire(node, voltage, state, current=current)
    if isinstance(node, nir.LIF):
        mem = f32(dt) / node.tau.astype(f32)
        voltage = state.get("voltage", np.zeros_like(mem) + node.v_leak.astype(f32))
        voltage = (1 - mem) * voltage + mem * (node.v_leak.astype(f32) + node.r.astype(f32) * drive)
        return _fire(node, voltage, state)
    if isinstance(node, nir.IF):
        voltage = state.get("voltage", np.zeros(node.r.shape, f32)) + f32(dt) * node.r.astype(f32) * drive
        return _fire(node, voltage, state)
    if isinstance(node, nir.LI):
        mem = f32(dt) / node.tau.astype(f32)
        voltage = state.get("voltage", np.zeros_like(mem) + node.v_leak.astype(f32))
        state["voltage"] = (1 - mem) * voltage + mem * (node.v_leak.astype(f32) + node.r.astype(f32) * drive)
        return state["voltage"]
    if isinstance(node, nir.I):
        state["voltage"] = state.get("voltage", np.zeros(node.r.shape, f32)) + f32(dt) * node.r.astype(f32) * drive
        return state["voltage"]
    raise UserError(f"simulate_nir does not support NIR node type {type(node).__name__}")


def _fire(node, voltage: np.ndarray, state: dict[str, np.ndarray], **extra: np.ndarray) -> np.ndarray:
    """z = [v > v_threshold] (NIR's strict comparison), hard reset v ← v_reset where z."""
    spikes = voltage > node.v_threshold.astype(np.float32)
    state["voltage"] = np.where(spikes, node.v_reset.astype(np.float32), voltage).astype(np.float32)
    state.update(extra)
    return spikes.astype(np.float32)


# ------------------------------------------------------------------------------------- host side
def read_host(graph) -> dict[str, Any]:
    """The host-side constants stored in an ilcsan NIR graph's metadata (bundle meta keys: ``T``, ``statistic``)."""
    metadata = getattr(graph, "metadata", None) or {}
    if str(metadata.get("format", "")) != FORMAT or "host" not in metadata:
        raise UserError(f"this NIR graph has no ilcsan host metadata (format {FORMAT!r}); it was not written "
                        "by ilcsan export --format nir")
    host = json.loads(str(metadata["host"]))
    host.setdefault("T", int(metadata["timesteps"]))  # graphs written before the host held the bundle's meta
    for name in ("encoder_mu", "encoder_sigma", "decoder_weight", "decoder_bias"):
        if name in metadata:
            host[name] = np.asarray(metadata[name], np.float32)
    return host


def host_encode(host: Mapping[str, Any], observation: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
    """Normalise and encode one raw observation (N,) into the graph input (T, D_0) on the host, with the
    numpy runtime's normaliser and encoders (:mod:`ilcsan.deploy.runtime.host`)."""
    state = normalize(observation, host["obs_mean"], host["obs_std"], host["obs_clip"])
    return encode(host["encoder"], state, int(host["T"]), host.get("encoder_mu"), host.get("encoder_sigma"),
                  float(host["enc_v_th"]), float(host["obs_clip"]), rng)


def host_decode(host: Mapping[str, Any], outputs: np.ndarray) -> np.ndarray:
    """The graph's output over T steps → action: Stat(V_1..V_T) (Eq. (8)) or, for ``fr``, PopSAN's group FC
    of the firing rates; then offset + scale · tanh(O), as the numpy runtime."""
    if host["statistic"] == "fr":
        populations, size = int(host["action_dim"]), int(host["population_out"])
        rates = outputs[:, :populations * size].mean(axis=0, dtype=np.float32).reshape(populations, size)
        output = (rates * host["decoder_weight"]).sum(-1) + host["decoder_bias"]
    else:
        output = select_statistic(outputs.astype(np.float32), host["statistic"])
    return squash(output, host["action_scale"], host["action_offset"])


def nir_action(graph, observation: np.ndarray) -> np.ndarray:
    """Host encoder → :func:`simulate_nir` → host decoder: the action of one raw observation (N,)."""
    host = read_host(graph)
    outputs = simulate_nir(graph, host_encode(host, observation))
    (name,) = outputs
    return host_decode(host, outputs[name])
