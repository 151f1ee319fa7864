"""TD3 (Fujimoto et al. 2018) with a deep twin critic, as the paper trains every actor (Section III-E).

The agent holds K independent agents in stacked weights: the actor ensemble, a critic ensemble of 2K
MLPs (the twin critics of seed k are slices 2k and 2k+1, evaluated in one batched matmul) and their
targets. Losses are summed over seeds, so each seed's gradient is exactly its own; Adam is elementwise,
so one optimizer over stacked weights equals K separate optimizers.

One update (:mod:`ilcsan.rl.update`, defined once, compiled or not), in TD3's order:
  ã = clip(π'(s') + clip(ε, −c, c), low, high),  ε ~ N(0, σ̃²)             target policy smoothing
  y = r + γ (1 − terminal) min_j Q'_j(s', ã)                                clipped double-Q
  critic ← ∇ Σ_j (Q_j(s, a) − y)²
  every d updates: actor ← ∇ −Q_1(s, π(s)); targets ← τ θ + (1 − τ) θ'      delayed policy updates

How the actor explores and which actor is π' are training methods (:mod:`ilcsan.rl.methods`): TD3's Gaussian action
noise and Polyak-averaged target by default; NoisySAN and Proxy Target are the others.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from ..compute.matmul import DEFAULT_MATMUL, MatmulPath
from ..compute.programs import CompiledPerShape, prepare_compilation
from ..config import ActorConfig, TD3Config
from ..runs.checkpoint import load_state, slice_state
from ..snn.actor import build_actor
from ..snn.ensemble import EnsembleMLP, seed_generators
from .adam import Adam
from .methods import MethodContext, exploration_method, target_actor_method
from .update import TD3Update

CRITIC_SALT = 2
NOISE_SALT = 3


class TwinCritic(nn.Module):
    """2K critics (N+M, 256, ReLU, 256, ReLU, 1): Q_1 and Q_2 of seed k at slices 2k and 2k+1."""

    def __init__(self, state_dim: int, action_dim: int, hidden: Sequence[int], seeds: Sequence[int],
                 matmul: MatmulPath = DEFAULT_MATMUL):
        super().__init__()
        self.ensemble = len(seeds)
        self.mlp = EnsembleMLP(2 * self.ensemble, [state_dim + action_dim, *hidden, 1], matmul)
        generators = seed_generators(seeds, CRITIC_SALT)
        self.mlp.reset_parameters([g for g in generators for _ in range(2)])

    def forward(self, state: torch.Tensor, action: torch.Tensor, first_only: bool = False) -> torch.Tensor:
        """(K, B, N), (K, B, M) → Q values (K, 2, B); with ``first_only`` Q_1 alone, (K, B)."""
        if first_only:
            return self.first(state, action)
        inputs = torch.cat([state, action], dim=-1)
        k, b, d = inputs.shape
        twin = inputs.unsqueeze(1).expand(k, 2, b, d).reshape(2 * k, b, d)
        return self.mlp(twin).reshape(k, 2, b)

    def first(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Q_1 only (the actor's objective): (K, B, N), (K, B, M) → (K, B), half the work of ``forward``."""
        return self.mlp(torch.cat([state, action], dim=-1), members=slice(0, None, 2)).squeeze(-1)


AGENT_NETWORKS = (("actor", "actor", 1), ("actor_target", "target actor (Proxy Target: the proxy)", 1),
                  ("critic", "critic", 2), ("critic_target", "target critic", 2))
"""The agent's networks in a checkpoint: (attribute and key, what it is called in errors, rows per seed)."""


