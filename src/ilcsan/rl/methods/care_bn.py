"""CaRe-BN's training (Xu et al., ICLR 2026), for TD3, DDPG and SAC; the actor's side (the normalisation, the Kalman
update, the recalibration, the fold) is :mod:`ilcsan.snn.normalization`, its declaration (paper, refusals)
:mod:`ilcsan.methods.care_bn`.

* The actor's loss normalises every layer with its minibatch's own statistics μ_B, σ_B² (pooled over the B states
  and the T steps), and its gradient flows through them (a pass with ``statistics="batch"``).
* After the actor's Adam step, the running statistics move toward that same pass's batch statistics by the
  Kalman-style gain (:func:`~ilcsan.snn.normalization.kalman_update`, B the minibatch's states per seed, as the
  authors' code counts them) — inside the update program, in place on the tensors it is passed.
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
  (:func:`~ilcsan.snn.normalization.recalibrated_statistics`; P_μ, P_σ² kept), as the authors' code does
  every 5 000 steps with 100 batches of 256 (there in one pass per batch, each layer normalised by the statistics
  pooled so far; here exact, one pass per batch and layer, so L times the work). Only the online actor's: its target
  follows them by the Polyak average. The states are drawn by generators of their own, seeded from the run seed and
  the step, so that the run's random streams are untouched. The passes run eagerly, also in a compiled run.
* Everything else — acting, evaluation, the target actor, the critic's target values (SAC's next action), the
  deployed actor — normalises with the running statistics; exports fold them into the weights
  (:meth:`~ilcsan.snn.normalization.LayerNormalizations.export_fold`), so a deployed actor stays additions-only.

It combines with the other methods: NoisySAN's noise enters after the normalisation (its loss pass uses the batch
statistics too); Proxy Target's proxy imitates the actor as it acts (with running statistics) and has no running
statistics to follow.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from ...snn.normalization import (
    RUNNING_BUFFERS,
    CareBatchNorm,
    RunningStatistics,
    kalman_update_,
    recalibrated_statistics,
)
from .base import MethodContext, Normalization

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


class CareBN(Normalization):
    """CaRe-BN as a training method (the module docstring); the interval and the recalibration's size are read from
    the module's constants when the method is built."""

    def __init__(self, context: MethodContext):
        self.actor, self.seeds, self.device = context.actor, context.seeds, context.compute.device
        self.interval = RECALIBRATION_INTERVAL
        self.batches, self.batch_size = RECALIBRATION_BATCHES, RECALIBRATION_BATCH_SIZE
        self.norms = [(name, module.momentum) for name, module in self.actor.named_modules()
                      if isinstance(module, CareBatchNorm)]
        """Each normalised layer's module name (its buffers' prefix) and innovation momentum, in layer order."""

    def loss_pass(self, record: list) -> dict[str, Any]:
        """The batch's own statistics, recorded for :meth:`after_actor_step`."""
        return {"statistics": "batch", "record": record}

    def after_actor_step(self, buffers: dict[str, torch.Tensor], record: Sequence, samples: int) -> None:
        """The Kalman update of every layer's μ̂, σ̂², P_μ, P_σ² toward the loss pass's batch statistics, in place."""
        (statistics,) = record  # the actor's loss runs the actor once
        for (prefix, momentum), batch in zip(self.norms, statistics, strict=True):
            running = RunningStatistics(*(buffers[f"{prefix}.{name}"] for name in RUNNING_BUFFERS))
            kalman_update_(running, batch, samples, momentum)

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
