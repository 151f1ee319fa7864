"""The ``.npz`` deploy bundle as the runtime reads it: metadata keys, checks, and the synaptic layers.

A bundle holds float32 (or int8) arrays and a JSON string ``meta`` (layout: :mod:`ilcsan.deploy.bundle`).
The meta is the actor's :meth:`ilcsan.config.ActorConfig.to_dict` with the keys renamed by
:data:`CONFIG_META_KEYS`, plus the frozen normaliser, the action bounds and the reset voltages. Every
check raises :class:`UserError` with one sentence naming the bundle and the fix.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .errors import UserError
from .synapses import GROUP_FC, INTRA_FC, Synapses, fc_name

SCALE_SUFFIX = ".scale"
"""An int8 weight array ``<name>`` has its float32 scale in ``<name>.scale`` (W ≈ scale · int8)."""

CONFIG_META_KEYS = {"timesteps": "T", "decoder": "statistic"}
"""ActorConfig fields stored under another key in the meta (every other field keeps its name)."""

REQUIRED_META = ("T", "alpha_c", "alpha_v", "v_th", "v_reset", "alpha_v_li", "v_reset_li", "statistic",
                 "encoder", "enc_v_th", "obs_mean", "obs_std", "obs_clip", "action_scale", "action_offset",
                 "neuron", "network", "population_out", "population_in")
NUMBER_META = ("T", "alpha_c", "alpha_v", "v_th", "v_reset", "alpha_v_li", "v_reset_li", "enc_v_th", "obs_clip",
               "population_out", "population_in")
VECTOR_META = ("obs_mean", "obs_std", "action_scale", "action_offset")
STATISTICS = ("last", "max", "mean")
NEURONS = ("clif", "dynamic")
INTRA_TIMINGS = ("paper", "authors")
"""Meta ``intra_timing`` (absent: ``paper``): b_intra from t = 2 on (Algorithm 1) or from t = 1 (the authors' code)."""
MASK_PARTS = ("self_weights", "lateral_weights", "bias")
"""Meta ``intra_mask`` holds these flags (:class:`ilcsan.config.IntraMask`): which parts of Eq. (10) exist."""
PART_NAMES = {"self": "self_weights", "lateral": "lateral_weights", "bias": "bias"}


def read_bundle(path: str | Path) -> tuple[dict[str, np.ndarray], Any]:
    """The arrays and the decoded meta of a bundle file (``np.load(allow_pickle=False)``: data only)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path} does not exist; export one with `ilcsan export RUN --format npz`")
    try:
        with np.load(path, allow_pickle=False) as bundle:
            arrays = {name: bundle[name] for name in bundle.files}
    except (OSError, ValueError, EOFError) as error:
        raise UserError(f"{path} is not a readable .npz deploy bundle ({error})") from None
    if "meta" not in arrays:
        raise UserError(f"{path} has no 'meta' entry: it is not an ilcsan deploy bundle")
    try:
        return arrays, json.loads(str(arrays.pop("meta")))
    except json.JSONDecodeError as error:
        raise UserError(f"{path}: the bundle's meta is not valid JSON ({error})") from None


# ------------------------------------------------------------------------------------------ meta
def mask_of_variant(name: str) -> tuple[bool, bool, bool] | None:
    """(self, lateral, bias) of an intra-layer variant name, for bundles that store only the name: ``intra``
    keeps every part, ``none`` none, any other name is the '+'-joined parts it keeps; None if unknown."""
    if name in ("intra", "none"):
        parts = set(PART_NAMES) if name == "intra" else set()
    else:
        parts = set(name.split("+"))
        if not parts <= set(PART_NAMES):
            return None
    kept = {PART_NAMES[part] for part in parts}
    return tuple(part in kept for part in MASK_PARTS)  # type: ignore[return-value]


def intra_mask(meta: Mapping[str, Any], source: str) -> tuple[bool, bool, bool] | None:
    """The (self, lateral, bias) mask the meta declares: its ``intra_mask`` flags, else its ``intra`` variant
    name (older bundles); None when it declares neither (then the weights tell)."""
    name, flags = meta.get("intra"), meta.get("intra_mask")
    named = mask_of_variant(name) if isinstance(name, str) else None
    if name is not None and named is None:
        raise UserError(f"{source}: meta 'intra' {name!r} is not an intra-layer variant (e.g. intra, self+bias, none)")
    if flags is None:
        return named
    if (not isinstance(flags, Mapping) or set(flags) != set(MASK_PARTS)
            or not all(isinstance(flags[part], bool) for part in MASK_PARTS)):
        raise UserError(f"{source}: meta 'intra_mask' must map {', '.join(MASK_PARTS)} to true/false")
    mask = tuple(flags[part] for part in MASK_PARTS)
    if named is not None and named != mask:
        raise UserError(f"{source}: meta 'intra' {name!r} and 'intra_mask' {dict(flags)} disagree")
    return mask  # type: ignore[return-value]


def checked_meta(meta: Any, source: str) -> dict[str, Any]:
    """The meta as a dict, after checking that it describes a fully spiking actor the runtime can run."""
    if not isinstance(meta, Mapping):
        raise UserError(f"{source}: the bundle's meta must be a JSON object")
    missing = [key for key in REQUIRED_META if key not in meta]
    if missing:
        raise UserError(f"{source}: the bundle's meta lacks {', '.join(missing)}; re-export it with this "
                        "version of ilcsan")
    _check_fully_spiking(meta, source)
    for key in NUMBER_META:
        value = meta[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise UserError(f"{source}: meta {key!r} must be a finite number, got {value!r}")
    for key in ("T", "population_out", "population_in"):
        if int(meta[key]) != meta[key] or meta[key] < 1:
            raise UserError(f"{source}: meta {key!r} must be a positive integer, got {meta[key]!r}")
    if meta["v_reset"] != 0 or meta["v_reset_li"] != 0:
        raise UserError(f"{source}: the runtime implements reset voltages of 0 (the paper's); got "
                        f"v_reset={meta['v_reset']}, v_reset_li={meta['v_reset_li']}")
    check_vectors(meta, source)
    intra_mask(meta, source)
    if meta.get("intra_timing", INTRA_TIMINGS[0]) not in INTRA_TIMINGS:
        raise UserError(f"{source}: meta 'intra_timing' {meta['intra_timing']!r} is not one of {INTRA_TIMINGS}")
    return dict(meta)


def intra_bias_at_first_step(meta: Mapping[str, Any]) -> bool:
    """Whether b_intra already reaches the output layer at t = 1 (meta ``intra_timing`` "authors")."""
    return meta.get("intra_timing", INTRA_TIMINGS[0]) == "authors"


def _check_fully_spiking(meta: Mapping[str, Any], source: str) -> None:
    if meta["network"] != "spiking":
        raise UserError(f"{source} holds a {meta['network']!r} actor (DAN); the additions-only runtime runs "
                        "spiking actors only: use ilcsan.load(run).predict for a deep actor")
    if meta["encoder"] == "pop-prob":
        raise UserError(f"{source}: encoder 'pop-prob' draws Bernoulli spikes, so its actions are random; the "
                        "deployed runtime is deterministic: train (or fine-tune) with --encoder pop-det")
    if meta["encoder"] != "pop-det":
        raise UserError(f"{source}: encoder {meta['encoder']!r} feeds analog values to FC1 (floating-point "
                        "matrix operations), so the actor is not fully spiking; the runtime needs pop-det")
    if meta["statistic"] not in STATISTICS:
        raise UserError(f"{source}: decoder {meta['statistic']!r} is not fully spiking (a floating-point FC "
                        f"on firing rates); the runtime runs the membrane-voltage decoders {STATISTICS}")
    if meta["neuron"] not in NEURONS:
        raise UserError(f"{source}: unknown neuron {meta['neuron']!r}; expected one of {NEURONS}")


def check_encoder_widths(sigma: np.ndarray, name: str, source: str) -> None:
    """Eq. (9)'s receptive fields divide by σ: a zero width is a damaged actor (a negative one is the same
    Gaussian, σ enters squared)."""
    if np.any(sigma == 0):
        raise UserError(f"{source}: {name!r} has zeros; Eq. (9)'s receptive fields divide by σ (re-export the "
                        "actor)")


def check_vectors(meta: Mapping[str, Any], source: str) -> None:
    """The frozen normaliser's mean/std and the action bounds: non-empty finite lists, std > 0, paired lengths."""
    vectors = {}
    for key in VECTOR_META:
        try:
            vectors[key] = np.asarray(meta[key], dtype=np.float64)
        except (TypeError, ValueError):
            raise UserError(f"{source}: meta {key!r} must be a list of numbers") from None
        if vectors[key].ndim != 1 or vectors[key].size == 0 or not np.all(np.isfinite(vectors[key])):
            raise UserError(f"{source}: meta {key!r} must be a non-empty list of finite numbers")
    if vectors["obs_std"].shape != vectors["obs_mean"].shape or np.any(vectors["obs_std"] <= 0):
        raise UserError(f"{source}: meta 'obs_std' must be positive and as long as 'obs_mean'")
    if vectors["action_offset"].shape != vectors["action_scale"].shape:
        raise UserError(f"{source}: meta 'action_offset' and 'action_scale' differ in length")


