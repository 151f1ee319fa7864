"""NoisySAN exploration (Chen, Peng, Huang, Tian, arXiv 2403.04162): noise inside the spiking actor, not on its action.
Declared (settings, paper, cost) in :mod:`ilcsan.methods.noisysan`.

While training, the actor acts with additive coloured noise (:mod:`ilcsan.rl.methods.coloured_noise`, spectral
exponent β = ``noisy_beta``) where :class:`~ilcsan.snn.noise.NeuronNoise` says: in the charge and in the spike
transmission of every synaptic layer l of width D_l, with the fixed scale σ_l = σ_init/√D_l, and in the decoder's
drive with a *learned* scale σ_d (one per action dimension, initial σ_init/√M). No Gaussian noise is added to the
action, and the target actor and every evaluation act without noise.

Noise channels: per seed C = 2·ΣD_l + M series (charge and transmission of each neuron, then the decoder),
ordered [charge_1, transmission_1, charge_2, …, decoder]. The i-th action of an episode reads samples iT … iT+T−1
of series drawn when the episode's first noisy action is taken, at least (episode step limit + 1)·T samples long
(the authors' script draws exactly that many; here the next length whose FFT is fast,
:func:`~ilcsan.rl.methods.coloured_noise.fft_length`): the noise is correlated across the T steps of an action and
across the actions of an episode.

The actor update minimises, per seed,

    −Q_1(s, π(s; ε)) + k · (mean_m σ_d,m)²,    k = max(0, R) / R*,

R the seed's latest evaluation return (0 before the first) and R* the task's reference return
(:data:`~ilcsan.methods.noisysan.RETURN_REFERENCE`): as the actor gets good, the penalty pulls the decoder's noise
down. The gradient reaches σ_d through ε. Here ε for each minibatch state is a fresh window of T samples of the
same process — a Gaussian vector with the window covariance of
:func:`~ilcsan.rl.methods.coloured_noise.window_covariance`, so exactly distributed as an exploration window. The
authors' script instead replays the noise each transition was collected with; that costs C·T floats per transition
(5 435 for Hopper: 4.3 GB for a 200 000-step seed), which our replay buffer and checkpoints do not carry.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from ...compute.programs import CompiledPerShape
from ...config import TrainingProtocol
from ...methods.noisysan import return_reference
from ...runs.checkpoint import load_state, slice_state
from ...snn.noise import NeuronNoise
from ...snn.output import PassOptions
from ..adam import Adam
from .base import Exploration, MethodContext
from .coloured_noise import coloured_noise, fft_length, window_covariance

NOISY_SALT = 5
"""Offset of the noise generators from a seed (the actor, critic, smoothing noise and proxy use others)."""
DEFAULT_EPISODE_STEPS = 1000
"""Series length (in actions) for a task without a time limit."""


class NoisyExploration(nn.Module):
    """The noise of K seeds: the learned decoder scales σ_d (K, M), each seed's exploration series, and the draws of
    the update's noise windows."""

    def __init__(self, widths: Sequence[int], action_dim: int, timesteps: int, training: TrainingProtocol,
                 reference_return: float, episode_steps: int | None, seeds: Sequence[int], device: torch.device):
        super().__init__()
        self.widths, self.timesteps = tuple(widths), timesteps
        self.layer_sigmas = tuple(training.noisy_sigma / math.sqrt(width) for width in self.widths)
        self.decoder_sigma = nn.Parameter(torch.full((len(seeds), action_dim),
                                                     training.noisy_sigma / math.sqrt(action_dim), device=device))
        self.beta, self.reference_return = training.noisy_beta, reference_return
        self.channels = 2 * sum(self.widths) + action_dim
        self.series_samples = fft_length(((episode_steps or DEFAULT_EPISODE_STEPS) + 1) * timesteps)
        covariance = window_covariance(self.beta, self.series_samples, timesteps)
        self.window_factor = torch.as_tensor(np.linalg.cholesky(covariance), dtype=torch.float32, device=device)
        self.generators = [torch.Generator().manual_seed(seed * 1_000_003 + NOISY_SALT) for seed in seeds]
        self.update_generators = [torch.Generator(device=device).manual_seed(seed * 1_000_003 + NOISY_SALT + 1)
                                  for seed in seeds]
        self.series: list[torch.Tensor | None] = [None] * len(seeds)  # (samples, C) of the running episode
        self.series_states: list[torch.Tensor | None] = [None] * len(seeds)  # generator state it was drawn from
        self.cursors = [0] * len(seeds)
        self.weights = torch.zeros(len(seeds), device=device)  # k of the penalty, per seed (set_returns)
        self.device = device

    # ----------------------------------------------------------------------------- exploring
    def end_episode(self, index: int) -> None:
        """Seed ``index``'s episode ended: its next noisy action starts a new series."""
        self.series[index], self.series_states[index], self.cursors[index] = None, None, 0

    def acting_noise(self) -> torch.Tensor:
        """The next window of every seed's series as unit noise (K, 1, T, C), the cursor moved on by T."""
        windows = []
        for index in range(len(self.series)):
            if self.series[index] is None or self.cursors[index] + self.timesteps > self.series_samples:
                self._draw_series(index)
            start = self.cursors[index]
            windows.append(self.series[index][start:start + self.timesteps])
            self.cursors[index] = start + self.timesteps
        return torch.stack(windows)[:, None].to(self.device)

    def _draw_series(self, index: int, state: torch.Tensor | None = None) -> None:
        generator = self.generators[index]
        if state is not None:
            generator.set_state(state)
        self.series_states[index] = generator.get_state()
        self.series[index] = coloured_noise(self.beta, (self.channels, self.series_samples), generator).T.contiguous()
        self.cursors[index] = 0

    # ------------------------------------------------------------------------------- learning
    def update_noise(self, batch_size: int) -> torch.Tensor:
        """Unit noise (K, B, T, C) for the actor loss: per state and channel an independent window of T samples,
        N(0, Σ_T) with Σ_T the window covariance of the exploration series (one matmul of N(0, I) draws)."""
        shape = (batch_size, self.channels, self.timesteps)
        white = torch.stack([torch.randn(shape, generator=g, device=self.device) for g in self.update_generators])
        return (white @ self.window_factor.T).transpose(-1, -2)

    def perturbation(self, unit: torch.Tensor, decoder_sigma: torch.Tensor | None = None) -> NeuronNoise:
        """Scale unit noise (K, B, T, C) into the actor's :class:`NeuronNoise` ((K, T, B, D) each);
        ``decoder_sigma`` replaces the parameter σ_d (the compiled update passes its own tensor)."""
        sigma = self.decoder_sigma if decoder_sigma is None else decoder_sigma
        unit = unit.transpose(1, 2)
        charge, transmission, start = [], [], 0
        for width, scale in zip(self.widths, self.layer_sigmas, strict=True):
            charge.append(unit[..., start:start + width] * scale)
            transmission.append(unit[..., start + width:start + 2 * width] * scale)
            start += 2 * width
        return NeuronNoise(tuple(charge), tuple(transmission), unit[..., start:] * sigma[:, None, None, :])

    def set_returns(self, evaluations: Sequence[Sequence[dict[str, float]]]) -> None:
        """The penalty weights k = max(0, R)/R* per seed, R the seed's latest evaluation return (0 before the first)."""
        latest = [rows[-1]["eval_return_mean"] if rows else 0.0 for rows in evaluations]
        self.weights = torch.as_tensor([max(0.0, r) / self.reference_return for r in latest], dtype=torch.float32,
                                       device=self.device)

    @staticmethod
    def penalty(decoder_sigma: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        """Σ_k k_k · (mean_m σ_d,k,m)²: the noise-reduction term of the actor loss."""
        return (weights * decoder_sigma.mean(dim=-1) ** 2).sum()

    # ---------------------------------------------------------------------------- checkpoints
    def stream_state(self, index: int) -> dict[str, Any]:
        """Seed ``index``'s noise streams: the generator states and where its running episode's series is read."""
        return {"generator": self.generators[index].get_state(),
                "update_generator": self.update_generators[index].get_state(),
                "series_state": self.series_states[index], "cursor": self.cursors[index]}

    def load_stream_state(self, index: int, state: dict[str, Any]) -> None:
        """Continue seed ``index``'s streams from :meth:`stream_state` (the series is drawn again from its state)."""
        self.update_generators[index].set_state(state["update_generator"])
        if state["series_state"] is None:
            self.end_episode(index)
        else:
            self._draw_series(index, state["series_state"])
            self.cursors[index] = int(state["cursor"])
        self.generators[index].set_state(state["generator"])


class ExploringActor(nn.Module):
    """The actor with NoisySAN's noise, as one module (so that acting compiles as one program): (state (K, B, N),
    unit noise (K, B, T, C)) → action (K, B, M)."""

    def __init__(self, actor: nn.Module, exploration: NoisyExploration):
        super().__init__()
        self.actor, self.exploration = actor, exploration

    def forward(self, state: torch.Tensor, unit_noise: torch.Tensor) -> torch.Tensor:
        return self.actor(state, PassOptions(noise=self.exploration.perturbation(unit_noise)))


class NoisySAN(Exploration):
    """NoisySAN as a training method: the noise (:class:`NoisyExploration`, this method's :attr:`module`, whose σ_d
    takes an Adam step at the actor's learning rate with every actor step) and the exploring actor, compiled per
    input shape when the run compiles."""

    def __init__(self, context: MethodContext):
        actor = context.actor
        self.module = NoisyExploration(actor.noise_widths(), actor.action_dim, actor.config.timesteps, context.training,
                                       return_reference(context.task.name, context.training),
                                       context.task.episode_steps, context.seeds, context.compute.device)
        self.adam = Adam(self.module, context.actor_config.learning_rate)
        exploring = ExploringActor(actor, self.module)
        self.exploring_fn = CompiledPerShape(exploring) if context.compute.compile else exploring

    @torch.no_grad()
    def explore(self, agent, states: np.ndarray, rngs) -> np.ndarray:
        """The actor with the next window of each seed's noise series in its neurons: (K, N) → (K, M)."""
        state = torch.as_tensor(states[:, None, :], device=self.module.device)
        return self.exploring_fn(state, self.module.acting_noise())[:, 0].cpu().numpy()

    def end_episode(self, index: int) -> None:
        self.module.end_episode(index)

    def before_updates(self, evaluations) -> None:
        self.module.set_returns(evaluations)

    def update_inputs(self, batch_size: int) -> dict[str, torch.Tensor]:
        return {"actor_noise": self.module.update_noise(batch_size), "penalty_weights": self.module.weights}

    def loss_pass(self, batch: dict[str, torch.Tensor], parameters) -> dict[str, Any]:
        return {"noise": self.module.perturbation(batch["actor_noise"], parameters[0])}

    def loss_terms(self, parameters, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.module.penalty(parameters[0], batch["penalty_weights"])

    def seed_state(self, index: int) -> dict[str, Any]:
        return {"module": slice_state(self.module, index, 1), "optimizer": self.adam.seed_state(index, 1),
                "streams": self.module.stream_state(index)}

    def load_seed_states(self, states) -> None:
        """A seed's state as :meth:`seed_state` gives it; its module state (parameters and buffers) may also be under
        ``parameters``, the key of checkpoints written before it was named for what it holds."""
        load_state(self.module, [state.get("module", state.get("parameters")) for state in states],
                   "decoder noise scale")
        self.adam.load_seed_states([state["optimizer"] for state in states])
        for index, state in enumerate(states):
            self.module.load_stream_state(index, state["streams"])
