"""The ``.npz`` deploy bundle of a trained actor (``ilcsan export --format npz``; :mod:`ilcsan.deploy.export`).

Deploy bundle (float32 arrays, plus a JSON string ``meta``), read by :mod:`ilcsan.runtime` with
numpy only. The arrays are the actor's exported state (:mod:`ilcsan.deploy.state`: its parameters with the masks
applied; a persistent buffer folded in, or the export refused):

=====================  ============  =========================================================
name                   shape         meaning
=====================  ============  =========================================================
encoder.mu             (N, P_in)     Gaussian receptive-field centres (population encoders)
encoder.sigma          (N, P_in)     Gaussian receptive-field widths
layers.<l>.weight      (out, in)     synaptic layer l = 0..L-1 (backbone incl. output layer)
layers.<l>.bias        (out,)
intra.weight           (M, P, P)     intra-layer weights, ablation mask applied (absent: none)
intra.bias             (M, P)        intra-layer bias, mask applied (absent: none)
decoder.weight         (M, P_out)    group FC of the population decoder
decoder.bias           (M,)
<name>.scale           ()            float32 scale of an int8 weight, W ≈ scale · q (``--weights int8``)
meta                   str (JSON)    see :func:`bundle_meta`
=====================  ============  =========================================================

The meta is the actor's :meth:`~ilcsan.config.ActorConfig.to_dict` with two keys renamed
(:data:`~ilcsan.runtime.CONFIG_META_KEYS`: ``timesteps`` → ``T``, ``decoder`` → ``statistic``),
the intra-layer mask as flags (``intra_mask``, :class:`~ilcsan.config.IntraMask`), the reset voltages
``v_reset`` = ``v_reset_li`` = 0, ``output`` = "tanh", the ``task``, the frozen normaliser (``obs_mean``,
``obs_std``, ``obs_clip``) and the action bounds (``action_scale``, ``action_offset``); int8 bundles add
``weights`` and ``quantization``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from ..config import INTRA_MASKS, WEIGHT_FORMATS, ActorConfig
from ..files import atomic_savez
from ..runtime import CONFIG_META_KEYS
from .policy import Policy
from .quantize import quantize_bundle
from .state import export_state, exported_config

WEIGHTS = tuple(WEIGHT_FORMATS)
"""Weight formats of a bundle: float32, or int8 with a float32 scale per layer (:mod:`ilcsan.deploy.quantize`)."""


FIXED_META = {"v_reset": 0.0, "v_reset_li": 0.0, "output": "tanh"}
"""Constants of every exported actor: reset voltages of 0 (the paper's) and the tanh action squashing."""


def bundle_meta(policy: Policy) -> dict[str, Any]:
    """The bundle's metadata (JSON-serialisable): the actor's configuration under the bundle's keys (as exported:
    its normalisation folded into the weights, :func:`~ilcsan.deploy.state.exported_config`), its intra-layer mask,
    the task, the frozen normaliser and the action bounds."""
    config = exported_config(policy.actor_config)
    meta = {CONFIG_META_KEYS.get(name, name): value for name, value in config.to_dict().items()}
    meta.update(FIXED_META, intra_mask=INTRA_MASKS[config.intra]._asdict(), task=policy.task,
                contact_forces=policy.contact_forces,
                obs_mean=policy.obs_mean.tolist(), obs_std=policy.obs_std.tolist(), obs_clip=float(policy.obs_clip),
                action_scale=policy.action_scale.tolist(), action_offset=policy.action_offset.tolist())
    return meta


def actor_config_of(meta: dict[str, Any]) -> ActorConfig:
    """The :class:`~ilcsan.config.ActorConfig` a bundle's meta was written from (the inverse of the renaming)."""
    renamed = {key: name for name, key in CONFIG_META_KEYS.items()}
    fields = {field.name for field in dataclasses.fields(ActorConfig)}
    values = {renamed.get(key, key): value for key, value in meta.items()}
    return ActorConfig.from_dict({name: value for name, value in values.items() if name in fields})


def bundle_arrays(policy: Policy) -> dict[str, np.ndarray]:
    """The actor's exported state (:func:`~ilcsan.deploy.state.export_state`: float32, seed slice 0, masks applied,
    persistent buffers folded or refused) under the bundle's names: a spiking actor's own names, DAN's without
    its ``mlp.`` prefix."""
    return {name.removeprefix("mlp."): array for name, array in export_state(policy.actor).items()}


def export_npz(policy: Policy, path: Path, weights: str = "float32") -> Path:
    arrays = bundle_arrays(policy)
    meta = bundle_meta(policy)
    if weights == "int8":
        arrays, meta = quantize_bundle(arrays, meta)
    atomic_savez(path, meta=np.array(json.dumps(meta)), **arrays)
    return path
