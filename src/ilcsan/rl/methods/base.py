"""The hooks of a training method (:class:`Exploration`, :class:`TargetActor`, :class:`Normalization`,
:class:`LossTerm`) with their do-nothing defaults, and what a method is built from (:class:`MethodContext`). What a
method is before it trains — its settings, paper, cost, products and refusals — it declares in :mod:`ilcsan.methods`."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from ...config import ActorConfig, TrainingProtocol
from ..agent_settings import ComputeSettings, TaskSpace


@dataclass(frozen=True)
class MethodContext:
    """What a method may need to build itself: the agent's actor and settings, the task, the seeds and how the agent
    computes."""

    actor: nn.Module
    actor_config: ActorConfig
    training: TrainingProtocol
    task: TaskSpace
    seeds: tuple[int, ...]
    compute: ComputeSettings


class Method:
    """Hooks shared by every kind of method, with their do-nothing defaults.

    ``module``: the method's own trainable parameters or networks (None: none).
    ``seed_state(index)``: seed ``index``'s part of the method's state for a one-seed checkpoint (None: nothing to
    save), and ``load_seed_states(states)`` the inverse for all seeds.
    ``interval``: environment steps between calls of ``at_interval(step, replay, normalizer)`` (0: never), made after
    the step's updates, with the replay buffer and observation normaliser (e.g. to recalibrate statistics). What
    it draws, it draws with generators of its own, so that the run's random streams are untouched.
    """

    module: nn.Module | None = None
    interval = 0

    def seed_state(self, index: int) -> dict[str, Any] | None:
        return None

    def load_seed_states(self, states: Sequence[dict[str, Any] | None]) -> None:
        return None

    def at_interval(self, step: int, replay, normalizer) -> None:
        return None


class Exploration(Method):
    """How the actor explores while training (evaluation and the target actor act without it).

    ``explore(agent, states, rngs)``: the actions (K, M) for normalised states (K, N) after the random phase,
    ``rngs`` the seeds' numpy generators. ``end_episode(index)``: seed ``index``'s episode ended.
    ``before_updates(evaluations)``: called before each chunk of updates with every seed's evaluation rows.
    ``update_inputs(batch_size)``: tensors the actor loss needs, added to the minibatch of each delayed (actor)
    update, drawn outside the update program.
    ``loss_pass(batch, parameters)``: what it asks of the actor's pass that the actor loss evaluates, π(s), as
    fields of :class:`~ilcsan.snn.output.PassOptions` ({}: a plain pass; NoisySAN: the neurons' noise), with
    ``parameters`` the tensors of :attr:`module` (as the update program passes them).
    ``loss_terms(parameters, batch)``: what the actor loss adds to −Q_1(s, π(s)) (None: nothing). The parameters of
    :attr:`module`, if any, take an Adam step (:attr:`adam`) at the actor's learning rate with each actor step.
    """

    adam = None

    def explore(self, agent, states: np.ndarray, rngs: Sequence[np.random.Generator]) -> np.ndarray:
        raise NotImplementedError

    def end_episode(self, index: int) -> None:
        return None

    def before_updates(self, evaluations: Sequence[Sequence[dict[str, float]]]) -> None:
        return None

    def update_inputs(self, batch_size: int) -> dict[str, torch.Tensor]:
        return {}

    def loss_pass(self, batch: dict[str, torch.Tensor], parameters: Sequence[torch.Tensor]) -> dict[str, Any]:
        return {}

    def loss_terms(self, parameters: Sequence[torch.Tensor], batch: dict[str, torch.Tensor]) -> torch.Tensor | None:
        return None


class TargetActor(Method):
    """The actor π' in TD3's target values y = r + γ(1 − d) min_j Q'_j(s', clip(π'(s') + ε)).

    :attr:`module` is π' itself, whose parameters the update reads (and, with ``soft_update``, moves toward the
    actor's, θ' ← τθ + (1 − τ)θ', at each delayed step); :attr:`called` is what errors about its checkpoint call it.
    ``extra_samples(replay, normalizer, rngs, training)``: arrays added to each minibatch, drawn after its transitions
    from the same generators. ``before_update(agent, batch)``: runs before each update, outside the update program.
    """

    soft_update = False
    called = "target actor"

    def extra_samples(self, replay, normalizer, rngs, training: TrainingProtocol) -> dict[str, np.ndarray]:
        return {}

    def before_update(self, agent, batch: dict[str, torch.Tensor]) -> None:
        return None


class Normalization(Method):
    """What training does for the actor's normalisation (``actor.normalization``; every algorithm, TD3, DDPG and SAC,
    runs it). The defaults, the choice ``none``, do nothing.

    The hooks act inside the update program, on the actor's persistent buffers (its state beside the parameters, by
    name: :func:`~ilcsan.rl.algorithms.update_tensors.persistent_buffers`), which every pass of the actor or the
    target actor in an update reads from tensors passed in and which the hooks write in place, as Adam writes its
    state, so that the eager and the compiled update agree:

    ``loss_pass(record)``: what it asks of the actor's pass in the actor's loss, as fields of
    :class:`~ilcsan.snn.output.PassOptions` ({}: a plain pass); ``record`` is a list that pass may append to, handed
    to ``after_actor_step`` (the loss's aux output, detached).
    ``after_actor_step(buffers, record, samples)``: after the actor's Adam step, write ``buffers`` (the online actor's,
    name → tensor) in place from ``record``; ``samples`` is the number of states per seed in the minibatch.
    ``followed_buffers(names)``: of the actor's buffer ``names``, those a Polyak-averaged target actor follows as it
    follows the weights, b' ← τb + (1 − τ)b', at the same moments (TD3: each delayed step; DDPG: each update).
    ``cancelled_parameters(names)``: of the actor's parameter ``names``, those the loss pass's normalisation cancels:
    their gradient is zero but for rounding, which Adam, dividing by its own running scale of it, would turn into
    steps of the learning rate's size; the update sets it to exactly zero, so they stay where they are.
    """

    def __init__(self, context: MethodContext):
        return None

    def loss_pass(self, record: list) -> dict[str, Any]:
        return {}

    def after_actor_step(self, buffers: dict[str, torch.Tensor], record: Sequence, samples: int) -> None:
        return None

    def followed_buffers(self, names: Sequence[str]) -> list[str]:
        return []

    def cancelled_parameters(self, names: Sequence[str]) -> list[str]:
        return []


class LossTerm(Method):
    """A term added to the actor's loss, for every algorithm (TD3, DDPG, SAC), on when its weight setting is above 0.

    ``loss(preaction)``: the term, summed over seeds, of the actor's pre-tanh output (K, B, M) in the pass the loss
    evaluates — O for the deterministic actors of TD3 and DDPG, SAC's mean μ — added after the algorithm's own loss.
    """

    def __init__(self, context: MethodContext):
        return None

    def loss(self, preaction: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError
