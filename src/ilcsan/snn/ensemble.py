"""Synaptic layers with an ensemble dimension: K independent networks in one batched module.

Every trainable tensor carries a leading dimension K (the number of seeds trained together, 1 for an
ordinary run), so one batched matmul serves K agents (``torch.baddbmm``). Slice ``k`` is initialised
from its own generator, in the same order whatever K is: seed k of a K-seed run starts from exactly the
weights of a single run with seed k.

Module state. What a module keeps between calls is of two kinds, and the kind decides where it is saved:

* learned or accumulated state — every parameter and every *persistent* buffer (e.g. running statistics that
  change during training) — carries the ensemble dimension first, like the parameters: K rows, or K·r when
  each seed owns r rows (the twin critics: r = 2). Checkpoints and ``policy.pt`` cut it per seed and stack it
  back (:func:`ilcsan.runs.checkpoint.slice_state`), and every export must fold it into the weights or refuse
  (:mod:`ilcsan.deploy.state`);
* constants derived from the task or the configuration — the action bounds, the intra-layer masks — are
  registered with ``persistent=False``: they are rebuilt from the config, so they are in no file and carry no
  ensemble dimension. They are still buffers, so ``.to(device)``, ``deepcopy`` and the compiled programs'
  constants (:func:`ilcsan.compute.programs.module_tensors`) see them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from ..compute.matmul import DEFAULT_MATMUL, MatmulPath, ensemble_matmul


def uniform_(tensor: torch.Tensor, bound: float, generators: Sequence[torch.Generator]) -> None:
    """Fill slice k of ``tensor`` with U(-bound, bound) drawn from ``generators[k]``."""
    with torch.no_grad():
        for k, generator in enumerate(generators):
            values = torch.rand(tensor.shape[1:], generator=generator, dtype=tensor.dtype)
            tensor[k].copy_(values.mul_(2 * bound).sub_(bound))


class _EnsembleAffine(torch.autograd.Function):
    """y_k = x_k W_kᵀ + b_k for every ensemble member k, with the weight gradient built in W's own layout; each of
    the three products runs on the path its layer's :class:`~ilcsan.compute.matmul.MatmulPath` gives its shapes
    (``paths``: forward, ∂L/∂x, ∂L/∂W).

    Autograd's generic rule for ``baddbmm(b, x, Wᵀ)`` produces ∂L/∂Wᵀ = xᵀ g and hands back its transpose, a
    non-contiguous view that AccumulateGrad then copies into W's layout on every backward pass. Here
    ∂L/∂W = gᵀ x is computed directly as a contiguous (K, out, in) tensor: the same numbers, one copy fewer
    per layer.
    """

    @staticmethod
    def forward(flat: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None,  # noqa: D102
                paths: tuple[str, str, str]) -> torch.Tensor:
        if bias is None:
            return ensemble_matmul(flat, weight, paths[0])
        if paths[0] == "aten":  # the bias rides in the BLAS call
            return torch.baddbmm(bias.unsqueeze(1), flat, weight.transpose(1, 2))
        return ensemble_matmul(flat, weight, paths[0]) + bias.unsqueeze(1)

    @staticmethod
    def setup_context(ctx, inputs, output) -> None:  # noqa: D102
        flat, weight, bias, paths = inputs
        ctx.save_for_backward(flat, weight)
        ctx.has_bias, ctx.paths = bias is not None, paths

    @staticmethod
    def backward(ctx, grad_output: torch.Tensor):  # noqa: D102
        # Every gradient is computed, needed or not: traced by torch.compile through torch.func.grad_and_value
        # (torch 2.13), ctx.needs_input_grad reported wrong flags and skipping on them silently dropped gradients;
        # the update program's torch.autograd.grad tracing (compute.programs.value_and_grads) was not checked for it.
        flat, weight = ctx.saved_tensors
        grad_bias = grad_output.sum(dim=1) if ctx.has_bias else None
        grad_input = ensemble_matmul(grad_output, weight.transpose(1, 2), ctx.paths[1])  # g W
        grad_weight = ensemble_matmul(grad_output.transpose(1, 2), flat.transpose(1, 2), ctx.paths[2])  # gᵀ x
        return grad_input, grad_weight, grad_bias, None


def affine_paths(matmul_path: MatmulPath, flat_shape: Sequence[int],
                 weight_shape: Sequence[int]) -> tuple[str, str, str]:
    """The paths of a layer's three products for input (K, R, in) and weight (K, out, in): the forward product
    x Wᵀ, ∂L/∂x = g W (a (K, R, out) by (K, in, out) product) and ∂L/∂W = gᵀ x ((K, out, R) by (K, in, R))."""
    k, rows, d_in = flat_shape
    d_out = weight_shape[1]
    return (matmul_path.product_path(flat_shape, weight_shape),
            matmul_path.product_path((k, rows, d_out), (k, d_in, d_out)),
            matmul_path.product_path((k, d_out, rows), (k, d_in, rows)))


class EnsembleLinear(nn.Module):
    """K fully-connected layers y = W_k x + b_k, weight (K, out, in), bias (K, out), whose products run on
    ``matmul_path``.

    Initialised as ``torch.nn.Linear``: W, b ~ U(−1/√in, 1/√in).
    """

    def __init__(self, ensemble: int, in_features: int, out_features: int, bias: bool = True,
                 matmul_path: MatmulPath = DEFAULT_MATMUL):
        super().__init__()
        self.in_features, self.out_features, self.matmul_path = in_features, out_features, matmul_path
        self.weight = nn.Parameter(torch.empty(ensemble, out_features, in_features))
        self.bias = nn.Parameter(torch.empty(ensemble, out_features)) if bias else None

    def reset_parameters(self, generators: Sequence[torch.Generator]) -> None:
        """Draw slice k from ``generators[k]`` (weight first, then bias)."""
        bound = 1.0 / math.sqrt(self.in_features)
        uniform_(self.weight, bound, generators)
        if self.bias is not None:
            uniform_(self.bias, bound, generators)

    def forward(self, inputs: torch.Tensor, members: slice | None = None) -> torch.Tensor:
        """``inputs`` (K, ..., in) → (K, ..., out); the middle dimensions are flattened for one bmm.

        ``members`` selects a subset of the ensemble (then K is the subset's size).
        """
        shape = inputs.shape
        flat = inputs.reshape(shape[0], -1, shape[-1])
        weight, bias = self.weight, self.bias
        if members is not None:
            weight, bias = weight[members], (bias[members] if bias is not None else None)
        out = _EnsembleAffine.apply(flat, weight, bias, affine_paths(self.matmul_path, flat.shape, weight.shape))
        return out.reshape(*shape[:-1], self.out_features)

    def extra_repr(self) -> str:
        return f"ensemble={self.weight.shape[0]}, in={self.in_features}, out={self.out_features}"


class EnsembleMLP(nn.Module):
    """K multilayer perceptrons with ReLU between layers (TD3's critic and deep actor)."""

    def __init__(self, ensemble: int, sizes: Sequence[int], matmul_path: MatmulPath = DEFAULT_MATMUL):
        super().__init__()
        self.layers = nn.ModuleList(
            EnsembleLinear(ensemble, d_in, d_out, matmul_path=matmul_path) for d_in, d_out in zip(sizes[:-1], sizes[1:],
                                                                                       strict=True)
        )

    def reset_parameters(self, generators: Sequence[torch.Generator]) -> None:
        for layer in self.layers:
            layer.reset_parameters(generators)

    def forward(self, inputs: torch.Tensor, members: slice | None = None) -> torch.Tensor:
        hidden = inputs
        for index, layer in enumerate(self.layers):
            hidden = layer(hidden, members)
            if index < len(self.layers) - 1:
                hidden = torch.relu(hidden)
        return hidden


def seed_generators(seeds: Sequence[int], salt: int) -> list[torch.Generator]:
    """One CPU generator per seed, offset by ``salt`` so actor and critic draw different streams."""
    return [torch.Generator().manual_seed(int(seed) * 1_000_003 + salt) for seed in seeds]
