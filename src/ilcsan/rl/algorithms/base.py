"""What an off-policy algorithm is to the training loop, and what TD3, DDPG and SAC share.

:class:`~ilcsan.rl.training.Trainer` runs any :class:`OffPolicyAlgorithm`: it asks for actions (``act``,
``explore``), hands it minibatches (``update``) and tells it when episodes end and evaluations happen; the algorithm
owns its networks, their Adam states, its random streams and its part of a checkpoint. The shared parts:

- K agents in stacked weights on one device: the actor ensemble, a critic ensemble of C·K Q-networks
  (:class:`~ilcsan.rl.algorithms.critic.Critics`) and its Polyak-averaged target. Losses are summed over seeds, so
  each seed's gradient is exactly its own; Adam is elementwise, so one optimiser over stacked weights is K optimisers.
- An update is a pure function of the agent's tensors (parameters, targets, Adam state), run eagerly or as one
  compiled program (:func:`~ilcsan.compute.programs.as_program`); its random numbers are drawn outside, from the
  seeds' own generators, and passed in with the minibatch.
- The actor's persistent buffers (a normalisation's running statistics) are state the update reads and writes like
  its parameters: every pass of the actor or target actor inside an update takes them from the tensors passed in
  (:meth:`OffPolicyAlgorithm.stateful`), and the actor's normalisation method (:class:`~ilcsan.rl.methods.
  Normalization`, chosen by ``actor.normalization``) writes them in place after the actor's step. The paper's,
  ``none``, has no buffers and does nothing.
- The loss terms (:class:`~ilcsan.rl.methods.LossTerm`, each on when its weight is above 0; none in the paper) add to
  every algorithm's actor loss a term of the pre-tanh output of the pass it evaluates
  (:meth:`OffPolicyAlgorithm.with_loss_terms`).
- The actor reads ``readouts`` values per action dimension from its output populations: 1 for the deterministic
  actors of TD3 and DDPG (a = offset + scale · tanh(O)), 2 for SAC's Gaussian (a mean and a log-std). The
  deterministic action — for evaluation, diagnostics and deployment — is always the first readout squashed, so the
  deployed actor (:meth:`OffPolicyAlgorithm.deployable_actor`) has the same form whatever trained it.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from ... import methods
from ...compute.matmul import DEFAULT_MATMUL, MatmulPath
from ...compute.programs import CompiledPerShape, as_function, prepare_compilation
from ...config import ActorConfig, RunConfig, TrainingProtocol
from ...runs.checkpoint import first_readout, load_state, module_state, slice_state
from ...snn.actor import build_actor
from ..adam import Adam
from ..methods import Method, MethodContext, loss_term_methods, normalization_method
from .critic import Critics

NOISE_SALT = 3
"""Offset of the update's noise generators (TD3's target smoothing, SAC's reparameterisation) from a seed."""


