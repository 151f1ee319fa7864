"""A small NIR interpreter: the reference semantics the exported graphs are written for.

Euler steps of size dt with *zero lag* on feed-forward edges (a spike emitted at step t reaches the next
layer's current and voltage at step t, as Algorithm 1 and snnTorch's ``Synaptic`` do) and a *one-step delay
on recurrent (back) edges* (the intra-layer current of Eq. (10) at t comes from the spikes of t − 1, zeros at
the first step), as NIRTorch executes recurrent graphs.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ...errors import UserError


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


def simulate_nir(graph, inputs: np.ndarray | Mapping[str, np.ndarray],
                 dt: float | None = None) -> dict[str, np.ndarray]:
    """Run a NIR graph for T steps: ``inputs`` (T, D) (or a dict per Input node) → {Output name: (T, …)}.

    ``dt`` defaults to the graph's ``metadata["dt"]`` (seconds; 1 when absent). Semantics: Euler steps of size
    ``dt`` with zero lag on feed-forward edges (a node sees its
    predecessors' outputs of the same step) and a one-step delay on recurrent edges (zeros at the first
    step); several incoming edges add. Supported nodes: Input, Output, Affine, Linear, Scale, CubaLIF,
    LIF, IF, LI, I. float32 throughout, like the actor.
    """
    import nir

    nodes, edges = graph.nodes, [tuple(edge) for edge in graph.edges]
    if dt is None:
        dt = float((getattr(graph, "metadata", None) or {}).get("dt", 1.0))
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
