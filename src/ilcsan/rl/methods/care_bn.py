"""CaRe-BN's training (Xu et al., ICLR 2026), for TD3, DDPG and SAC: how the running statistics are estimated (the
Kalman update, the recalibration) and when. The actor's side (the normalising layer, its buffers, the fold) is
:mod:`ilcsan.snn.normalization`, the declaration (paper, refusals) :mod:`ilcsan.methods.care_bn`.

* The actor's loss normalises every layer with its minibatch's own statistics μ_B, σ_B² (pooled over the B states
  and the T steps), and its gradient flows through them (a pass with ``statistics="batch"``).
* After the actor's Adam step, the running statistics move toward that same pass's batch statistics by the
  Kalman-style gain (:func:`kalman_update`, B the minibatch's states per seed, as the authors' code counts them) —
  inside the update program, in place on the tensors it is passed.
* A normalised layer's bias b is cancelled by the batch mean (X − μ_B does not depend on it; β takes its place), so
  its gradient is zero but for rounding; the update makes it exactly zero (:meth:`CareBN.cancelled_parameters`) and
  b stays at its initial value. (The authors' code leaves the rounding to Adam, which divides it by its own running
  scale of it: b then drifts by up to the learning rate per actor step, a random walk that the running mean
  follows, and that made eager and compiled updates part after a few steps.)
* A Polyak-averaged target actor follows the online actor's running μ̂, σ̂² as it follows its weights,
  b' ← τb + (1 − τ)b', at the same moments (TD3: each delayed step; DDPG: each update), as in the authors' code (whose
  running statistics are parameters without gradient, so its Polyak loop over the parameters carries them). Its
  P_μ, P_σ² are never read and stay as they started.
* Every :data:`RECALIBRATION_INTERVAL` environment steps, after that step's updates, the running statistics are
  replaced by the exact ones of :data:`RECALIBRATION_BATCHES` replayed minibatches of
  :data:`RECALIBRATION_BATCH_SIZE` states, normalised by the observation normaliser, layer by layer
  (:func:`recalibrated_statistics`; P_μ, P_σ² kept), as the authors' code does every 5 000 steps with 100 batches
  of 256 (there in one pass per batch, each layer normalised by the statistics pooled so far; here exact, one pass
  per batch and layer, so L times the work). Only the online actor's: its target follows them by the Polyak
  average. The states are drawn by generators of their own, seeded from the run seed and the step, so that the
  run's random streams are untouched. The passes run eagerly, also in a compiled run.
* Everything else — acting, evaluation, the target actor, the critic's target values (SAC's next action), the
  deployed actor — normalises with the running statistics; exports fold them into the weights
  (:meth:`~ilcsan.snn.normalization.LayerNormalizations.export_fold`), so a deployed actor stays additions-only.

The functions here are pure (new tensors out) but :func:`kalman_update_`, which writes :func:`kalman_update`'s result
into the tensors it is given (a layer's buffers, or the training update's views of them).

It combines with the other methods: NoisySAN's noise enters after the normalisation (its loss pass uses the batch
statistics too); Proxy Target's proxy imitates the actor as it acts (with running statistics) and has no running
statistics to follow.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from ...errors import UserError
from ...snn.actor import SpikingActor
from ...snn.normalization import (
    RUNNING_BUFFERS,
    CareBatchNorm,
    NormStatistics,
    RunningStatistics,
    batch_statistics,
)
from .base import MethodContext, Normalization

INNOVATION_MOMENTUM = 0.8
"""m in P ← m P + (1 − m) δ², the exponential average of the innovation's square (the authors' value)."""
RECALIBRATION_INTERVAL = 5_000
"""Environment steps between recalibrations (the authors' ``recalibration_freq``)."""
RECALIBRATION_BATCHES = 100
"""Replayed minibatches a recalibration pools (the authors' ``recalibration_batchs``)."""
RECALIBRATION_BATCH_SIZE = 256
"""States per seed in each of them (the authors' batch size)."""
RECALIBRATION_SALT = 8
"""First entropy word of the recalibration's generators, [salt, seed, step] (the diagnostics' states use 7)."""
FOLLOWED = ("running_mean", "running_var")
"""The buffers a Polyak-averaged target actor follows: those a forward pass reads."""


def kalman_update(running: RunningStatistics, batch: NormStatistics, samples: int,
                  momentum: float = INNOVATION_MOMENTUM) -> RunningStatistics:
    """One Kalman-style step of the running statistics toward a batch's (pure: returns new tensors).

    For the mean (the variance alike, with σ_B² and σ̂² in place of μ_B and μ̂):

      innovation         δ = μ_B − μ̂
      its variance       P ← m P + (1 − m) δ²            (m = ``momentum``, 0.8)
      observation noise  R = σ_B² / (B − 1)              (for the variance: R = 2 (σ_B²)² / (B − 1))
      gain               K = P / (P + R)                 (0 where P + R = 0: then δ = 0, nothing to move)
      update             μ̂ ← μ̂ + K δ

    P is updated with this batch's innovation before the gain is formed, as in the authors' code. B = ``samples`` is
    the number of states in the batch: the authors' code divides by 255 for its batches of 256 states; the T steps of
    one state are not counted as independent samples. The batch statistics are detached: the running statistics are
    not trained.
    """
    if samples < 2:
        raise UserError(f"CaRe-BN's running statistics need batches of at least 2 states, got {samples}")
    batch_mean, batch_var = batch.mean.detach(), batch.var.detach()
    mean, mean_innovation = _kalman_step(running.mean, running.mean_innovation, batch_mean,
                                         batch_var / (samples - 1), momentum)
    var, var_innovation = _kalman_step(running.var, running.var_innovation, batch_var,
                                       2.0 * batch_var.square() / (samples - 1), momentum)
    return RunningStatistics(mean, var, mean_innovation, var_innovation)


def kalman_update_(running: RunningStatistics, batch: NormStatistics, samples: int,
                   momentum: float = INNOVATION_MOMENTUM) -> None:
    """:func:`kalman_update` written into the tensors of ``running``, in place."""
    for tensor, value in zip(running, kalman_update(running, batch, samples, momentum), strict=True):
        tensor.copy_(value)


def _kalman_step(estimate: torch.Tensor, innovation_var: torch.Tensor, observation: torch.Tensor,
                 noise: torch.Tensor, momentum: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(estimate + K δ, P) for δ = observation − estimate, P = m P + (1 − m) δ², K = P / (P + noise)."""
    innovation = observation - estimate
    innovation_var = momentum * innovation_var + (1.0 - momentum) * innovation.square()
    total = innovation_var + noise
    gain = torch.where(total > 0, innovation_var / total, torch.zeros_like(total))
    return estimate + gain * innovation, innovation_var


def pool_statistics(parts: Sequence[NormStatistics], counts: Sequence[int] | None = None) -> NormStatistics:
    """The exact μ and biased σ² of the union of several batches from each batch's statistics and size n_i
    (``counts``; equal sizes when None): μ = Σ n_i μ_i / N, σ² = Σ n_i (σ_i² + (μ_i − μ)²) / N, N = Σ n_i."""
    if not parts:
        raise ValueError("pooling needs at least one batch's statistics")
    means = torch.stack([part.mean for part in parts])
    variances = torch.stack([part.var for part in parts])
    weights = torch.as_tensor([1.0] * len(parts) if counts is None else [float(n) for n in counts],
                              dtype=means.dtype, device=means.device)
    weights = (weights / weights.sum()).reshape(-1, *([1] * (means.dim() - 1)))
    mean = (weights * means).sum(dim=0)
    return NormStatistics(mean, (weights * (variances + (means - mean).square())).sum(dim=0))


@torch.no_grad()
def recalibrated_statistics(actor: SpikingActor, batches: Sequence[torch.Tensor]) -> tuple[NormStatistics, ...]:
    """The exact statistics of each layer's currents in a normalising spiking ``actor`` pooled over all ``batches``
    of normalised states (K, B_i, N), layer by layer: layer l's currents over every batch are computed with layers
    1..l−1 normalised by their recalibrated statistics, so it takes one pass over the batches per layer, and the pass
    for layer l stops at layer l's currents (the later layers, the intra-layer loop and the decoder do not run:
    1 + 2 + … + L layer products instead of L²). The hidden layers' spikes are the fast engine's, equal to the
    reference engine's. The actor is unchanged
    (:meth:`~ilcsan.snn.normalization.LayerNormalizations.set_running_` installs the result)."""
    if actor.norms is None:
        raise UserError("this actor does not normalise its currents (--normalization none)")
    found: list[NormStatistics] = []
    for index in range(len(actor.layers)):
        parts = []
        for batch in batches:
            encoded = actor.encoder(batch)
            values, constant = encoded.values, encoded.constant
            for before in range(index):
                currents, _ = actor.layer_currents(before, values, constant, tuple(found))
                values, constant = actor.layer_spikes(currents, output_layer=False), False
            parts.append(batch_statistics(actor.layers[index](values)))
        found.append(pool_statistics(parts, [batch.shape[1] for batch in batches]))
    return tuple(found)


class CareBN(Normalization):
    """CaRe-BN as a training method (the module docstring); the interval and the recalibration's size are read from
    the module's constants when the method is built."""

    def __init__(self, context: MethodContext):
        self.actor, self.seeds, self.device = context.actor, context.seeds, context.compute.device
        self.interval = RECALIBRATION_INTERVAL
        self.batches, self.batch_size = RECALIBRATION_BATCHES, RECALIBRATION_BATCH_SIZE
        self.norms = [name for name, module in self.actor.named_modules() if isinstance(module, CareBatchNorm)]
        """Each normalised layer's module name (its buffers' prefix), in layer order."""

    def loss_pass(self, record: list) -> dict[str, Any]:
        """The batch's own statistics, recorded for :meth:`after_actor_step`."""
        return {"statistics": "batch", "record": record}

    def after_actor_step(self, buffers: dict[str, torch.Tensor], record: Sequence, samples: int) -> None:
        """The Kalman update of every layer's μ̂, σ̂², P_μ, P_σ² toward the loss pass's batch statistics, in place."""
        (statistics,) = record  # the actor's loss runs the actor once
        for prefix, batch in zip(self.norms, statistics, strict=True):
            running = RunningStatistics(*(buffers[f"{prefix}.{name}"] for name in RUNNING_BUFFERS))
            kalman_update_(running, batch, samples)

    def followed_buffers(self, names: Sequence[str]) -> list[str]:
        return [name for name in names if name.rsplit(".", 1)[-1] in FOLLOWED]

    def cancelled_parameters(self, names: Sequence[str]) -> list[str]:
        """The bias of every normalised layer (``layers.<l>.bias`` beside ``norms.<l>``)."""
        biases = {f"layers.{index}.bias" for index in range(len(self.norms))}
        return [name for name in names if name in biases]

    @torch.no_grad()
    def at_interval(self, step: int, replay, normalizer) -> None:
        """Recalibrate the online actor's running statistics on replayed states (the module docstring)."""
        generators = [np.random.default_rng([RECALIBRATION_SALT, seed, step]) for seed in self.seeds]
        batches = [torch.as_tensor(normalizer.normalize(replay.sample_states(generators, self.batch_size)),
                                   device=self.device) for _ in range(self.batches)]
        self.actor.norms.set_running_(recalibrated_statistics(self.actor, batches))
