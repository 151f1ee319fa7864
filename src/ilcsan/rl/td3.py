"""TD3 (Fujimoto et al. 2018) with a deep twin critic, as the paper trains every actor (Section III-E).

The agent holds K independent agents in stacked weights: the actor ensemble, a critic ensemble of 2K
MLPs (the twin critics of seed k are slices 2k and 2k+1, evaluated in one batched matmul) and their
targets. Losses are summed over seeds, so each seed's gradient is exactly its own; Adam is elementwise,
so one optimizer over stacked weights equals K separate optimizers.

One update (``update``), in TD3's order:
  ã = clip(π'(s') + clip(ε, −c, c), low, high),  ε ~ N(0, σ̃²)             target policy smoothing
  y = r + γ (1 − terminal) min_j Q'_j(s', ã)                                clipped double-Q
  critic ← ∇ Σ_j (Q_j(s, a) − y)²
  every d updates: actor ← ∇ −Q_1(s, π(s)); targets ← τ θ + (1 − τ) θ'      delayed policy updates

With ``target_actor = "proxy"`` (Proxy Target, :mod:`ilcsan.rl.proxy`) π' is a continuous proxy fitted to π
before every update instead of the soft-updated copy of π. With ``exploration = "noisy"`` (NoisySAN,
:mod:`ilcsan.rl.noisy_exploration`) the actor's loss sees π with noise in its neurons, −Q_1(s, π(s; ε)), plus the
noise penalty k (mean σ_d)², and σ_d takes an Adam step with the actor.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence

import numpy as np
import torch
from torch import nn

from ..config import ActorConfig, TD3Config
from ..snn.actor import build_actor
from ..snn.ensemble import EnsembleMLP, seed_generators
from .noisy_exploration import ExploringActor, NoisyExploration, noisy_exploration
from .proxy import ProxyTarget, build_proxy
from .update_program import CompiledPerShape, UpdateProgram

CRITIC_SALT = 2
NOISE_SALT = 3


class TwinCritic(nn.Module):
    """2K critics (N+M, 256, ReLU, 256, ReLU, 1): Q_1 and Q_2 of seed k at slices 2k and 2k+1."""

    def __init__(self, state_dim: int, action_dim: int, hidden: Sequence[int], seeds: Sequence[int]):
        super().__init__()
        self.ensemble = len(seeds)
        self.mlp = EnsembleMLP(2 * self.ensemble, [state_dim + action_dim, *hidden, 1])
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


COMPILE_RECOMPILE_LIMIT = 64


def prepare_compilation() -> None:
    """Free the graphs of earlier agents in this process and allow enough variants per function.

    torch.compile guards each graph on the module instance, grad mode and input shapes; one agent needs
    about three variants per forward (acting, training, target), so a process that builds agent after agent
    (``ilcsan reproduce`` workers, benchmarks) would exhaust dynamo's default limit of 8 and silently fall
    back to eager execution.
    """
    import torch._dynamo

    torch._dynamo.reset()
    torch._dynamo.config.recompile_limit = max(torch._dynamo.config.recompile_limit, COMPILE_RECOMPILE_LIMIT)


def polyak_update(target: nn.Module, source: nn.Module, tau: float) -> None:
    """θ' ← τ θ + (1 − τ) θ' for every parameter, in one fused call."""
    with torch.no_grad():
        target_params = list(target.parameters())
        torch._foreach_lerp_(target_params, list(source.parameters()), tau)


class TD3Agent:
    """K TD3 agents in stacked weights on one device; ``engine`` is the actor's forward pass ('fast' or
    'reference'); ``compile`` runs each update as one compiled program (:mod:`ilcsan.rl.update_program`)
    and compiles a spiking actor's acting pass."""

    def __init__(self, actor_config: ActorConfig, td3: TD3Config, state_dim: int, action_dim: int,
                 action_scale: Sequence[float], action_offset: Sequence[float], seeds: Sequence[int],
                 device: str | torch.device = "cpu", compile: bool = False, engine: str = "fast", task: str = "",
                 episode_steps: int | None = None):
        self.config, self.td3, self.seeds = actor_config, td3, list(seeds)
        self.device = torch.device(device)
        self.actor = build_actor(actor_config, state_dim, action_dim, action_scale, action_offset, self.seeds,
                                 engine=engine).to(self.device)
        fused = self.device.type in ("cpu", "cuda")
        self.proxy: ProxyTarget | None = None  # Proxy Target: π' is the proxy, fitted before every update
        if td3.target_actor == "proxy":
            proxy = build_proxy(state_dim, action_dim, action_scale, action_offset, self.seeds).to(self.device)
            self.proxy = ProxyTarget(proxy, td3, fused, compile)
        self.actor_target = copy.deepcopy(self.actor) if self.proxy is None else self.proxy.actor
        self.critic = TwinCritic(state_dim, action_dim, td3.critic_hidden, self.seeds).to(self.device)
        self.critic_target = copy.deepcopy(self.critic)
        for module in (self.actor_target, self.critic_target) if self.proxy is None else (self.critic_target,):
            module.requires_grad_(False)
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=actor_config.learning_rate, fused=fused)
        self.critic_optimizer = torch.optim.Adam(self.critic.parameters(), lr=td3.critic_lr, fused=fused)
        self.exploration: NoisyExploration | None = None  # NoisySAN: noise in the neurons instead of on the action
        if td3.exploration == "noisy":
            self.exploration = noisy_exploration(self.actor, td3, task, episode_steps, self.seeds,
                                                 actor_config.learning_rate, self.device)
        # compile: the whole update runs as one compiled program (UpdateProgram) and the acting forward pass is
        # compiled too (a spiking actor's many small neuron-update ops fuse into a few loops; for DAN the program
        # saves the eager per-op dispatch: a batch-1 action 169 → 42 µs in the Hopper training loop).
        self.compiled = compile
        if compile:
            prepare_compilation()
        self.actor_fn = CompiledPerShape(self.actor) if compile else self.actor
        if self.exploration is not None:
            exploring = ExploringActor(self.actor, self.exploration)
            self.exploring_fn = CompiledPerShape(exploring) if compile else exploring
        self.noise_generators = [torch.Generator(device=self.device).manual_seed(seed * 1_000_003 + NOISE_SALT)
                                 for seed in self.seeds]
        self.scale = torch.as_tensor(np.asarray(action_scale), dtype=torch.float32, device=self.device)
        self.offset = torch.as_tensor(np.asarray(action_offset), dtype=torch.float32, device=self.device)
        self.updates = 0
        self.program = UpdateProgram(self) if compile else None

    @property
    def execution(self) -> str:
        """What runs compiled, for progress lines: 'compiled update + acting', 'compiled update' or 'eager'."""
        if self.program is None:
            return "eager"
        return "compiled update + acting" if self.actor_fn is not self.actor else "compiled update"

    # ------------------------------------------------------------------------------- acting
    @torch.no_grad()
    def act(self, normalized_state: np.ndarray) -> np.ndarray:
        """Deterministic actions for normalised states: (K, N) → (K, M), or (K, B, N) → (K, B, M)."""
        if normalized_state.ndim == 2:
            return self.act(normalized_state[:, None, :])[:, 0]
        return self.actor_fn(torch.as_tensor(normalized_state, device=self.device)).cpu().numpy()

    @torch.no_grad()
    def explore(self, normalized_state: np.ndarray) -> np.ndarray:
        """NoisySAN's exploring actions (K, N) → (K, M): the actor with the next window of each seed's noise
        series in its neurons (compiled with the update; the deterministic :meth:`act` is unchanged)."""
        state = torch.as_tensor(normalized_state[:, None, :], device=self.device)
        return self.exploring_fn(state, self.exploration.acting_noise())[:, 0].cpu().numpy()

    # ------------------------------------------------------------------------------ learning
    def _standard_noise(self, batch_size: int) -> torch.Tensor:
        """ε/σ̃ ~ N(0, 1) of shape (K, B, M), each seed from its own generator."""
        shape = (batch_size, len(self.scale))
        return torch.stack([torch.randn(shape, generator=g, device=self.device) for g in self.noise_generators])

    def target_values(self, next_obs: torch.Tensor, standard_noise: torch.Tensor, reward: torch.Tensor,
                      terminal: torch.Tensor, target_actor: Callable | None = None,
                      target_critic: Callable | None = None) -> torch.Tensor:
        """y = r + γ (1 − terminal) min_j Q'_j(s', clip(π'(s') + clip(σ̃ ε, −c, c), low, high)), shape (K, B).

        ``target_actor``/``target_critic`` replace π' and Q' (the update program passes them as functions of its
        parameter tensors); by default they are the agent's target modules."""
        target_actor = target_actor or self.actor_target
        target_critic = target_critic or self.critic_target
        clip = self.td3.noise_clip
        noise = (standard_noise * self.td3.target_noise).clamp(-clip, clip) * self.scale
        next_action = target_actor(next_obs) + noise
        next_action = torch.maximum(torch.minimum(next_action, self.offset + self.scale), self.offset - self.scale)
        target_q = target_critic(next_obs, next_action).min(dim=1).values
        return reward + self.td3.gamma * (1.0 - terminal) * target_q

    def critic_loss(self, batch: dict[str, torch.Tensor], target: torch.Tensor | None = None,
                    critic: Callable | None = None) -> torch.Tensor:
        """Σ_k Σ_j mean_b (Q_j(s, a) − y)², with y from the target actor and the min of the target twins (drawn
        here unless ``target`` is given); ``critic`` replaces the critic module."""
        if target is None:
            with torch.no_grad():
                noise = self._standard_noise(batch["next_obs"].shape[1])
                target = self.target_values(batch["next_obs"], noise, batch["reward"], batch["terminal"])
        q_values = (critic or self.critic)(batch["obs"], batch["action"])
        return ((q_values - target.unsqueeze(1)) ** 2).mean(dim=-1).sum()

    def actor_loss(self, batch: dict[str, torch.Tensor], actor: Callable | None = None,
                   critic: Callable | None = None, decoder_sigma: torch.Tensor | None = None) -> torch.Tensor:
        """Σ_k −mean_b Q_1(s, π(s)); ``actor`` and ``critic`` (called with ``first_only=True``) replace the modules.

        NoisySAN: π(s; ε) with the unit noise ``batch["actor_noise"]`` scaled into the neurons, plus the penalty
        Σ_k k_k (mean σ_d)² with ``batch["penalty_weights"]``; ``decoder_sigma`` replaces the parameter σ_d."""
        actor = actor or self.actor
        exploration = self.exploration
        if exploration is None:
            action = actor(batch["obs"])
        else:
            action = actor(batch["obs"], noise=exploration.perturbation(batch["actor_noise"], decoder_sigma))
        loss = -(critic or self.critic)(batch["obs"], action, first_only=True).mean(dim=-1).sum()
        if exploration is not None:
            sigma = exploration.decoder_sigma if decoder_sigma is None else decoder_sigma
            loss = loss + exploration.penalty(sigma, batch["penalty_weights"])
        return loss

    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, float | None]:
        """One TD3 update for all K seeds; returns the summed losses (actor loss on delayed steps).

        With a proxy target, ``batch["proxy_obs"]`` (K_iterations, K_seeds, B, N) holds the proxy's minibatches.
        """
        if self.proxy is not None:
            self.proxy.fit(self.actor_fn, batch["proxy_obs"])
        self.updates += 1
        delayed = self.updates % self.td3.policy_delay == 0
        exploration = self.exploration
        if exploration is not None and delayed:  # NoisySAN: the actor loss's noise, drawn outside the program
            batch = {**batch, "actor_noise": exploration.update_noise(batch["obs"].shape[1]),
                     "penalty_weights": exploration.weights}
        if self.program is not None:
            noise = self._standard_noise(batch["next_obs"].shape[1])
            critic_loss, actor_loss = self.program.run(batch, noise, delayed)
            return {"critic_loss": critic_loss, "actor_loss": actor_loss}
        critic_loss = self.critic_loss(batch)
        self.critic_optimizer.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic_optimizer.step()
        actor_loss = None
        if delayed:
            self.critic.requires_grad_(False)
            loss = self.actor_loss(batch)
            self.actor_optimizer.zero_grad(set_to_none=True)
            if exploration is not None:
                exploration.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.actor_optimizer.step()
            if exploration is not None:
                exploration.optimizer.step()
            self.critic.requires_grad_(True)
            if self.proxy is None:
                polyak_update(self.actor_target, self.actor, self.td3.tau)
            polyak_update(self.critic_target, self.critic, self.td3.tau)
            actor_loss = loss.detach()
        return {"critic_loss": critic_loss.detach(), "actor_loss": actor_loss}

    def to_batch(self, arrays: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
        return {name: torch.as_tensor(value, device=self.device) for name, value in arrays.items()}
