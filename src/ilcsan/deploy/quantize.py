"""int8 synaptic weights with one float scale per layer, as neuromorphic chips store them.

``quantize_bundle(arrays, meta)`` turns a float32 deploy bundle (:mod:`ilcsan.deploy.bundle`) into an int8
one (``ilcsan export RUN --weights int8``). Scheme: symmetric, per synaptic layer, zero-point 0:

    scale = max|W| / 127,    q = clip(round(W / scale), −127, 127) as int8,    W ≈ scale · q

for every synaptic weight matrix (``layers.<l>.weight``, ``intra.weight``, ``decoder.weight``). The
scale is stored as a float32 scalar array ``<name>.scale`` (:data:`ilcsan.deploy.SCALE_SUFFIX`).
Zero-point 0 keeps a zero weight exactly zero, so the ablation masks of the intra-layer connections
survive quantisation, and a spike selects whole integer weights: on chip the accumulation is
integer and the scale folds into the neuron's threshold and decay constants. Biases (constant currents,
usually held at higher precision on chips), the encoder's receptive fields (host) and everything in
``meta`` stay float. The runtime (:class:`ilcsan.deploy.DeployedActor`) accumulates the integers
exactly and multiplies each neuron's integer sum by the layer's scale once per step.

The metadata gains ``"weights": "int8"`` and ``"quantization"`` (scheme, bits, the quantised names).
The rounding error per weight is at most scale/2 = max|W|/254.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..errors import UserError
from ..runtime import SCALE_SUFFIX

BITS = 8
LEVELS = 2 ** (BITS - 1) - 1  # 127: symmetric range [−127, 127]
SYNAPTIC_WEIGHT = re.compile(r"^(layers\.\d+|intra|decoder)\.weight$")


def is_synaptic_weight(name: str) -> bool:
    """True for the weight matrices a spike selects: ``layers.<l>.weight``, ``intra.weight``, ``decoder.weight``."""
    return bool(SYNAPTIC_WEIGHT.match(name))


def quantize_weight(weight: np.ndarray) -> tuple[np.ndarray, np.float32]:
    """Symmetric per-tensor int8: (q, scale) with W ≈ scale · q, scale = max|W|/127 (1 for all-zero W)."""
    weight = np.asarray(weight, dtype=np.float32)
    if not np.all(np.isfinite(weight)):
        raise UserError("cannot quantise weights that contain NaN or inf")
    largest = float(np.max(np.abs(weight))) if weight.size else 0.0
    scale = np.float32(largest / LEVELS if largest > 0 else 1.0)
    quantized = np.clip(np.rint(weight / scale), -LEVELS, LEVELS).astype(np.int8)
    return quantized, scale


def dequantize_weight(quantized: np.ndarray, scale: float) -> np.ndarray:
    """scale · q as float32."""
    return (np.asarray(quantized, np.float32) * np.float32(scale)).astype(np.float32)


def quantize_bundle(arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> tuple[dict[str, np.ndarray],
                                                                                      dict[str, Any]]:
    """A new (arrays, meta) pair with int8 synaptic weights and float32 ``<name>.scale`` arrays."""
    if meta.get("weights") == "int8" or any(np.asarray(value).dtype == np.int8 for value in arrays.values()):
        raise UserError("the bundle is already quantised to int8")
    quantized_arrays: dict[str, np.ndarray] = {}
    names = []
    for name, value in arrays.items():
        if is_synaptic_weight(name):
            quantized_arrays[name], scale = quantize_weight(value)
            quantized_arrays[name + SCALE_SUFFIX] = np.asarray(scale, dtype=np.float32)
            names.append(name)
        else:
            quantized_arrays[name] = np.asarray(value)
    new_meta = dict(meta)
    new_meta["weights"] = "int8"
    new_meta["quantization"] = {"scheme": "symmetric per-layer, zero-point 0", "bits": BITS,
                                "levels": LEVELS, "scale_suffix": SCALE_SUFFIX, "weights": names}
    return quantized_arrays, new_meta
