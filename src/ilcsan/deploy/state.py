"""The actor's state as every export reads it: seed 0 of its parameters and persistent buffers, the buffers folded.

The deploy bundle (:func:`~ilcsan.deploy.bundle.bundle_arrays`; through it the int8 bundle and the Lava network,
which are built from a bundle) and the NIR graph (:mod:`ilcsan.deploy.nir`) take the actor's tensors from
:func:`export_state` alone, never from its submodules, so that nothing a checkpoint keeps
(:func:`~ilcsan.runs.checkpoint.module_state`) is left out without a word. A persistent buffer (the convention:
:mod:`ilcsan.snn.ensemble`) acts on the network — running statistics normalise what a layer receives — and a
deployed network has no place for it: an export folds it into the weights it acts on, as batch normalisation
folds into the affine layer beside it. The fold is declared by the module that keeps the buffer, or by a module
that holds it (its method ``export_fold(state, prefix)``; a normalisation's:
:meth:`~ilcsan.snn.normalization.LayerNormalizations.export_fold`), so a new normalisation touches nothing here; a
buffer that no module folds is refused, naming it. With every normalisation folded, the exported actor normalises
nothing (:func:`exported_config`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from ..config import ActorConfig
from ..errors import UserError
from ..methods import NO_NORMALIZATION
from ..runs.checkpoint import module_state


def fold_buffers(actor: torch.nn.Module, state: dict[str, torch.Tensor],
                 buffers: list[str]) -> dict[str, torch.Tensor]:
    """``state`` (seed 0 of ``actor``'s tensors by name) with its persistent ``buffers`` folded: each module of
    ``actor`` that declares ``export_fold``, outermost first, folds what it holds under its prefix, and returns the
    state without those buffers. A buffer still there afterwards is a :class:`UserError` naming it, never ignored:
    an export without it would compute another network."""
    for prefix, module in actor.named_modules():
        fold = getattr(module, "export_fold", None)
        held = [name for name in buffers if name in state and (not prefix or name.startswith(prefix + "."))]
        if fold is not None and held:
            state = fold(state, prefix)
    left = [name for name in buffers if name in state]
    if left:
        raise unfoldable(left[0])
    return state


def unfoldable(name: str) -> UserError:
    """The error for a persistent buffer no fold knows."""
    return UserError(f"the actor keeps {name!r}, a persistent buffer that no export knows how to fold into its "
                     "weights (no module that holds it declares export_fold), so it cannot be exported")


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
    is folded into the weights (:func:`fold_buffers`), so that a bundle's meta describes its arrays."""
    return dataclasses.replace(config, normalization=NO_NORMALIZATION)


def export_state(actor: torch.nn.Module) -> dict[str, np.ndarray]:
    """Seed 0 of ``actor``'s parameters and persistent buffers as float32 arrays under the module's names, in
    ``state_dict`` order: the masks applied (:func:`masked`), every persistent buffer folded (:func:`fold_buffers`)."""
    state = {name: tensor.detach()[0].cpu() for name, tensor in module_state(actor).items()}
    parameters = {name for name, _ in actor.named_parameters()}
    state = fold_buffers(actor, masked(actor, state), [name for name in state if name not in parameters])
    return {name: tensor.numpy().astype(np.float32) for name, tensor in state.items()}
