"""TD3's update, defined once: pure functions of the agent's tensors, run as they are or compiled whole.

One update of K seeds, in TD3's order (Fujimoto et al. 2018):

* ``critic``: y = r + γ(1 − d) min_j Q'_j(s', clip(π'(s') + clip(σ̃ε, −c, c), low, high)) and one Adam step of the
  twin critics on Σ_j (Q_j(s, a) − y)²;
* ``critic+actor`` (every ``policy_delay``-th update): the same, then one Adam step of the actor on −Q_1(s, π(s))
  with the *updated* critic (plus what the exploration method adds, e.g. NoisySAN's noise and penalty, whose own
  parameters step beside the actor's), then θ' ← τθ + (1 − τ)θ' for the target critic and, when the target actor
  follows the actor (:attr:`~ilcsan.rl.methods.TargetActor.soft_update`), for the target actor.

The networks run through ``torch.func.functional_call`` on tensors passed in (:func:`~ilcsan.compute.programs.
as_function`), the gradients come from :func:`~ilcsan.compute.programs.value_and_grads`, Adam is
:func:`~ilcsan.rl.adam.adam_`. Both variants read and write the agent's own tensors in place — parameters, target
parameters and Adam's state — so checkpoints and resuming see exactly what the update did. With ``compile`` each
variant is one :class:`~ilcsan.compute.programs.DirectProgram` (no Python between operations); without, the very
same functions run eagerly. The program is capture-ready: static shapes, no ``.item()``, no branching on tensor
values; the target-smoothing noise ε is drawn outside, from the agent's per-seed generators, and passed in.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from ..compute.programs import DirectProgram, as_function, module_tensors, value_and_grads
from .adam import adam_


class TD3Update:
    """The two variants of one TD3 update of ``agent`` (see the module docstring), compiled or not.

    ``run(batch, noise, delayed)`` performs one update in place and returns the summed losses as 0-dim tensors
    (critic, actor or None). The losses are also available on their own (:meth:`target_values`,
    :meth:`critic_loss`, :meth:`actor_loss`), with the agent's modules unless functions are passed.
    """

    def __init__(self, agent, compile: bool = True):
        self.agent = agent
        self.actor_names = [name for name, _ in agent.actor.named_parameters()]
        self.critic_names = [name for name, _ in agent.critic.named_parameters()]
        self.target_actor_names = [name for name, _ in agent.actor_target.named_parameters()]
        self.soft_target_actor = agent.target.soft_update
        self._target_views: tuple[list, list] | None = None
        constants = [agent.scale, agent.offset]
        for module in (agent.actor, agent.critic, agent.actor_target, agent.critic_target, agent.exploration.module):
            constants += module_tensors(module) if module is not None else []
        self.critic_step = DirectProgram(self._critic_step, constants) if compile else self._critic_step
        self.delayed_step = DirectProgram(self._delayed_step, constants) if compile else self._delayed_step

    # ------------------------------------------------------------------------------- the losses
    def target_values(self, next_obs: torch.Tensor, standard_noise: torch.Tensor, reward: torch.Tensor,
                      terminal: torch.Tensor, target_actor: Callable | None = None,
                      target_critic: Callable | None = None) -> torch.Tensor:
        """y = r + γ (1 − terminal) min_j Q'_j(s', clip(π'(s') + clip(σ̃ ε, −c, c), low, high)), shape (K, B)."""
        agent, td3 = self.agent, self.agent.td3
        target_actor = target_actor or agent.actor_target
        target_critic = target_critic or agent.critic_target
        noise = (standard_noise * td3.target_noise).clamp(-td3.noise_clip, td3.noise_clip) * agent.scale
        next_action = target_actor(next_obs) + noise
        next_action = torch.maximum(torch.minimum(next_action, agent.offset + agent.scale), agent.offset - agent.scale)
        target_q = target_critic(next_obs, next_action).min(dim=1).values
        return reward + td3.gamma * (1.0 - terminal) * target_q

    def critic_loss(self, batch: dict[str, torch.Tensor], target: torch.Tensor,
                    critic: Callable | None = None) -> torch.Tensor:
        """Σ_k Σ_j mean_b (Q_j(s, a) − y)² for the targets y (K, B)."""
        q_values = (critic or self.agent.critic)(batch["obs"], batch["action"])
        return ((q_values - target.unsqueeze(1)) ** 2).mean(dim=-1).sum()

    def actor_loss(self, batch: dict[str, torch.Tensor], actor: Callable | None = None,
                   critic: Callable | None = None, method_parameters: list | None = None) -> torch.Tensor:
        """Σ_k −mean_b Q_1(s, π(s)) plus the exploration method's terms, π(s) as the method evaluates it
        (:meth:`~ilcsan.rl.methods.Exploration.actor_action`); ``method_parameters`` are the method's tensors.
        With ``td3.preaction_penalty`` λ > 0 it adds Σ_k λ mean_{b,m} O², O the pre-tanh output of that same π(s)."""
        agent = self.agent
        exploration = agent.exploration
        parameters = method_parameters if method_parameters is not None else module_parameters(exploration.module)
        actor = actor or agent.actor
        penalty = agent.td3.preaction_penalty
        preactions: list[torch.Tensor] = []
        if penalty:
            actor = recording_preaction(actor, preactions)
        action = exploration.actor_action(actor, batch, parameters)
        loss = -(critic or agent.critic)(batch["obs"], action, first_only=True).mean(dim=-1).sum()
        if penalty:
            loss = loss + penalty * (preactions[0] ** 2).mean(dim=(-2, -1)).sum()
        extra = exploration.loss_terms(parameters, batch)
        return loss if extra is None else loss + extra

    # ------------------------------------------------------------------------ the two variants
    def _critic_step(self, tensors: dict, batch: dict, noise: torch.Tensor) -> torch.Tensor:
        agent = self.agent
        with torch.no_grad():
            target = self.target_values(
                batch["next_obs"], noise, batch["reward"], batch["terminal"],
                as_function(agent.actor_target, tensors["actor_target"], self.target_actor_names),
                as_function(agent.critic_target, tensors["critic_target"], self.critic_names))
        grads, loss = value_and_grads(self._critic_loss, tensors["critic"], batch, target)
        adam_(tensors["critic"], grads, *tensors["critic_adam"], lr=agent.td3.critic_lr)
        return loss

    def _critic_loss(self, critic: list, batch: dict, target: torch.Tensor) -> torch.Tensor:
        return self.critic_loss(batch, target, as_function(self.agent.critic, critic, self.critic_names))

    def _actor_loss(self, actor: list, method: list, critic: list, batch: dict) -> torch.Tensor:
        agent = self.agent
        return self.actor_loss(batch, as_function(agent.actor, actor, self.actor_names),
                               as_function(agent.critic, critic, self.critic_names), method)

    def _delayed_step(self, tensors: dict, batch: dict, noise: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        critic_loss = self._critic_step(tensors, batch, noise)
        lr = self.agent.config.learning_rate
        (grads, method_grads), actor_loss = value_and_grads(
            self._actor_loss, tensors["actor"], tensors["exploration"], tensors["critic"], batch, wrt=(0, 1))
        adam_(tensors["actor"], grads, *tensors["actor_adam"], lr=lr)
        if tensors["exploration"]:  # the exploration method's own parameters (NoisySAN's σ_d), at the actor's rate
            adam_(tensors["exploration"], method_grads, *tensors["exploration_adam"], lr=lr)
        tau = self.agent.td3.tau
        if self.soft_target_actor:
            torch._foreach_lerp_(tensors["actor_target"], tensors["actor"], tau)
        torch._foreach_lerp_(tensors["critic_target"], tensors["critic"], tau)
        return critic_loss, actor_loss

    # ------------------------------------------------------------------------------ the host side
    def tensors(self) -> dict[str, list]:
        """The agent's tensors the update reads and writes: the networks' parameters (detached views, whose identity
        lasts the agent's life) and Adam's state, looked up anew on each call (loading a checkpoint replaces it)."""
        agent = self.agent
        if self._target_views is None:
            self._target_views = ([p.detach() for p in agent.actor_target.parameters()],
                                  [p.detach() for p in agent.critic_target.parameters()])
        tensors = {"actor": agent.actor_adam.views, "critic": agent.critic_adam.views,
                   "actor_target": self._target_views[0], "critic_target": self._target_views[1],
                   "exploration": agent.exploration.adam.views if agent.exploration.adam is not None else [],
                   "actor_adam": agent.actor_adam.tensors(), "critic_adam": agent.critic_adam.tensors()}
        if agent.exploration.adam is not None:
            tensors["exploration_adam"] = agent.exploration.adam.tensors()
        return tensors

    def run(self, batch: dict[str, torch.Tensor], noise: torch.Tensor,
            delayed: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
        """One update in place; returns (critic loss, actor loss or None) as 0-dim tensors."""
        tensors = self.tensors()
        batch = {name: value.contiguous() for name, value in batch.items()}  # the layout the program was built for
        with torch.no_grad():  # value_and_grads makes its own gradients; nothing outside is recorded
            if delayed:
                critic_loss, actor_loss = self.delayed_step(tensors, batch, noise)
                return critic_loss, actor_loss
            return self.critic_step(tensors, batch, noise), None


def recording_preaction(actor: Callable, preactions: list[torch.Tensor]) -> Callable:
    """``actor`` as a function of states that returns the action and appends its pre-tanh output O to ``preactions``."""
    def acting(states: torch.Tensor, **kwargs) -> torch.Tensor:
        action, preaction = actor(states, with_preaction=True, **kwargs)
        preactions.append(preaction)
        return action
    return acting


def module_parameters(module: torch.nn.Module | None) -> list[torch.Tensor]:
    """The parameters of ``module`` (none for None), as the update passes a method's tensors."""
    return list(module.parameters()) if module is not None else []
