"""SAC (Haarnoja et al., "Soft Actor-Critic Algorithms and Applications", arXiv 1812.05905) for every actor; its
settings (``entropy_lr``, ``initial_entropy_coefficient``) are declared in :mod:`ilcsan.methods.sac`.

The actor's output populations decode 2M values (:attr:`SAC.readouts` = 2): a mean μ and a log-std
log σ (clamped to [−20, 2]) per action dimension, for the squashed Gaussian a = offset + scale · tanh(u),
u = μ + σ ε, ε ~ N(0, I). Its log-density, by the change of variables through tanh,

    log π(a | s) = Σ_m [log N(ε_m; 0, 1) − log σ_m − log(1 − tanh²(u_m))],

with log(1 − tanh² u) = 2 (log 2 − u − softplus(−2u)) (the action scale's constant Jacobian is left out, as in SAC's
code). One update of K seeds, every environment step of an update chunk:

* critics: y = r + γ(1 − d) (min_j Q'_j(s', a') − α log π(a' | s')), a' ~ π(· | s'); one Adam step on
  Σ_j (Q_j(s, a) − y)²;
* actor: one Adam step on mean_b (α log π(ã | s) − min_j Q_j(s, ã)), ã ~ π(· | s) reparameterised, with the updated
  critics (plus the loss terms of the pre-tanh mean μ, :meth:`~ilcsan.rl.methods.actor_methods.
  ActorMethods.with_loss_terms`);
* entropy coefficient: one Adam step of log α on −mean_b log α (log π(ã | s) + H̄), H̄ = −M the target entropy
  (SAC's automatic tuning), with the same sample ã;
* targets: θ' ← τθ + (1 − τ)θ'.

α of the update is the one before its step. There is no target actor. Exploration samples from π; evaluation and
deployment act with the mean, a = offset + scale · tanh(μ), so the deployed actor keeps only the mean's populations
(:meth:`~ilcsan.rl.algorithms.base.OffPolicyAlgorithm.deployable_actor`), and its persistent buffers cut alike. The
actor's normalisation (:class:`~ilcsan.rl.methods.Normalization`) chooses the options of the actor
loss's pass and writes the actor's persistent buffers after the actor's step; the target values' pass, before it,
reads them as they were.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ...compute.programs import CompiledPerShape, as_function, as_program, module_tensors, value_and_grads
from ...runs.checkpoint import load_state, slice_state
from ...snn.output import PassOptions
from ..adam import Adam, adam_
from .base import OffPolicyAlgorithm

READOUT = PassOptions(preaction=True)
"""The actor's pass SAC reads: its 2M decoded values (μ, raw log σ) beside the action."""
LOG_STD_BOUNDS = (-20.0, 2.0)
"""The log-std's clamp (SAC's code and PopSAN's SAC)."""
LOG_2 = math.log(2.0)
HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


class EntropyCoefficient(nn.Module):
    """log α per seed (K,), the only parameter of SAC's entropy tuning."""

    def __init__(self, seeds: int, initial: float, device: torch.device):
        super().__init__()
        self.log_alpha = nn.Parameter(torch.full((seeds,), math.log(initial), device=device))


