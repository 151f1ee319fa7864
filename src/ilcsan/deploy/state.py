"""The actor's state as every export reads it: seed 0 of its parameters and persistent buffers, the buffers folded.

The deploy bundle (:func:`~ilcsan.deploy.bundle.bundle_arrays`; through it the int8 bundle and the Lava network,
which are built from a bundle) and the NIR graph (:mod:`ilcsan.deploy.nir`) take the actor's tensors from
:func:`export_state` alone, never from its submodules, so that nothing a checkpoint keeps
(:func:`~ilcsan.runs.checkpoint.module_state`) is left out without a word. A persistent buffer (the convention:
:mod:`ilcsan.snn.ensemble`) acts on the network — running statistics normalise what a layer receives — and a
deployed network has no place for it: an export folds it into the weights it acts on, as batch normalisation
folds into the affine layer beside it. :data:`FOLDS` is the one place such a fold goes; a buffer without one is
refused, naming it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch

from ..errors import UserError
from ..runs.checkpoint import module_state

Fold = Callable[[dict[str, torch.Tensor], str], dict[str, torch.Tensor]]

FOLDS: dict[str, Fold] = {}
"""How an export folds a persistent buffer, by the last part of its name (``running_mean`` for
``layers.0.norm.running_mean``): ``fold(state, name)`` returns seed 0's ``state`` (names → tensors without the
ensemble dimension) with buffer ``name`` folded into the parameters it acts on and removed. No actor has a
persistent buffer yet, so there is no fold yet (CaRe-BN's running statistics will bring the first)."""


def fold_buffers(state: dict[str, torch.Tensor], buffers: Sequence[str]) -> dict[str, torch.Tensor]:
    """``state`` with each of ``buffers`` folded by its :data:`FOLDS` entry, in order; a buffer no fold knows is
    a :class:`UserError` naming it, never ignored: an export without it would compute another network."""
    for name in buffers:
        fold = FOLDS.get(name.rsplit(".", 1)[-1])
        if fold is None:
            raise UserError(f"the actor keeps {name!r}, a persistent buffer that no export knows how to fold into "
                            "its weights (ilcsan.deploy.state.FOLDS), so it cannot be exported")
        state = fold(state, name)
    return state


def masked(actor: torch.nn.Module, state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """``state`` with the intra-layer ablation mask (a constant of the configuration, Eq. (10)) applied to
    W_intra and b_intra, as the forward pass applies it."""
    intra = getattr(actor, "intra", None)
    if intra is None:
        return state
    return {**state, "intra.weight": state["intra.weight"] * intra.weight_mask,
            "intra.bias": state["intra.bias"] * intra.bias_mask}


def export_state(actor: torch.nn.Module) -> dict[str, np.ndarray]:
    """Seed 0 of ``actor``'s parameters and persistent buffers as float32 arrays under the module's names, in
    ``state_dict`` order: the masks applied (:func:`masked`), every persistent buffer folded (:func:`fold_buffers`)."""
    state = {name: tensor.detach()[0].cpu() for name, tensor in module_state(actor).items()}
    parameters = {name for name, _ in actor.named_parameters()}
    state = fold_buffers(masked(actor, state), [name for name in state if name not in parameters])
    return {name: tensor.numpy().astype(np.float32) for name, tensor in state.items()}
