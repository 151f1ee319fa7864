"""The training methods every algorithm (TD3, DDPG, SAC) runs on its actor, as one object the update calls: the
actor's normalisation (``actor.normalization``, :class:`~ilcsan.rl.methods.Normalization`) and the loss terms
(:class:`~ilcsan.rl.methods.LossTerm`, each on when its weight setting is above 0; none in the paper).

The update reaches the actor's persistent buffers by position (the tensors passed to its program); the methods name
them. This object keeps the names, so that the normalisation's writes after the actor's step, the buffers a
Polyak-averaged target actor follows and the parameters whose gradient is cancelled are found once, when it is built.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

from ..algorithms.update_tensors import persistent_buffers
from . import loss_term_methods, normalization_method
from .base import Method, MethodContext


class ActorMethods:
    """The actor's normalisation and loss terms of one agent, built from ``context``; ``parameter_names`` are the
    actor's parameters in the order the update passes them (its Adam's)."""

    def __init__(self, context: MethodContext, parameter_names: Sequence[str]):
        self.normalization = normalization_method(context.actor_config.normalization)(context)
        self.loss_terms = [method(context) for method in loss_term_methods(context.training)]
        self.buffer_names = list(persistent_buffers(context.actor))
        self.followed_buffers = self.normalization.followed_buffers(self.buffer_names)
        """The actor's buffers a Polyak-averaged target actor follows (by name; the target's are named alike)."""
        cancelled = set(self.normalization.cancelled_parameters(parameter_names))
        self.cancelled_parameters = [index for index, name in enumerate(parameter_names) if name in cancelled]
        """Positions of the actor's parameters whose gradient the update sets to exactly zero."""

    def every(self) -> list[Method]:
        return [self.normalization, *self.loss_terms]

    def loss_pass(self, record: list) -> dict[str, Any]:
        """The normalisation's request of the actor loss's pass (:meth:`~ilcsan.rl.methods.Normalization.loss_pass`)."""
        return self.normalization.loss_pass(record)

    def with_loss_terms(self, loss: torch.Tensor, preaction: torch.Tensor | None) -> torch.Tensor:
        """``loss`` plus each loss term's :meth:`~ilcsan.rl.methods.LossTerm.loss` of ``preaction``, the pre-tanh
        output (K, B, M) of the pass the algorithm's actor loss evaluated (needed only when a term is on)."""
        for term in self.loss_terms:
            loss = loss + term.loss(preaction)
        return loss

    def gradients(self, grads: list[torch.Tensor]) -> list[torch.Tensor]:
        """The actor loss's gradients with those of the :attr:`cancelled_parameters` exactly zero."""
        cancelled = self.cancelled_parameters
        return [torch.zeros_like(grad) if index in cancelled else grad for index, grad in enumerate(grads)]

    def after_actor_step(self, buffers: list[torch.Tensor], record, samples: int) -> None:
        """The normalisation method's writes after an actor step (in the update program), on the actor's buffers
        as passed in, from what the loss pass recorded (its aux output)."""
        self.normalization.after_actor_step(dict(zip(self.buffer_names, buffers, strict=True)), record, samples)

    def follow_buffers(self, target: list[torch.Tensor], online: list[torch.Tensor], tau: float) -> None:
        """b' ← τb + (1 − τ)b' for the :attr:`followed_buffers` of a Polyak-averaged target actor, in place."""
        if not self.followed_buffers:
            return
        target_by_name = dict(zip(self.buffer_names, target, strict=True))
        online_by_name = dict(zip(self.buffer_names, online, strict=True))
        torch._foreach_lerp_([target_by_name[name] for name in self.followed_buffers],
                             [online_by_name[name] for name in self.followed_buffers], tau)
