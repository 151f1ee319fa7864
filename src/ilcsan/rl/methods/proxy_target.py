"""Proxy Target (Xu, Bu, Hao, Ding, Yu, NeurIPS 2025, arXiv 2505.24161): a continuous proxy actor in TD3's
target values in place of the soft-updated spiking target actor. Declared (settings, paper, cost, products) in
:mod:`ilcsan.methods.proxy_target`.

The proxy π̃ is a ReLU MLP with tanh output (:data:`~ilcsan.methods.proxy_target.PROXY_HIDDEN`, built as DAN is), one per
seed in stacked weights. Before every TD3 update (every critic update, not only the delayed actor updates, as
in the public code), it takes K = ``proxy_iterations`` Adam steps (lr ``proxy_lr``), each on its own minibatch
of replayed states s_1..s_B:

    L_proxy = Σ_k (1 / (B·M)) Σ_b ‖π̃_k(s_b) − π_k(s_b)‖²        π_k the online spiking actor, held fixed

and is then used *directly* as π' in y = r + γ(1 − d) min_j Q'_j(s', clip(π̃(s') + ε, low, high)), with
TD3's target policy smoothing ε. The proxy has no soft-updated copy of its own, and the spiking actor's
soft-updated copy is not kept. Training only: the deployed actor is the spiking one.

Compiled, the K regression steps run as one program (:class:`~ilcsan.compute.programs.DirectProgram`): the loss
as a pure function of the proxy's parameters (``value_and_grads``), Adam (:func:`~ilcsan.rl.adam.adam_`) in place on
its own state, as the update program does; uncompiled, the same function runs eagerly.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from ...compute.matmul import DEFAULT_MATMUL, MatmulPath
from ...compute.programs import as_function, as_program, module_tensors, value_and_grads
from ...config import TrainingProtocol, actor_config
from ...methods.proxy_target import PROXY_HIDDEN
from ...snn.actor import DeepActor
from ..adam import Adam, adam_
from .base import MethodContext, TargetActor

PROXY_SALT = 4
"""Offset of the proxy's initial weights from a seed (the actor and critic use others)."""


def build_proxy(state_dim: int, action_dim: int, action_scale: Sequence[float], action_offset: Sequence[float],
                seeds: Sequence[int], matmul_path: MatmulPath = DEFAULT_MATMUL) -> DeepActor:
    """K proxy actors (N, 512, ReLU, 512, ReLU, M, tanh·scale + offset), seed k's from its own generator."""
    config = actor_config("dan", hidden=PROXY_HIDDEN)
    return DeepActor(config, state_dim, action_dim, action_scale, action_offset,
                     [seed * 7919 + PROXY_SALT for seed in seeds], matmul_path=matmul_path)


class ProxyTarget(TargetActor):
    """The proxy actor (:attr:`module`, π') and its Adam: before every update ``fit`` imitates the online actor."""

    called = "target actor (Proxy Target: the proxy)"

    def __init__(self, context: MethodContext):
        training = context.training
        task, compute = context.task, context.compute
        proxy = build_proxy(task.state_dim, task.action_dim, task.action_scale, task.action_offset, context.seeds,
                            compute.matmul_path).to(compute.device)
        self.module, self.iterations, self.lr = proxy, training.proxy_iterations, training.proxy_lr
        self.adam = Adam(proxy, training.proxy_lr)
        self.names = self.adam.names
        self.program = as_program(self._regression_steps, module_tensors(proxy), compute.compile)

    def loss(self, states: torch.Tensor, goal: torch.Tensor, parameters: Sequence[torch.Tensor] | None = None
             ) -> torch.Tensor:
        """L_proxy of the module docstring for states (K, B, N) and the online actor's actions ``goal`` (K, B, M):
        the mean squared action error, summed over seeds (so each seed's gradient is its own); with
        ``parameters``, of the proxy with those tensors as its parameters."""
        actor = self.module if parameters is None else as_function(self.module, parameters, self.names)
        return ((actor(states) - goal) ** 2).mean(dim=(-2, -1)).sum()

    def _regression_steps(self, tensors: dict, states: torch.Tensor, goals: torch.Tensor) -> torch.Tensor:
        """The K regression steps as a pure function of the proxy's parameters and Adam state."""
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
            tensors = {"proxy": self.adam.views, "adam": self.adam.tensors()}
            return self.program(tensors, states.contiguous(), goals.contiguous())

    # ------------------------------------------------------------------------------------ hooks
    def extra_samples(self, replay, normalizer, rngs, training: TrainingProtocol) -> dict[str, np.ndarray]:
        """A fresh minibatch of replayed states per regression step: ``proxy_obs`` (iterations, K, B, N)."""
        return {"proxy_obs": np.stack([normalizer.normalize(replay.sample_states(rngs, training.batch_size))
                                       for _ in range(training.proxy_iterations)])}

    def before_update(self, agent, batch: dict[str, torch.Tensor]) -> None:
        self.fit(agent.actor_fn, batch["proxy_obs"])

    def seed_state(self, index: int) -> dict[str, Any]:
        return {"proxy_optimizer": self.adam.seed_state(index, 1)}

    def load_seed_states(self, states) -> None:
        self.adam.load_seed_states([state["proxy_optimizer"] for state in states])
