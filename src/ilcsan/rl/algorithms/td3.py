"""TD3 (Fujimoto et al. 2018) with a deep twin critic, as the paper trains every actor (Section III-E), and DDPG as
TD3's paper re-implements it: the same update with TD3's three changes switched off.

One update of K seeds, in TD3's order:

* the critic step: y = r + γ(1 − d) min_j Q'_j(s', ã), ã = clip(π'(s') + clip(σ̃ε, −c, c), low, high) (target policy
  smoothing), and one Adam step of the critics on Σ_j (Q_j(s, a) − y)² (clipped double-Q);
* every ``policy_delay``-th update (delayed policy updates) the same, then one Adam step of the actor on
  −Q_1(s, π(s)) with the *updated* critic (plus what the exploration method adds — π(s) as it evaluates it, terms of
  its own parameters, which step beside the actor's — and the loss terms of the pre-tanh output O of that π(s)),
  then θ' ← τθ + (1 − τ)θ' for the target critic and, when the target actor follows the actor, for the target actor.

The actor's normalisation (:class:`~ilcsan.rl.methods.Normalization`) chooses the options of the actor loss's pass,
writes the actor's persistent buffers after its step and names those the target actor follows with its weights.

DDPG (:class:`DDPG`): one critic (min over one is itself), no smoothing (ã = π'(s')), the actor and targets at every
update. How the actor explores and which actor is π' are training methods (:mod:`ilcsan.rl.methods`); TD3's own, the
paper's, are here: :class:`GaussianActionNoise` and :class:`PolyakTarget`. They change one hook each (the exploring
action; π' as a copy of the actor that follows it); every other hook the update calls keeps its do-nothing default
(:mod:`ilcsan.rl.methods.base`): the actor loss evaluates the actor's own π(s), nothing is added to the minibatch or
the loss, nothing runs before an update or at intervals.

Each variant (critic step; critic and actor step) is one function of the agent's tensors, run eagerly, or as one
compiled program when the run compiles (:func:`~ilcsan.compute.programs.as_program`: the same function either way);
the networks run through ``torch.func.functional_call`` on tensors passed in (:func:`~ilcsan.compute.programs.
as_function`), the gradients and the loss are ``torch.func.grad_and_value``'s (:func:`~ilcsan.compute.programs.
value_and_grads`), Adam is :func:`~ilcsan.rl.adam.adam_`, all in place on the agent's own tensors.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from ...compute.programs import as_function, as_program, module_tensors, value_and_grads
from ...config import TrainingProtocol
from ...snn.output import PassOptions
from ..adam import adam_
from ..methods import Exploration, Method, MethodContext, TargetActor, exploration_method, target_actor_method
from .base import OffPolicyAlgorithm


class TD3(OffPolicyAlgorithm):
    """K TD3 agents; the exploration and target-actor methods are the run's (``training.exploration``,
    ``training.target_actor``)."""

    smoothing = True
    """Target policy smoothing: noise on the target action."""

    @classmethod
    def policy_delay(cls, training: TrainingProtocol) -> int:
        return training.policy_delay

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        context = self.method_context()
        self.target_method = target_actor_method(self.training.target_actor)(context)
        self.exploration = exploration_method(self.training.exploration)(context)
        constants = [self.scale, self.offset]
        for module in (self.actor, self.critic, self.actor_target, self.critic_target, self.exploration.module):
            constants += module_tensors(module) if module is not None else []
        self.critic_step = as_program(self._critic_step, constants, self.compiled)
        self.delayed_step = as_program(self._delayed_step, constants, self.compiled)

    @property
    def actor_target(self) -> nn.Module:
        """π' in the target values: the target actor method's network (:mod:`ilcsan.rl.methods`)."""
        return self.target_method.module

    def methods(self) -> list[Method]:
        return [*super().methods(), self.exploration, self.target_method]

    # ------------------------------------------------------------------ the training loop's
    def explore(self, normalized_state: np.ndarray, rngs: Sequence[np.random.Generator]) -> np.ndarray:
        """The exploration method's actions (TD3's: π(s) + N(0, σ²) clipped to the bounds)."""
        return self.exploration.explore(self, normalized_state, rngs)

    def end_episode(self, index: int) -> None:
        self.exploration.end_episode(index)

    def before_updates(self, evaluations) -> None:
        self.exploration.before_updates(evaluations)

    def extra_samples(self, replay, normalizer, rngs) -> dict[str, np.ndarray]:
        return self.target_method.extra_samples(replay, normalizer, rngs, self.training)

    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor | None]:
        """One update (the module docstring). The target actor method runs first (e.g. fitting a network of its own on
        its :meth:`extra_samples`); on an actor step the exploration method adds what the actor loss needs (e.g. noise
        drawn outside the update program)."""
        self.target_method.before_update(self, batch)
        self.updates += 1
        delayed = self.updates % self.policy_delay(self.training) == 0
        if delayed:
            batch = {**batch, **self.exploration.update_inputs(batch["obs"].shape[1])}
        if self.smoothing:
            batch = {**batch, "smoothing_noise": self.standard_noise(batch["next_obs"].shape[1])}
        if delayed:
            critic_loss, actor_loss = self.run(self.delayed_step, batch)
            return {"critic_loss": critic_loss, "actor_loss": actor_loss}
        return {"critic_loss": self.run(self.critic_step, batch), "actor_loss": None}

    # ------------------------------------------------------------------------------- the losses
    def target_values(self, batch: dict[str, torch.Tensor], target_actor: Callable | None = None,
                      target_critic: Callable | None = None) -> torch.Tensor:
        """y = r + γ (1 − terminal) min_j Q'_j(s', ã), shape (K, B); ã = clip(π'(s') + clip(σ̃ε, −c, c), low, high)
        with smoothing (ε ~ N(0, 1) is ``batch["smoothing_noise"]``), else π'(s')."""
        training = self.training
        next_obs = batch["next_obs"]
        next_action = (target_actor or self.actor_target)(next_obs)
        if self.smoothing:
            clip = training.noise_clip
            noise = (batch["smoothing_noise"] * training.target_noise).clamp(-clip, clip) * self.scale
            next_action = torch.maximum(torch.minimum(next_action + noise, self.offset + self.scale),
                                        self.offset - self.scale)
        target_q = (target_critic or self.critic_target)(next_obs, next_action).min(dim=1).values
        return batch["reward"] + training.gamma * (1.0 - batch["terminal"]) * target_q

    def actor_loss(self, batch: dict[str, torch.Tensor], actor: Callable | None = None,
                   critic: Callable | None = None, method_parameters: list | None = None,
                   record: list | None = None) -> torch.Tensor:
        """Σ_k −mean_b Q_1(s, π(s)) plus the loss terms of the pre-tanh output O of that π(s)
        (:meth:`~ilcsan.rl.methods.actor_methods.ActorMethods.with_loss_terms`) and the exploration method's terms,
        π(s) in a pass as the exploration and normalisation methods ask for it
        (:meth:`~ilcsan.rl.methods.Exploration.loss_pass`, :meth:`~ilcsan.rl.methods.Normalization.loss_pass`;
        ``record`` receives what that pass records); ``method_parameters`` are the exploration method's tensors."""
        exploration = self.exploration
        parameters = method_parameters if method_parameters is not None else module_parameters(exploration.module)
        options = PassOptions(**self.actor_methods.loss_pass([] if record is None else record),
                              **exploration.loss_pass(batch, parameters), preaction=bool(self.actor_methods.loss_terms))
        output = (actor or self.actor)(batch["obs"], options)
        action, preaction = output if options.preaction else (output, None)
        loss = -(critic or self.critic)(batch["obs"], action, first_only=True).mean(dim=-1).sum()
        loss = self.actor_methods.with_loss_terms(loss, preaction)
        extra = exploration.loss_terms(parameters, batch)
        return loss if extra is None else loss + extra

    # ------------------------------------------------------------------------ the two variants
    def _critic_step(self, tensors: dict, batch: dict) -> torch.Tensor:
        with torch.no_grad():
            target_actor = self.update_tensors.stateful(self.actor_target, tensors["actor_target"],
                                                        tensors["actor_target_buffers"])
            target = self.target_values(batch, target_actor,
                                        as_function(self.critic_target, tensors["critic_target"], self.critic_names))
        return self.step_critics(tensors, batch, target)

    def _actor_loss(self, actor: list, method: list, critic: list, buffers: list,
                    batch: dict) -> tuple[torch.Tensor, tuple]:
        """The actor loss of the actor's tensors and what its pass recorded (the aux output)."""
        record: list = []
        loss = self.actor_loss(batch, self.update_tensors.stateful(self.actor, actor, buffers),
                               as_function(self.critic, critic, self.critic_names), method, record)
        return loss, tuple(record)

    def _delayed_step(self, tensors: dict, batch: dict) -> tuple[torch.Tensor, torch.Tensor]:
        critic_loss = self._critic_step(tensors, batch)
        lr = self.actor_config.learning_rate
        (grads, method_grads), (actor_loss, record) = value_and_grads(
            self._actor_loss, tensors["actor"], tensors["exploration"], tensors["critic"], tensors["actor_buffers"],
            batch, wrt=(0, 1), has_aux=True)
        adam_(tensors["actor"], self.actor_methods.gradients(grads), *tensors["actor_adam"], lr=lr)
        if tensors["exploration"]:  # the exploration method's own parameters, at the actor's rate
            adam_(tensors["exploration"], method_grads, *tensors["exploration_adam"], lr=lr)
        self.actor_methods.after_actor_step(tensors["actor_buffers"], record, batch["obs"].shape[1])
        tau = self.training.tau
        if self.target_method.soft_update:
            torch._foreach_lerp_(tensors["actor_target"], tensors["actor"], tau)
            self.actor_methods.follow_buffers(tensors["actor_target_buffers"], tensors["actor_buffers"], tau)
        self.follow_critics(tensors)
        return critic_loss, actor_loss

    def tensors(self) -> dict[str, list]:
        """The shared tensors (:meth:`OffPolicyAlgorithm.tensors`), the target actor's parameters and buffers, and
        the exploration method's parameters and Adam state."""
        tensors = super().tensors()
        adam = self.exploration.adam
        tensors.update(actor_target=self.update_tensors.parameters(self.actor_target),
                       actor_target_buffers=self.update_tensors.buffers(self.actor_target),
                       exploration=adam.views if adam is not None else [])
        if adam is not None:
            tensors["exploration_adam"] = adam.tensors()
        return tensors

    # --------------------------------------------------------------------------- checkpoints
    def networks(self) -> tuple[tuple[str, str, int], ...]:
        return (*super().networks(), ("actor_target", self.target_method.called, 1))

    def seed_state(self, index: int) -> dict[str, Any]:
        """The shared state (:meth:`OffPolicyAlgorithm.seed_state`) and the methods'."""
        state = super().seed_state(index)
        state.update(self.target_method.seed_state(index) or {})
        exploration = self.exploration.seed_state(index)
        if exploration is not None:
            state["exploration"] = exploration
        return state

    def load_seed_states(self, states: Sequence[dict[str, Any]]) -> None:
        super().load_seed_states(states)
        self.target_method.load_seed_states(states)
        if self.exploration.module is not None:
            self.exploration.load_seed_states([state["exploration"] for state in states])


