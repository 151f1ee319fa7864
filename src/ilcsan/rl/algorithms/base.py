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
  (:class:`~ilcsan.rl.algorithms.update_tensors.UpdateTensors`), and the actor's normalisation method
  (:class:`~ilcsan.rl.methods.Normalization`, chosen by ``actor.normalization``) writes them in place after the
  actor's step. The paper's, ``none``, has no buffers and does nothing.
- The loss terms (:class:`~ilcsan.rl.methods.LossTerm`, each on when its weight is above 0; none in the paper) add to
  every algorithm's actor loss a term of the pre-tanh output of the pass it evaluates
  (:meth:`~ilcsan.rl.methods.actor_methods.ActorMethods.with_loss_terms`).
- The actor reads ``readouts`` values per action dimension from its output populations: 1 for the deterministic
  actors of TD3 and DDPG (a = offset + scale · tanh(O)), 2 for SAC's Gaussian (a mean and a log-std). The
  deterministic action — for evaluation, diagnostics and deployment — is always the first readout squashed, so the
  deployed actor (:meth:`OffPolicyAlgorithm.deployable_actor`) has the same form whatever trained it.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from ... import methods
from ...actors import build_actor
from ...compute.programs import CompiledPerShape, as_function, prepare_compilation, value_and_grads
from ...config import ActorConfig, RunConfig, TrainingProtocol
from ...runs.checkpoint import first_readout, load_state, module_state, slice_state
from ..adam import Adam, adam_
from ..agent_settings import EAGER_ON_CPU, ComputeSettings, TaskSpace
from ..methods import Method, MethodContext
from ..methods.actor_methods import ActorMethods
from .critic import Critics
from .update_tensors import UpdateTensors

NOISE_SALT = 3
"""Offset of the update's noise generators (TD3's target smoothing, SAC's reparameterisation) from a seed."""


class OffPolicyAlgorithm:
    """K agents of one off-policy algorithm (one per seed) for the actor ``actor_config`` describes, trained with the
    settings ``training``, on ``task`` (:class:`~ilcsan.rl.agent_settings.TaskSpace`), computing as ``compute`` says
    (:class:`~ilcsan.rl.agent_settings.ComputeSettings`). Subclasses define :meth:`explore` and :meth:`update`."""

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
        methods.check_run(config.task, config.algorithm, config.actor, config.training)

    @classmethod
    def policy_delay(cls, training: TrainingProtocol) -> int:
        """Critic updates per actor update."""
        return 1

    def __init__(self, actor_config: ActorConfig, training: TrainingProtocol, task: TaskSpace, seeds: Sequence[int],
                 compute: ComputeSettings = EAGER_ON_CPU):
        self.actor_config, self.training, self.task = actor_config, training, task
        self.compute, self.seeds = compute, list(seeds)
        self.device, self.compiled = compute.device, compute.compile
        self.state_dim, self.action_dim = task.state_dim, task.action_dim
        self.action_scale, self.action_offset = task.action_scale, task.action_offset
        self.actor = self._build_actor(self.readouts)
        self.critic = Critics(task.state_dim, task.action_dim, training.critic_hidden, self.seeds, self.critics,
                              compute.matmul_path).to(self.device)
        self.critic_target = copy.deepcopy(self.critic)
        self.critic_target.requires_grad_(False)
        self.critic_names = [name for name, _ in self.critic.named_parameters()]
        if compute.compile:
            prepare_compilation()
        self.actor_adam = Adam(self.actor, actor_config.learning_rate)
        self.critic_adam = Adam(self.critic, training.critic_lr)
        # compile: the acting forward pass too (a spiking actor's many small neuron-update ops fuse into a few loops;
        # for DAN the program saves the eager per-op dispatch of a batch-1 action)
        self.actor_fn = CompiledPerShape(self.actor) if compute.compile else self.actor
        self.noise_generators = [torch.Generator(device=self.device).manual_seed(seed * 1_000_003 + NOISE_SALT)
                                 for seed in self.seeds]
        self.scale = torch.as_tensor(self.action_scale, dtype=torch.float32, device=self.device)
        self.offset = torch.as_tensor(self.action_offset, dtype=torch.float32, device=self.device)
        self.updates = 0
        self.update_tensors = UpdateTensors()
        self.actor_methods = ActorMethods(self.method_context(), self.actor_adam.names)
        """The actor's normalisation and loss terms, as the update calls them."""

    def _build_actor(self, readouts: int) -> nn.Module:
        """The actor ensemble with ``readouts`` output populations per action dimension; the squashing bounds of
        every readout after the first are (0, 1), unused."""
        padding = readouts - 1
        scale = np.concatenate([self.action_scale, np.ones(padding * self.action_dim)])
        offset = np.concatenate([self.action_offset, np.zeros(padding * self.action_dim)])
        return build_actor(self.actor_config, self.state_dim, readouts * self.action_dim, scale, offset, self.seeds,
                           engine=self.compute.engine, matmul_path=self.compute.matmul_path).to(self.device)

    def method_context(self) -> MethodContext:
        """What a training method is built from: this agent's actor, settings, task and seeds."""
        return MethodContext(self.actor, self.actor_config, self.training, self.task, tuple(self.seeds), self.compute)

    def methods(self) -> list[Method]:
        """The training methods this agent runs (every algorithm: the actor's normalisation and the loss terms)."""
        return self.actor_methods.every()

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
        """The tensors an update reads and writes: parameters and the actor's persistent buffers (views,
        :class:`~ilcsan.rl.algorithms.update_tensors.UpdateTensors`) and Adam's state, looked up anew on each call
        (loading a checkpoint replaces the Adam state)."""
        return {"actor": self.actor_adam.views, "critic": self.critic_adam.views,
                "critic_target": self.update_tensors.parameters(self.critic_target),
                "actor_buffers": self.update_tensors.buffers(self.actor),
                "actor_adam": self.actor_adam.tensors(), "critic_adam": self.critic_adam.tensors()}

    def critic_loss(self, batch: dict[str, torch.Tensor], target: torch.Tensor,
                    critic: Callable | None = None) -> torch.Tensor:
        """Σ_k Σ_j mean_b (Q_j(s, a) − y)² for the targets y (K, B): every algorithm's critic loss."""
        q_values = (critic or self.critic)(batch["obs"], batch["action"])
        return ((q_values - target.unsqueeze(1)) ** 2).mean(dim=-1).sum()

    def step_critics(self, tensors: dict, batch: dict, target: torch.Tensor) -> torch.Tensor:
        """One Adam step of the critics' tensors (at ``critic_lr``) on :meth:`critic_loss` toward the targets y, in
        place; returns the loss."""
        grads, loss = value_and_grads(self._critic_loss, tensors["critic"], batch, target)
        adam_(tensors["critic"], grads, *tensors["critic_adam"], lr=self.training.critic_lr)
        return loss

    def _critic_loss(self, critic: list, batch: dict, target: torch.Tensor) -> torch.Tensor:
        return self.critic_loss(batch, target, as_function(self.critic, critic, self.critic_names))

    def follow_critics(self, tensors: dict) -> None:
        """θ' ← τθ + (1 − τ)θ' for the target critics, in place."""
        torch._foreach_lerp_(tensors["critic_target"], tensors["critic"], self.training.tau)

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
        normalization = self.actor_methods.normalization.seed_state(index)
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
        self.actor_methods.normalization.load_seed_states([state.get("normalization") for state in states])
