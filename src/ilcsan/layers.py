"""Synaptic layers with an ensemble dimension: K independent networks in one batched module.

Every trainable tensor carries a leading dimension K (the number of seeds trained together, 1 for an
ordinary run), so one batched matmul serves K agents (``torch.baddbmm``). Slice ``k`` is initialised
from its own generator, in the same order whatever K is: seed k of a K-seed run starts from exactly the
weights of a single run with seed k.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn


def uniform_(tensor: torch.Tensor, bound: float, generators: Sequence[torch.Generator]) -> None:
    """Fill slice k of ``tensor`` with U(-bound, bound) drawn from ``generators[k]``."""
    with torch.no_grad():
        for k, generator in enumerate(generators):
            values = torch.rand(tensor.shape[1:], generator=generator, dtype=tensor.dtype)
            tensor[k].copy_(values.mul_(2 * bound).sub_(bound))


class EnsembleLinear(nn.Module):
    """K fully-connected layers y = W_k x + b_k, weight (K, out, in), bias (K, out).

    Initialised as ``torch.nn.Linear``: W, b ~ U(−1/√in, 1/√in).
    """

    def __init__(self, ensemble: int, in_features: int, out_features: int, bias: bool = True):
        super().__init__()
        self.in_features, self.out_features = in_features, out_features
        self.weight = nn.Parameter(torch.empty(ensemble, out_features, in_features))
        self.bias = nn.Parameter(torch.empty(ensemble, out_features)) if bias else None

    def reset_parameters(self, generators: Sequence[torch.Generator]) -> None:
        """Draw slice k from ``generators[k]`` (weight first, then bias)."""
        bound = 1.0 / math.sqrt(self.in_features)
        uniform_(self.weight, bound, generators)
        if self.bias is not None:
            uniform_(self.bias, bound, generators)

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        """``inputs`` (K, ..., in) → (K, ..., out); the middle dimensions are flattened for one bmm."""
        shape = inputs.shape
        flat = inputs.reshape(shape[0], -1, shape[-1])
        weight_t = self.weight.transpose(1, 2)
        if self.bias is None:
            out = torch.bmm(flat, weight_t)
        else:
            out = torch.baddbmm(self.bias.unsqueeze(1), flat, weight_t)
        return out.reshape(*shape[:-1], self.out_features)

    def extra_repr(self) -> str:
        return f"ensemble={self.weight.shape[0]}, in={self.in_features}, out={self.out_features}"


class EnsembleMLP(nn.Module):
    """K multilayer perceptrons with ReLU between layers (TD3's critic and deep actor)."""

    def __init__(self, ensemble: int, sizes: Sequence[int]):
        super().__init__()
        self.layers = nn.ModuleList(
            EnsembleLinear(ensemble, d_in, d_out) for d_in, d_out in zip(sizes[:-1], sizes[1:], strict=True)
        )

    def reset_parameters(self, generators: Sequence[torch.Generator]) -> None:
        for layer in self.layers:
            layer.reset_parameters(generators)

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        hidden = inputs
        for index, layer in enumerate(self.layers):
            hidden = layer(hidden)
            if index < len(self.layers) - 1:
                hidden = torch.relu(hidden)
        return hidden


def seed_generators(seeds: Sequence[int], salt: int) -> list[torch.Generator]:
    """One CPU generator per seed, offset by ``salt`` so actor and critic draw different streams."""
    return [torch.Generator().manual_seed(int(seed) * 1_000_003 + salt) for seed in seeds]
