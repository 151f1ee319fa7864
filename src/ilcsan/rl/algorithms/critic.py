"""The deep critic of every algorithm (Section III-E): C Q-networks per seed in stacked weights."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from ...compute.matmul import DEFAULT_MATMUL, MatmulPath
from ...snn.ensemble import EnsembleMLP, seed_generators

CRITIC_SALT = 2


class Critics(nn.Module):
    """C·K critics (N+M, 256, ReLU, 256, ReLU, 1): Q_j of seed k at slice C·k + j, all evaluated in one batched
    matmul. C = 2 is TD3's and SAC's twin, C = 1 DDPG's single critic; seed k's C critics are initialised one after
    the other from the seed's own generator."""

    def __init__(self, state_dim: int, action_dim: int, hidden: Sequence[int], seeds: Sequence[int], count: int = 2,
                 matmul_path: MatmulPath = DEFAULT_MATMUL):
        super().__init__()
        self.ensemble, self.count = len(seeds), count
        self.mlp = EnsembleMLP(count * self.ensemble, [state_dim + action_dim, *hidden, 1], matmul_path)
        generators = seed_generators(seeds, CRITIC_SALT)
        self.mlp.reset_parameters([g for g in generators for _ in range(count)])

    def forward(self, state: torch.Tensor, action: torch.Tensor, first_only: bool = False) -> torch.Tensor:
        """(K, B, N), (K, B, M) → Q values (K, C, B); with ``first_only`` Q_1 alone, (K, B) (a keyword, so that a
        functional call of the module reaches it)."""
        if first_only:
            return self.first(state, action)
        inputs = torch.cat([state, action], dim=-1)
        k, b, d = inputs.shape
        copies = inputs.unsqueeze(1).expand(k, self.count, b, d).reshape(self.count * k, b, d)
        return self.mlp(copies).reshape(k, self.count, b)

    def first(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Q_1 only (TD3's and DDPG's actor objective): (K, B, N), (K, B, M) → (K, B), 1/C of ``forward``'s work."""
        return self.mlp(torch.cat([state, action], dim=-1), members=slice(0, None, self.count)).squeeze(-1)