class DDPG(TD3):
    """DDPG as TD3's paper re-implements it ("our DDPG", Fujimoto et al. 2018): one critic, no target policy
    smoothing, the actor and targets updated at every critic update; exploration and target actor as TD3's."""

    critics = 1
    smoothing = False

    @classmethod
    def policy_delay(cls, training: TrainingProtocol) -> int:
        return 1


class GaussianActionNoise(Exploration):
    """TD3's exploration (the paper's): a = clip(π(s) + σ·scale·ε, low, high), ε ~ N(0, I) per seed from the seed's own
    generator, σ = ``training.exploration_noise`` relative to the action half-range ``scale``."""

    def __init__(self, context: MethodContext):
        self.scale, self.offset = context.task.action_scale, context.task.action_offset
        self.sigma, self.action_dim = context.training.exploration_noise, context.task.action_dim

    def explore(self, agent, states: np.ndarray, rngs: Sequence[np.random.Generator]) -> np.ndarray:
        low, high = self.offset - self.scale, self.offset + self.scale
        action = agent.act(states)
        noise = np.stack([rng.standard_normal(self.action_dim) for rng in rngs])
        return np.clip(action + noise * self.sigma * self.scale, low, high)


class PolyakTarget(TargetActor):
    """TD3's target actor (the paper's): π' is a copy of the actor made at the start, moved at every delayed step by
    θ' ← τθ + (1 − τ)θ' (:meth:`TD3._delayed_step`)."""

    soft_update = True

    def __init__(self, context: MethodContext):
        self.module = copy.deepcopy(context.actor)
        self.module.requires_grad_(False)


def module_parameters(module: torch.nn.Module | None) -> list[torch.Tensor]:
    """The parameters of ``module`` (none for None), as the update passes a method's tensors."""
    return list(module.parameters()) if module is not None else []
