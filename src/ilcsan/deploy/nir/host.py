"""The host side of an exported graph: spikes in, the decoder's voltages out.

``observation → normalize → encode → (T, N·P_in) spikes`` feeds the graph's input at every step;
``(T, ·) graph outputs → [LI integrator, Eq. (7), target portable] → statistic, Eq. (8) → offset + scale · tanh``
gives the action. Every step is a function of the numpy runtime (:mod:`ilcsan.runtime.host`), so a NIR
consumer and the additions-only runtime compute the host parts identically; the constants come from the
graph's metadata (:func:`read_host`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np

from ...errors import UserError
from ...runtime.bundle_format import check_encoder_widths, check_vectors
from ...runtime.host import encode, li_voltages, normalize, select_statistic, squash
from .graph import FORMAT
from .interpreter import simulate_nir

HOST_KEYS = ("encoder", "enc_v_th", "statistic", "obs_clip")
"""Host constants besides the normaliser's and the action bounds' vectors (checked as a bundle's meta's are)."""
FORMATS = (FORMAT, "ilcsan-nir/1")  # version 1: dt = 1 (one step), the integrator always in the graph


def read_host(graph) -> dict[str, Any]:
    """The host-side constants of an ilcsan NIR graph: the bundle's meta (``T``, ``statistic``, ``alpha_v_li``,
    the normaliser, the action bounds …), ``integrator`` (host | graph | none), ``dt`` and the arrays."""
    metadata = getattr(graph, "metadata", None) or {}
    if str(metadata.get("format", "")) not in FORMATS or "host" not in metadata:
        raise UserError(f"this NIR graph has no ilcsan host metadata (format {FORMAT!r}); it was not written "
                        "by ilcsan export --format nir")
    try:
        host = json.loads(str(metadata["host"]))
    except json.JSONDecodeError as error:
        raise UserError(f"this NIR graph's host metadata is not valid JSON ({error}); re-export it") from None
    if not isinstance(host, dict):
        raise UserError("this NIR graph's host metadata must be a JSON object; re-export it")
    missing = [key for key in HOST_KEYS if key not in host]
    if missing:
        raise UserError(f"this NIR graph's host metadata lacks {', '.join(missing)}; re-export it with this "
                        "version of ilcsan")
    check_vectors(host, "this NIR graph's host metadata")
    host.setdefault("T", int(metadata["timesteps"]))  # graphs written before the host held the bundle's meta
    host.setdefault("integrator", "none" if host.get("statistic") == "fr" else "graph")
    host["dt"] = float(metadata.get("dt", 1.0))
    for name in ("encoder_mu", "encoder_sigma", "decoder_weight", "decoder_bias"):
        if name in metadata:
            host[name] = np.asarray(metadata[name], np.float32)
            if not np.all(np.isfinite(host[name])):
                raise UserError(f"this NIR graph's metadata {name!r} contains NaN or inf; re-export it")
    if "encoder_sigma" in host:
        check_encoder_widths(host["encoder_sigma"], "encoder_sigma", "this NIR graph's metadata")
    return host


def host_encode(host: Mapping[str, Any], observation: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
    """One raw observation (N,) → the graph's input (T, D_0) float32: the frozen normaliser, then the encoder
    (Eq. (9)'s Gaussian fields and Eq. (4)'s soft-reset IF for ``pop-det``)."""
    state = normalize(observation, host["obs_mean"], host["obs_std"], host["obs_clip"])
    return encode(host["encoder"], state, int(host["T"]), host.get("encoder_mu"), host.get("encoder_sigma"),
                  float(host["enc_v_th"]), float(host["obs_clip"]), rng)


def host_decode(host: Mapping[str, Any], outputs: np.ndarray) -> np.ndarray:
    """The graph's outputs over T steps (T, ·) → action. ``integrator`` = host: the outputs are the LI inputs
    X_t, integrated here as V_t = α V_{t−1} + X_t (Eq. (7)); then O = Stat(V_1..V_T) (Eq. (8)). For ``fr``
    (PopSAN) the outputs are spikes: the group FC of their rates. Then action = offset + scale · tanh(O)."""
    outputs = np.asarray(outputs, np.float32)
    if host["statistic"] == "fr":
        populations, size = int(host["action_dim"]), int(host["population_out"])
        rates = outputs[:, :populations * size].mean(axis=0, dtype=np.float32).reshape(populations, size)
        output = (rates * host["decoder_weight"]).sum(-1) + host["decoder_bias"]
    else:
        if host["integrator"] == "host":
            outputs = li_voltages(outputs, float(host["alpha_v_li"]))
        output = select_statistic(outputs, host["statistic"])
    return squash(output, host["action_scale"], host["action_offset"])


def nir_action(graph, observation: np.ndarray) -> np.ndarray:
    """Host encoder → :func:`~.interpreter.simulate_nir` → host decoder: the action of one raw observation."""
    host = read_host(graph)
    outputs = simulate_nir(graph, host_encode(host, observation))
    if len(outputs) != 1:
        raise UserError(f"the graph has outputs {sorted(outputs)}; an ilcsan graph has one")
    (values,) = outputs.values()
    return host_decode(host, values)
