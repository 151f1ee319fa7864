"""The actor's state as every export reads it: seed 0 of its parameters and persistent buffers, the buffers folded.

The deploy bundle (:func:`~ilcsan.deploy.bundle.bundle_arrays`; through it the int8 bundle and the Lava network,
which are built from a bundle) and the NIR graph (:mod:`ilcsan.deploy.nir`) take the actor's tensors from
:func:`export_state` alone, never from its submodules, so that nothing a checkpoint keeps
(:func:`~ilcsan.runs.checkpoint.module_state`) is left out without a word. A persistent buffer (the convention:
:mod:`ilcsan.snn.ensemble`) acts on the network — running statistics normalise what a layer receives — and a
deployed network has no place for it: an export folds it into the weights it acts on, as batch normalisation
folds into the affine layer beside it. :data:`FOLDS` is the one place such a fold goes; a buffer without one is
refused, naming it. With every normalisation folded, the exported actor normalises nothing
(:func:`exported_config`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np
import torch

from ..config import ActorConfig
from ..errors import UserError
from ..runs.checkpoint import module_state
from ..snn.normalization import RUNNING_BUFFERS, NormStatistics, fold_into_linear

Fold = Callable[[dict[str, torch.Tensor], str], dict[str, torch.Tensor]]

def fold_normalization(state: dict[str, torch.Tensor], name: str) -> dict[str, torch.Tensor]:
    """The actor's normalisation ``norms.<l>`` (:mod:`ilcsan.snn.normalization`; the prefix of buffer ``name``) folded
    into synaptic layer ``layers.<l>``, whose current it normalises: W' = s W, b' = s (b − μ̂) + β with s = γ / √(σ̂² + ε)
    (:func:`~ilcsan.snn.normalization.fold_into_linear`), and every tensor of ``norms.<l>`` (γ, β and the four
    buffers) removed. One fold per layer: for the layer's other buffers, already gone, ``state`` is returned as it
    is. A buffer of that name outside such a normalisation is refused (:func:`unfoldable`)."""
    if name not in state:
        return state
    prefix = name.rsplit(".", 1)[0]
    layer = "layers." + prefix.rsplit(".", 1)[-1]
    needed = [f"{prefix}.{part}" for part in (*RUNNING_BUFFERS, "gamma", "beta")] + [f"{layer}.weight", f"{layer}.bias"]
    if not prefix.startswith("norms.") or any(key not in state for key in needed):
        raise unfoldable(name)
    statistics = NormStatistics(state[f"{prefix}.running_mean"], state[f"{prefix}.running_var"])
    weight, bias = fold_into_linear(state[f"{layer}.weight"], state[f"{layer}.bias"], statistics,
                                    state[f"{prefix}.gamma"], state[f"{prefix}.beta"])
    kept = {key: tensor for key, tensor in state.items() if not key.startswith(prefix + ".")}
    return {**kept, f"{layer}.weight": weight, f"{layer}.bias": bias}


FOLDS: dict[str, Fold] = {buffer: fold_normalization for buffer in RUNNING_BUFFERS}
"""How an export folds a persistent buffer, by the last part of its name (``running_mean`` for
``norms.0.running_mean``): ``fold(state, name)`` returns seed 0's ``state`` (names → tensors without the
ensemble dimension) with buffer ``name`` folded into the parameters it acts on and removed. A normalisation's buffers
(:data:`~ilcsan.snn.normalization.RUNNING_BUFFERS`) fold with their layer's γ and β (:func:`fold_normalization`)."""


def fold_buffers(state: dict[str, torch.Tensor], buffers: Sequence[str]) -> dict[str, torch.Tensor]:
    """``state`` with each of ``buffers`` folded by its :data:`FOLDS` entry, in order; a buffer no fold knows is
    a :class:`UserError` naming it, never ignored: an export without it would compute another network."""
    for name in buffers:
        fold = FOLDS.get(name.rsplit(".", 1)[-1])
        if fold is None:
            raise unfoldable(name)
        state = fold(state, name)
    return state


def unfoldable(name: str) -> UserError:
    """The error for a persistent buffer no fold knows."""
    return UserError(f"the actor keeps {name!r}, a persistent buffer that no export knows how to fold into its "
                     "weights (ilcsan.deploy.state.FOLDS), so it cannot be exported")


def masked(actor: torch.nn.Module, state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """``state`` with the intra-layer ablation mask (a constant of the configuration, Eq. (10)) applied to
    W_intra and b_intra, as the forward pass applies it."""
    intra = getattr(actor, "intra", None)
    if intra is None:
        return state
    return {**state, "intra.weight": state["intra.weight"] * intra.weight_mask,
            "intra.bias": state["intra.bias"] * intra.bias_mask}


def exported_config(config: ActorConfig) -> ActorConfig:
    """The configuration of the actor an export holds: ``config`` without normalisation, since every normalisation
    is folded into the weights (:data:`FOLDS`), so that a bundle's meta describes its arrays."""
    return dataclasses.replace(config, normalization="none")


def export_state(actor: torch.nn.Module) -> dict[str, np.ndarray]:
    """Seed 0 of ``actor``'s parameters and persistent buffers as float32 arrays under the module's names, in
    ``state_dict`` order: the masks applied (:func:`masked`), every persistent buffer folded (:func:`fold_buffers`)."""
    state = {name: tensor.detach()[0].cpu() for name, tensor in module_state(actor).items()}
    parameters = {name for name, _ in actor.named_parameters()}
    state = fold_buffers(masked(actor, state), [name for name in state if name not in parameters])
    return {name: tensor.numpy().astype(np.float32) for name, tensor in state.items()}