class SAC(OffPolicyAlgorithm):
    """K SAC agents (see the module docstring)."""

    readouts = 2
    actor_loss_critics = 2

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.entropy = EntropyCoefficient(len(self.seeds), self.training.initial_entropy_coefficient, self.device)
        self.entropy_adam = Adam(self.entropy, self.training.entropy_lr)
        self.target_entropy = -float(self.action_dim)
        self.readout_fn = CompiledPerShape(self.actor, self._readout) if self.compiled else self._readout
        constants = [self.scale, self.offset]
        for module in (self.actor, self.critic, self.critic_target, self.entropy):
            constants += module_tensors(module)
        self.update_step = as_program(self._update_step, constants, self.compiled)

    def _readout(self, state: torch.Tensor) -> torch.Tensor:
        """The actor's 2M decoded values (μ, raw log σ) for normalised states (K, B, N) → (K, B, 2M)."""
        return self.actor(state, READOUT)[1]

    # ------------------------------------------------------------------ the training loop's
    @torch.no_grad()
    def explore(self, normalized_state: np.ndarray, rngs: Sequence[np.random.Generator]) -> np.ndarray:
        """a = offset + scale · tanh(μ + σ ε) per seed, ε from the seed's numpy generator."""
        readout = self.readout_fn(torch.as_tensor(normalized_state[:, None, :], device=self.device))[:, 0]
        mean, log_std = readout.cpu().numpy().astype(np.float64).reshape(len(rngs), 2, self.action_dim).swapaxes(0, 1)
        noise = np.stack([rng.standard_normal(self.action_dim) for rng in rngs])
        std = np.exp(np.clip(log_std, *LOG_STD_BOUNDS))
        return self.action_offset + self.action_scale * np.tanh(mean + std * noise)

    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor | None]:
        """One SAC update (the module docstring); the noise of a' and ã is drawn here from the seeds' generators."""
        self.updates += 1
        size = batch["obs"].shape[1]
        batch = {**batch, "next_noise": self.standard_noise(size), "noise": self.standard_noise(size)}
        critic_loss, actor_loss = self.run(self.update_step, batch)
        return {"critic_loss": critic_loss, "actor_loss": actor_loss}

    # ------------------------------------------------------------------------------- the losses
    def sample(self, actor: Callable, states: torch.Tensor, noise: torch.Tensor,
               options: PassOptions = READOUT) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(a, log π(a | s), μ) for states (K, B, N) and standard noise ε (K, B, M): a reparameterised sample from
        the actor's pass under ``options`` (which ask for the pre-tanh readout)."""
        readout = actor(states, options)[1]
        mean, log_std = readout[..., :self.action_dim], readout[..., self.action_dim:]
        log_std = log_std.clamp(*LOG_STD_BOUNDS)
        pre_tanh = mean + log_std.exp() * noise
        gaussian = -0.5 * noise ** 2 - log_std - HALF_LOG_2PI
        squash = 2.0 * (LOG_2 - pre_tanh - F.softplus(-2.0 * pre_tanh))
        log_prob = (gaussian - squash).sum(dim=-1)
        return self.offset + self.scale * torch.tanh(pre_tanh), log_prob, mean

    def target_values(self, batch: dict[str, torch.Tensor], actor: Callable, target_critic: Callable,
                      alpha: torch.Tensor) -> torch.Tensor:
        """y = r + γ(1 − d)(min_j Q'_j(s', a') − α log π(a' | s')), shape (K, B)."""
        next_action, next_log_prob, _ = self.sample(actor, batch["next_obs"], batch["next_noise"])
        soft_q = target_critic(batch["next_obs"], next_action).min(dim=1).values - alpha[:, None] * next_log_prob
        return batch["reward"] + self.training.gamma * (1.0 - batch["terminal"]) * soft_q

    def actor_loss(self, actor: list, buffers: list, critic: list, alpha: torch.Tensor,
                   batch: dict) -> tuple[torch.Tensor, tuple[torch.Tensor, tuple]]:
        """(Σ_k mean_b (α log π(ã | s) − min_j Q_j(s, ã)) [+ the loss terms of μ], (log π(ã | s) (K, B), what the
        actor's pass recorded)), the pass with the normalisation method's options
        (:meth:`~ilcsan.rl.methods.Normalization.loss_pass`)."""
        record: list = []
        options = PassOptions(**self.actor_methods.loss_pass(record), preaction=True)
        acting = self.update_tensors.stateful(self.actor, actor, buffers)
        action, log_prob, mean = self.sample(acting, batch["obs"], batch["noise"], options)
        q_value = as_function(self.critic, critic, self.critic_names)(batch["obs"], action).min(dim=1).values
        loss = self.actor_methods.with_loss_terms((alpha[:, None] * log_prob - q_value).mean(dim=-1).sum(), mean)
        return loss, (log_prob, tuple(record))

    def _update_step(self, tensors: dict, batch: dict) -> tuple[torch.Tensor, torch.Tensor]:
        alpha = tensors["entropy"][0].exp()
        with torch.no_grad():
            actor = self.update_tensors.stateful(self.actor, tensors["actor"], tensors["actor_buffers"])
            target = self.target_values(batch, actor,
                                        as_function(self.critic_target, tensors["critic_target"], self.critic_names),
                                        alpha)
        critic_loss = self.step_critics(tensors, batch, target)
        grads, (actor_loss, (log_prob, record)) = value_and_grads(
            self.actor_loss, tensors["actor"], tensors["actor_buffers"], tensors["critic"], alpha, batch, has_aux=True)
        adam_(tensors["actor"], self.actor_methods.gradients(grads), *tensors["actor_adam"],
              lr=self.actor_config.learning_rate)
        self.actor_methods.after_actor_step(tensors["actor_buffers"], record, batch["obs"].shape[1])
        # ∂/∂log α of −mean_b log α (log π + H̄), per seed
        entropy_grads = [-(log_prob + self.target_entropy).mean(dim=-1)]
        adam_(tensors["entropy"], entropy_grads, *tensors["entropy_adam"], lr=self.training.entropy_lr)
        self.follow_critics(tensors)
        return critic_loss, actor_loss

    def tensors(self) -> dict[str, list]:
        return {**super().tensors(), "entropy": self.entropy_adam.views, "entropy_adam": self.entropy_adam.tensors()}

    @property
    def alpha(self) -> np.ndarray:
        """Each seed's entropy coefficient α."""
        return self.entropy.log_alpha.detach().exp().cpu().numpy()

    # --------------------------------------------------------------------------- checkpoints
    def seed_state(self, index: int) -> dict[str, Any]:
        return {**super().seed_state(index), "entropy": slice_state(self.entropy, index, 1),
                "entropy_optimizer": self.entropy_adam.seed_state(index, 1)}

    def load_seed_states(self, states: Sequence[dict[str, Any]]) -> None:
        super().load_seed_states(states)
        load_state(self.entropy, [state["entropy"] for state in states], "entropy coefficient")
        self.entropy_adam.load_seed_states([state["entropy_optimizer"] for state in states])
