"""Proxy Target (Xu, Bu, Hao, Ding, Yu, NeurIPS 2025, arXiv 2505.24161): a continuous proxy actor in TD3's
target values in place of the soft-updated spiking target actor.

The proxy π̃ is a ReLU MLP with tanh output (:data:`~ilcsan.config.PROXY_HIDDEN`, built as DAN is), one per
seed in stacked weights. Before every TD3 update (every critic update, not only the delayed actor updates, as
in the public code), it takes K = ``proxy_iterations`` Adam steps (lr ``proxy_lr``), each on its own minibatch
of replayed states s_1..s_B:

    L_proxy = Σ_k (1 / (B·M)) Σ_b ‖π̃_k(s_b) − π_k(s_b)‖²        π_k the online spiking actor, held fixed

and is then used *directly* as π' in y = r + γ(1 − d) min_j Q'_j(s', clip(π̃(s') + ε, low, high)), with
TD3's target policy smoothing ε. The proxy has no soft-updated copy of its own, and the spiking actor's
soft-updated copy is not kept. Training only: the deployed actor is the spiking one.

Compiled (``compile=True``), the K regression steps run as one program (:class:`~ilcsan.rl.update_program.
DirectProgram`): the loss as a pure function of the proxy's parameters (``value_and_grads``), Adam in place on the
optimizer's own state, as the update program does.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch

from ..config import PROXY_HIDDEN, TD3Config, actor_config
from ..snn.actor import DeepActor, build_actor
from .update_program import DirectProgram, adam_, adam_state, as_function, module_tensors, value_and_grads

PROXY_SALT = 4
"""Offset of the proxy's initial weights from a seed (the actor and critic use others)."""


def build_proxy(state_dim: int, action_dim: int, action_scale: Sequence[float], action_offset: Sequence[float],
                seeds: Sequence[int]) -> DeepActor:
    """K proxy actors (N, 512, ReLU, 512, ReLU, M, tanh·scale + offset), seed k's from its own generator."""
    config = actor_config("dan", hidden=PROXY_HIDDEN)
    return build_actor(config, state_dim, action_dim, action_scale, action_offset,
                       [seed * 7919 + PROXY_SALT for seed in seeds])


class ProxyTarget:
    """The proxy actor and its optimiser: ``fit`` imitates the online actor, the module serves as π'."""

    def __init__(self, proxy: DeepActor, td3: TD3Config, fused: bool, compile: bool = False):
        self.actor, self.iterations, self.lr = proxy, td3.proxy_iterations, td3.proxy_lr
        self.optimizer = torch.optim.Adam(proxy.parameters(), lr=td3.proxy_lr, fused=fused)
        self.names = [name for name, _ in proxy.named_parameters()]
        self.parameters = list(proxy.parameters())
        self.views = [p.detach() for p in self.parameters]
        self.program = DirectProgram(self._regression_steps, module_tensors(proxy)) if compile else None

    def loss(self, states: torch.Tensor, goal: torch.Tensor, parameters: Sequence[torch.Tensor] | None = None
             ) -> torch.Tensor:
        """L_proxy of the module docstring for states (K, B, N) and the online actor's actions ``goal`` (K, B, M):
        the mean squared action error, summed over seeds (so each seed's gradient is its own); with
        ``parameters``, of the proxy with those tensors as its parameters."""
        actor = self.actor if parameters is None else as_function(self.actor, parameters, self.names)
        return ((actor(states) - goal) ** 2).mean(dim=(-2, -1)).sum()

    def _regression_steps(self, tensors: dict, states: torch.Tensor, goals: torch.Tensor) -> torch.Tensor:
        """The K regression steps as a pure function of the proxy's parameters and Adam state (compiled whole)."""
        total = torch.zeros(())
        for step_states, goal in zip(states, goals, strict=True):
            grads, loss = value_and_grads(self.loss, step_states, goal, tensors["proxy"], wrt=(2,))
            adam_(tensors["proxy"], grads, *tensors["adam"], lr=self.lr)
            total = total + loss
        return total / len(states)

    def fit(self, online_actor: Callable[[torch.Tensor], torch.Tensor], states: torch.Tensor) -> torch.Tensor:
        """K regression steps, step i on ``states[i]`` (shape (K_iterations, K_seeds, B, N)); returns the mean loss.

        The online actor is fixed meanwhile, so its actions for all K minibatches come from one forward pass."""
        iterations, seeds, batch = states.shape[:3]
        with torch.no_grad():
            flat = states.transpose(0, 1).reshape(seeds, iterations * batch, -1)
            goals = online_actor(flat).reshape(seeds, iterations, batch, -1).transpose(0, 1)
            if self.program is not None:
                tensors = {"proxy": self.views, "adam": adam_state(self.optimizer, self.parameters)}
                return self.program(tensors, states.contiguous(), goals.contiguous())
        total = torch.zeros(())
        for step_states, goal in zip(states, goals, strict=True):
            loss = self.loss(step_states, goal)
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.optimizer.step()
            total = total + loss.detach()
        return total / iterations