class TD3Agent:
    """K TD3 agents in stacked weights on one device; ``engine`` is the actor's forward pass ('fast' or
    'reference'); ``compile`` runs each update as one compiled program (:mod:`ilcsan.rl.update`) and compiles a
    spiking actor's acting pass; ``matmul`` is where every network's products run."""

    def __init__(self, actor_config: ActorConfig, td3: TD3Config, state_dim: int, action_dim: int,
                 action_scale: Sequence[float], action_offset: Sequence[float], seeds: Sequence[int],
                 device: str | torch.device = "cpu", compile: bool = False, engine: str = "fast", task: str = "",
                 episode_steps: int | None = None, matmul: MatmulPath = DEFAULT_MATMUL):
        self.config, self.td3, self.seeds = actor_config, td3, list(seeds)
        self.device = torch.device(device)
        self.actor = build_actor(actor_config, state_dim, action_dim, action_scale, action_offset, self.seeds,
                                 engine=engine, matmul=matmul).to(self.device)
        self.critic = TwinCritic(state_dim, action_dim, td3.critic_hidden, self.seeds, matmul).to(self.device)
        self.critic_target = copy.deepcopy(self.critic)
        self.critic_target.requires_grad_(False)
        if compile:
            prepare_compilation()
        context = MethodContext(self.actor, actor_config, td3, task, episode_steps, tuple(self.seeds), state_dim,
                                action_dim, np.asarray(action_scale), np.asarray(action_offset), self.device,
                                compile, matmul)
        self.target = target_actor_method(td3.target_actor)(context)
        self.exploration = exploration_method(td3.exploration)(context)
        self.actor_adam = Adam(self.actor, actor_config.learning_rate)
        self.critic_adam = Adam(self.critic, td3.critic_lr)
        self.compiled = compile
        # compile: the acting forward pass too (a spiking actor's many small neuron-update ops fuse into a few loops;
        # for DAN the program saves the eager per-op dispatch of a batch-1 action)
        self.actor_fn = CompiledPerShape(self.actor) if compile else self.actor
        self.noise_generators = [torch.Generator(device=self.device).manual_seed(seed * 1_000_003 + NOISE_SALT)
                                 for seed in self.seeds]
        self.scale = torch.as_tensor(np.asarray(action_scale), dtype=torch.float32, device=self.device)
        self.offset = torch.as_tensor(np.asarray(action_offset), dtype=torch.float32, device=self.device)
        self.updates = 0
        self.program = TD3Update(self, compile)

    @property
    def actor_target(self) -> nn.Module:
        """π' in TD3's target values: the target actor method's network (:mod:`ilcsan.rl.methods`)."""
        return self.target.module

    @property
    def execution(self) -> str:
        """What runs compiled, for progress lines: 'compiled update + acting' or 'eager'."""
        return "compiled update + acting" if self.compiled else "eager"

    # ------------------------------------------------------------------------------- acting
    @torch.no_grad()
    def act(self, normalized_state: np.ndarray) -> np.ndarray:
        """Deterministic actions for normalised states: (K, N) → (K, M), or (K, B, N) → (K, B, M)."""
        if normalized_state.ndim == 2:
            return self.act(normalized_state[:, None, :])[:, 0]
        return self.actor_fn(torch.as_tensor(normalized_state, device=self.device)).cpu().numpy()

    def explore(self, normalized_state: np.ndarray, rngs: Sequence[np.random.Generator]) -> np.ndarray:
        """The exploring actions (K, N) → (K, M) of the run's exploration method (after the random phase)."""
        return self.exploration.explore(self, normalized_state, rngs)

    # ------------------------------------------------------------------------------ learning
    def _standard_noise(self, batch_size: int) -> torch.Tensor:
        """ε/σ̃ ~ N(0, 1) of shape (K, B, M), each seed from its own generator."""
        shape = (batch_size, len(self.scale))
        return torch.stack([torch.randn(shape, generator=g, device=self.device) for g in self.noise_generators])

    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor | None]:
        """One TD3 update for all K seeds (:mod:`ilcsan.rl.update`); returns the summed losses (actor loss on delayed
        steps). The target actor method runs first (Proxy Target fits its proxy on ``batch["proxy_obs"]``); on a
        delayed step the exploration method adds what the actor loss needs (NoisySAN's noise)."""
        self.target.before_update(self, batch)
        self.updates += 1
        delayed = self.updates % self.td3.policy_delay == 0
        if delayed:
            batch = {**batch, **self.exploration.update_inputs(batch["obs"].shape[1])}
        noise = self._standard_noise(batch["next_obs"].shape[1])
        critic_loss, actor_loss = self.program.run(batch, noise, delayed)
        return {"critic_loss": critic_loss, "actor_loss": actor_loss}

    def to_batch(self, arrays: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
        return {name: torch.as_tensor(value, device=self.device) for name, value in arrays.items()}

    # --------------------------------------------------------------------------- checkpoints
    def seed_state(self, index: int) -> dict[str, Any]:
        """Seed ``index``'s networks, Adam states, methods' states, update count and smoothing-noise generator."""
        state: dict[str, Any] = {key: slice_state(getattr(self, key), index, rows) for key, _, rows in AGENT_NETWORKS}
        state["actor_optimizer"] = self.actor_adam.seed_state(index, 1)
        state["critic_optimizer"] = self.critic_adam.seed_state(index, 2)
        state.update(self.target.seed_state(index) or {})
        exploration = self.exploration.seed_state(index)
        if exploration is not None:
            state["exploration"] = exploration
        state["updates"] = self.updates
        state["noise_generator"] = self.noise_generators[index].get_state()
        return state

    def load_seed_states(self, states: Sequence[dict[str, Any]]) -> None:
        """Stack the seeds' :meth:`seed_state` dicts into this agent (its seeds in the same order)."""
        for key, what, _ in AGENT_NETWORKS:
            load_state(getattr(self, key), [state[key] for state in states], what)
        self.actor_adam.load_seed_states([state["actor_optimizer"] for state in states])
        self.critic_adam.load_seed_states([state["critic_optimizer"] for state in states])
        self.target.load_seed_states(states)
        if self.exploration.module is not None:
            self.exploration.load_seed_states([state["exploration"] for state in states])
        for generator, state in zip(self.noise_generators, states, strict=True):
            generator.set_state(state["noise_generator"])
        self.updates = states[0]["updates"]
