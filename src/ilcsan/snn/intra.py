"""Intra-layer connections of the output populations (Section III-D, Eq. (10); ablations, Table intra).

For output population m:  I_{t+1}^m = W_intra^m S_t^{L,m} + b_intra^m                     Eq. (10)
with W_intra^m a square P_out × P_out matrix. The current reaches the output layer one step later and
never at t = 1 (Algorithm 1, ``intra_timing="paper"``). The authors' released code (``popsan.py``) instead adds
W_intra S_{t−1} + b_intra at every step t = 1..T with S_0 = 0, so that b_intra also arrives at t = 1
(``intra_timing="authors"``): at t = 1 the output layer then receives its own bias twice, and that copy of
b_intra shares the output bias's gradient at that step.

The ablations of Table "intra" are masks on this one mechanism: the diagonal of W_intra is the self
connection, the off-diagonal the lateral connections, b_intra the bias. A masked weight is zero at
initialisation and its gradient is zero (the forward multiplies by the mask), so it stays exactly zero
under Adam, while every kept weight trains.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from ..config import IntraMask
from .ensemble import uniform_


def weight_mask(population: int, mask: IntraMask) -> torch.Tensor:
    """P × P 0/1 matrix: ones on the diagonal if self, off the diagonal if lateral."""
    eye = torch.eye(population)
    return eye * float(mask.self_weights) + (1 - eye) * float(mask.lateral_weights)


class IntraLayerConnections(nn.Module):
    """W_intra (K, M, P, P) and b_intra (K, M, P) for K ensembles of M output populations of size P."""

    def __init__(self, ensemble: int, populations: int, population_size: int, mask: IntraMask,
                 bias_at_first_step: bool = False):
        super().__init__()
        self.mask, self.bias_at_first_step = mask, bias_at_first_step
        self.weight = nn.Parameter(torch.empty(ensemble, populations, population_size, population_size))
        self.bias = nn.Parameter(torch.empty(ensemble, populations, population_size))
        # constants of the configuration, not state (the convention: :mod:`ilcsan.snn.ensemble`)
        self.register_buffer("weight_mask", weight_mask(population_size, mask), persistent=False)
        self.register_buffer("bias_mask", torch.tensor(float(mask.bias)), persistent=False)

    def reset_parameters(self, generators: Sequence[torch.Generator]) -> None:
        """U(−1/√P, 1/√P) like a Linear(P, P) per population, then the mask applied."""
        bound = 1.0 / math.sqrt(self.weight.shape[-1])
        uniform_(self.weight, bound, generators)
        uniform_(self.bias, bound, generators)
        with torch.no_grad():
            self.weight.mul_(self.weight_mask)
            self.bias.mul_(self.bias_mask)

    def masked_weight(self) -> torch.Tensor:
        return self.weight * self.weight_mask

    def masked_bias(self) -> torch.Tensor:
        return self.bias * self.bias_mask

    def first_current(self, like: torch.Tensor, bias: torch.Tensor | None = None) -> torch.Tensor | None:
        """I_1, the intra-layer current at t = 1 for output currents shaped like ``like`` (K, B, M·P): None under
        Algorithm 1's timing, b_intra (= W_intra S_0 + b_intra with S_0 = 0) under the authors'."""
        if not self.bias_at_first_step:
            return None
        bias = self.masked_bias() if bias is None else bias
        return bias.reshape(bias.shape[0], 1, -1).expand_as(like)

    def forward(self, spikes: torch.Tensor, weight: torch.Tensor | None = None,
                bias: torch.Tensor | None = None) -> torch.Tensor:
        """Eq. (10): spikes (K, B, M·P) at step t → current (K, B, M·P) for step t + 1.

        ``weight``/``bias`` may be passed pre-masked to avoid re-masking on every time step.
        """
        weight = self.masked_weight() if weight is None else weight
        bias = self.masked_bias() if bias is None else bias
        k, b = spikes.shape[:2]
        populations, size = weight.shape[1], weight.shape[2]
        grouped = spikes.reshape(k, b, populations, size)
        current = torch.einsum("kbmq,kmpq->kbmp", grouped, weight) + bias.unsqueeze(1)
        return current.reshape(k, b, populations * size)