# ---------------------------------------------------------------------------------------- arrays
def read_array(arrays: Mapping[str, np.ndarray], name: str, shape: tuple[int, ...], source: str) -> np.ndarray:
    """A float32 array of the given shape (an int8 weight with its scale is returned as int8)."""
    if name not in arrays:
        raise UserError(f"{source} has no array {name!r}: it is incomplete or from another exporter")
    array = np.asarray(arrays[name])
    if tuple(array.shape) != tuple(shape):
        raise UserError(f"{source}: array {name!r} has shape {tuple(array.shape)}, expected {tuple(shape)}")
    if array.dtype == np.int8:
        return array
    if not np.issubdtype(array.dtype, np.floating):
        raise UserError(f"{source}: array {name!r} has dtype {array.dtype}, expected float32 or int8")
    array = array.astype(np.float32)
    if not np.all(np.isfinite(array)):
        raise UserError(f"{source}: array {name!r} contains NaN or inf")
    return array


def read_weight(arrays: Mapping[str, np.ndarray], name: str, shape: tuple[int, ...],
                source: str) -> tuple[np.ndarray, float | None]:
    """A synaptic weight matrix and its int8 scale (None for float weights)."""
    weight = read_array(arrays, name, shape, source)
    if weight.dtype != np.int8:
        return weight, None
    scale_name = name + SCALE_SUFFIX
    if scale_name not in arrays:
        raise UserError(f"{source}: int8 array {name!r} has no scale {scale_name!r}")
    scale = np.asarray(arrays[scale_name])
    if scale.size != 1 or not np.isfinite(scale).all() or float(scale.reshape(-1)[0]) <= 0:
        raise UserError(f"{source}: scale {scale_name!r} must be one positive finite number")
    return weight, float(scale.reshape(-1)[0])