class OffPolicyAlgorithm:
    """K agents of one off-policy algorithm; ``engine`` is the actor's forward pass ('fast' or 'reference');
    ``compile`` runs each update as one compiled program and compiles a spiking actor's acting pass; ``matmul`` is
    where every network's products run. Subclasses define :meth:`explore` and :meth:`update`."""

    critics = 2
    """Q-networks per seed."""
    actor_loss_critics = 1
    """Of them, those the actor's loss evaluates (TD3 and DDPG: Q_1; SAC: both)."""
    readouts = 1
    """Values the actor's output populations decode per action dimension."""

    @classmethod
    def check(cls, config: RunConfig) -> None:
        """Raise :class:`~ilcsan.errors.UserError` for a setting this algorithm cannot train with: the refusals its
        declaration and the run's methods declare (:func:`ilcsan.methods.check_run`)."""
        methods.check_run(config.task, config.algorithm, config.actor, config.td3)

    @classmethod
    def policy_delay(cls, td3: TrainingProtocol) -> int:
        """Critic updates per actor update."""
        return 1

    def __init__(self, actor_config: ActorConfig, td3: TrainingProtocol, state_dim: int, action_dim: int,
                 action_scale: Sequence[float], action_offset: Sequence[float], seeds: Sequence[int],
                 device: str | torch.device = "cpu", compile: bool = False, engine: str = "fast", task: str = "",
                 episode_steps: int | None = None, matmul: MatmulPath = DEFAULT_MATMUL):
        self.config, self.td3, self.seeds = actor_config, td3, list(seeds)
        self.device, self.compiled = torch.device(device), compile
        self.task, self.episode_steps, self.engine, self.matmul = task, episode_steps, engine, matmul
        self.state_dim, self.action_dim = state_dim, action_dim
        self.action_scale, self.action_offset = np.asarray(action_scale), np.asarray(action_offset)
        self.actor = self._build_actor(self.readouts)
        self.critic = Critics(state_dim, action_dim, td3.critic_hidden, self.seeds, self.critics,
                              matmul).to(self.device)
        self.critic_target = copy.deepcopy(self.critic)
        self.critic_target.requires_grad_(False)
        if compile:
            prepare_compilation()
        self.actor_adam = Adam(self.actor, actor_config.learning_rate)
        self.critic_adam = Adam(self.critic, td3.critic_lr)
        # compile: the acting forward pass too (a spiking actor's many small neuron-update ops fuse into a few loops;
        # for DAN the program saves the eager per-op dispatch of a batch-1 action)
        self.actor_fn = CompiledPerShape(self.actor) if compile else self.actor
        self.noise_generators = [torch.Generator(device=self.device).manual_seed(seed * 1_000_003 + NOISE_SALT)
                                 for seed in self.seeds]
        self.scale = torch.as_tensor(self.action_scale, dtype=torch.float32, device=self.device)
        self.offset = torch.as_tensor(self.action_offset, dtype=torch.float32, device=self.device)
        self.updates = 0
        self._critic_target_views: list[torch.Tensor] | None = None
        self._buffer_views: dict[int, list[torch.Tensor]] = {}
        self._state_names: dict[int, list[str]] = {}
        self.normalization = normalization_method(actor_config.normalization)(self.method_context())
        self.loss_terms = [method(self.method_context()) for method in loss_term_methods(td3)]
        self.actor_buffer_names = list(persistent_buffers(self.actor))
        self.followed_buffers = self.normalization.followed_buffers(self.actor_buffer_names)
        """The actor's buffers a Polyak-averaged target actor follows (by name; the target's are named alike)."""
        cancelled = set(self.normalization.cancelled_parameters(self.actor_adam.names))
        self.cancelled_parameters = [index for index, name in enumerate(self.actor_adam.names) if name in cancelled]
        """Positions of the actor's parameters whose gradient the update sets to exactly zero."""

    def _build_actor(self, readouts: int) -> nn.Module:
        """The actor ensemble with ``readouts`` output populations per action dimension; the squashing bounds of
        every readout after the first are (0, 1), unused."""
        padding = readouts - 1
        scale = np.concatenate([self.action_scale, np.ones(padding * self.action_dim)])
        offset = np.concatenate([self.action_offset, np.zeros(padding * self.action_dim)])
        return build_actor(self.config, self.state_dim, readouts * self.action_dim, scale, offset, self.seeds,
                           engine=self.engine, matmul=self.matmul).to(self.device)

    def method_context(self) -> MethodContext:
        """What a training method is built from: this agent's actor, settings, task and seeds."""
        return MethodContext(self.actor, self.config, self.td3, self.task, self.episode_steps, tuple(self.seeds),
                             self.state_dim, self.action_dim, self.action_scale, self.action_offset, self.device,
                             self.compiled, self.matmul)

    def methods(self) -> list[Method]:
        """The training methods this agent runs (every algorithm: the actor's normalisation and the loss terms)."""
        return [self.normalization, *self.loss_terms]

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
        actions = self.actor_fn(torch.as_tensor(normalized_state, device=self.device))
        return actions[..., :self.action_dim].cpu().numpy()

    def explore(self, normalized_state: np.ndarray, rngs: Sequence[np.random.Generator]) -> np.ndarray:
        """The exploring actions (K, N) → (K, M) after the random phase, ``rngs`` the seeds' numpy generators."""
        raise NotImplementedError

    def deployable_actor(self) -> nn.Module:
        """The actor as evaluated and deployed, acting deterministically: the actor itself, or for an actor with
        several readouts per action (SAC) a copy of its first readout's part (the mean's populations, which come
        first in every layer they occupy), made anew at each call."""
        if self.readouts == 1:
            return self.actor
        deployed = self._build_actor(1)
        parts = first_readout(module_state(self.actor), deployed)
        with torch.no_grad():
            for name, tensor in module_state(deployed).items():
                tensor.copy_(parts[name])
        return deployed

    # ---------------------------------------------------------------------- the training loop's
    def end_episode(self, index: int) -> None:
        """Seed ``index``'s training episode ended."""
        return None

    def before_updates(self, evaluations: Sequence[Sequence[dict[str, float]]]) -> None:
        """Called before each chunk of updates with every seed's evaluation rows."""
        return None

    def extra_samples(self, replay, normalizer, rngs) -> dict[str, np.ndarray]:
        """Arrays added to each minibatch, drawn after its transitions from the same generators."""
        return {}

    def after_step(self, step: int, replay, normalizer) -> None:
        """Called after environment step ``step`` and its updates: each method whose ``interval`` divides ``step``
        runs its ``at_interval`` (:class:`~ilcsan.rl.methods.Method`)."""
        for method in self.methods():
            if method.interval and step % method.interval == 0:
                method.at_interval(step, replay, normalizer)

    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor | None]:
        """One update of all K seeds; returns the summed losses as 0-dim tensors (``critic_loss``, ``actor_loss``,
        None on an update without an actor step)."""
        raise NotImplementedError

    def to_batch(self, arrays: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
        return {name: torch.as_tensor(value, device=self.device) for name, value in arrays.items()}

    # ---------------------------------------------------------------------------- the update
    def standard_noise(self, batch_size: int) -> torch.Tensor:
        """N(0, 1) of shape (K, B, M), each seed's from its own generator."""
        shape = (batch_size, self.action_dim)
        return torch.stack([torch.randn(shape, generator=g, device=self.device) for g in self.noise_generators])

    def tensors(self) -> dict[str, list]:
        """The tensors an update reads and writes: parameters and the actor's persistent buffers (detached views,
        whose identity lasts the agent's life) and Adam's state, looked up anew on each call (loading a checkpoint
        replaces the Adam state)."""
        if self._critic_target_views is None:
            self._critic_target_views = [p.detach() for p in self.critic_target.parameters()]
        return {"actor": self.actor_adam.views, "critic": self.critic_adam.views,
                "critic_target": self._critic_target_views, "actor_buffers": self.buffer_views(self.actor),
                "actor_adam": self.actor_adam.tensors(), "critic_adam": self.critic_adam.tensors()}

    def buffer_views(self, module: nn.Module) -> list[torch.Tensor]:
        """Detached views of ``module``'s :func:`persistent_buffers`, made once: what an update reads and writes them
        through (other tensor objects on the same storage, because a compiled program tells its inputs from the
        module's own tensors, which it reads as constants, by identity; a checkpoint loads into them in place)."""
        views = self._buffer_views.get(id(module))
        if views is None:
            views = self._buffer_views[id(module)] = [buffer.detach() for buffer in persistent_buffers(module).values()]
        return views

    def stateful(self, module: nn.Module, parameters: list[torch.Tensor], buffers: list[torch.Tensor]):
        """``module`` as a function of its parameters and persistent buffers passed in (:func:`~ilcsan.compute.
        programs.as_function`): how every pass of an actor inside an update reads its state."""
        names = self._state_names.get(id(module))
        if names is None:
            names = [name for name, _ in module.named_parameters()] + list(persistent_buffers(module))
            self._state_names[id(module)] = names
        return as_function(module, [*parameters, *buffers], names)

    def with_loss_terms(self, loss: torch.Tensor, preaction: torch.Tensor | None) -> torch.Tensor:
        """``loss`` plus each loss term's :meth:`~ilcsan.rl.methods.LossTerm.loss` of ``preaction``, the pre-tanh
        output (K, B, M) of the pass the algorithm's actor loss evaluated (needed only when a term is on)."""
        for term in self.loss_terms:
            loss = loss + term.loss(preaction)
        return loss

    def actor_gradients(self, grads: list[torch.Tensor]) -> list[torch.Tensor]:
        """The actor loss's gradients with those of the :attr:`cancelled_parameters` exactly zero."""
        cancelled = self.cancelled_parameters
        return [torch.zeros_like(grad) if index in cancelled else grad for index, grad in enumerate(grads)]

    def after_actor_step(self, buffers: list[torch.Tensor], record, samples: int) -> None:
        """The normalisation method's writes after an actor step (in the update program), on the actor's buffers
        as passed in, from what the loss pass recorded (its aux output)."""
        self.normalization.after_actor_step(dict(zip(self.actor_buffer_names, buffers, strict=True)), record,
                                            samples)

    def follow_buffers(self, target: list[torch.Tensor], online: list[torch.Tensor], tau: float) -> None:
        """b' ← τb + (1 − τ)b' for the :attr:`followed_buffers` of a Polyak-averaged target actor, in place."""
        if not self.followed_buffers:
            return
        target_by_name = dict(zip(self.actor_buffer_names, target, strict=True))
        online_by_name = dict(zip(self.actor_buffer_names, online, strict=True))
        torch._foreach_lerp_([target_by_name[name] for name in self.followed_buffers],
                             [online_by_name[name] for name in self.followed_buffers], tau)

    def run(self, program, batch: dict[str, torch.Tensor]):
        """``program(tensors, batch)`` in place, outside autograd (the update makes its own gradients)."""
        tensors = self.tensors()
        batch = {name: value.contiguous() for name, value in batch.items()}  # the layout the program was built for
        with torch.no_grad():
            return program(tensors, batch)

    # --------------------------------------------------------------------------- checkpoints
    def networks(self) -> tuple[tuple[str, str, int], ...]:
        """The networks in a checkpoint: (attribute and key, what it is called in errors, rows per seed)."""
        return (("actor", "actor", 1), ("critic", "critic", self.critics),
                ("critic_target", "target critic", self.critics))

    def seed_state(self, index: int) -> dict[str, Any]:
        """Seed ``index``'s networks, Adam states, update count and update-noise generator."""
        state: dict[str, Any] = {key: slice_state(getattr(self, key), index, rows)
                                 for key, _, rows in self.networks()}
        state["actor_optimizer"] = self.actor_adam.seed_state(index, 1)
        state["critic_optimizer"] = self.critic_adam.seed_state(index, self.critics)
        state["updates"] = self.updates
        state["noise_generator"] = self.noise_generators[index].get_state()
        normalization = self.normalization.seed_state(index)
        if normalization is not None:
            state["normalization"] = normalization
        return state

    def load_seed_states(self, states: Sequence[dict[str, Any]]) -> None:
        """Stack the seeds' :meth:`seed_state` dicts into this agent (its seeds in the same order)."""
        for key, what, _ in self.networks():
            load_state(getattr(self, key), [state[key] for state in states], what)
        self.actor_adam.load_seed_states([state["actor_optimizer"] for state in states])
        self.critic_adam.load_seed_states([state["critic_optimizer"] for state in states])
        for generator, state in zip(self.noise_generators, states, strict=True):
            generator.set_state(state["noise_generator"])
        self.updates = states[0]["updates"]
        self.normalization.load_seed_states([state.get("normalization") for state in states])


def persistent_buffers(module: nn.Module) -> dict[str, torch.Tensor]:
    """``module``'s persistent buffers by name: its :func:`~ilcsan.runs.checkpoint.module_state` without the
    parameters (state such as a normalisation's running statistics; none for an actor without normalisation)."""
    parameters = {name for name, _ in module.named_parameters()}
    return {name: tensor for name, tensor in module_state(module).items() if name not in parameters}