def backbone_synapses(arrays: Mapping[str, np.ndarray], input_dim: int, output_dim: int,
                      source: str) -> tuple[Synapses, ...]:
    """FC1 … FC(L+1) as dense event-driven layers, rows = presynaptic neurons (Wᵀ)."""
    count = 0
    while f"layers.{count}.weight" in arrays:
        count += 1
    if not 2 <= count <= 5:
        raise UserError(f"{source} has {count} synaptic layers; a spiking actor has 1-4 hidden layers + output")
    layers, fan_in = [], input_dim
    for index in range(count):
        name = f"layers.{index}.weight"
        if name not in arrays or np.ndim(arrays[name]) != 2:
            raise UserError(f"{source}: array {name!r} must be a 2-D (out, in) matrix")
        out_dim = int(np.shape(arrays[name])[0])
        if index == count - 1 and out_dim != output_dim:
            raise UserError(f"{source}: the output layer has {out_dim} neurons, expected M·P_out = {output_dim}")
        weight, scale = read_weight(arrays, name, (out_dim, fan_in), source)
        bias = read_array(arrays, f"layers.{index}.bias", (out_dim,), source)
        layers.append(Synapses(fc_name(index), np.ascontiguousarray(weight.T), None, scale, bias, out_dim,
                               out_dim))
        fan_in = out_dim
    return tuple(layers)


def intra_synapses(arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any], populations: int, size: int,
                   source: str) -> Synapses | None:
    """Intra FC as block-diagonal rows over the output layer, counting the synapses the ablation mask keeps.

    The mask comes from the meta (:func:`intra_mask`) when it declares one, else from the weights (a part
    whose weights are all exactly zero is absent; masked weights are stored as exact zeros). Row j (a
    presynaptic output neuron of population m) holds column j of the block-diagonal W_intra: W_intra^m[:, q]
    on population m's slots, zeros elsewhere — one vectorised add per step is cheaper in numpy than a
    scatter; the SOP count is spikes × the kept synapses of one population (P_out, 1, P_out − 1 or 0).
    """
    mask = intra_mask(meta, source)
    if "intra.weight" not in arrays and "intra.bias" not in arrays:
        if mask is not None and any(mask):
            raise UserError(f"{source}: meta says intra {meta.get('intra')!r} but the bundle has no intra arrays")
        return None
    weight, scale = read_weight(arrays, "intra.weight", (populations, size, size), source)
    bias = read_array(arrays, "intra.bias", (populations, size), source).reshape(-1)
    eye = np.eye(size, dtype=bool)
    if mask is not None:
        keep_self, keep_lateral, _ = mask
    else:
        keep_self = bool(np.any(weight[:, eye]))
        keep_lateral = bool(np.any(weight[:, ~eye]))
    keep = (eye & keep_self) | (~eye & keep_lateral)  # keep[post, pre]
    width = populations * size
    rows = np.zeros((width, width), weight.dtype)  # rows[pre, post]
    for m in range(populations):
        block = slice(m * size, (m + 1) * size)
        rows[block, block] = np.where(keep, weight[m], 0).T
    return Synapses(INTRA_FC, rows, None, scale, bias, width, int(keep[:, 0].sum()))


def decoder_synapses(arrays: Mapping[str, np.ndarray], populations: int, size: int, source: str) -> Synapses:
    """Group FC: output neuron j of population m = j // P_out adds W_D[m, j mod P_out] into LI neuron m."""
    weight, scale = read_weight(arrays, "decoder.weight", (populations, size), source)
    bias = read_array(arrays, "decoder.bias", (populations,), source)
    targets = np.repeat(np.arange(populations), size)[:, None]
    return Synapses(GROUP_FC, weight.reshape(-1, 1), targets, scale, bias, populations, 1)
