"""CaRe-BN (Xu et al., ICLR 2026) as declared: batch normalisation of a spiking actor's synaptic currents, trained with
batch statistics and acting with running ones. Training: :mod:`ilcsan.rl.methods.care_bn`; the actor's side:
:mod:`ilcsan.snn.normalization`."""

from __future__ import annotations

from ..errors import UserError
from .declaration import Declared


class CareBNDeclaration(Declared):
    kind, name, title = "normalization", "care-bn", "CaRe-BN"
    paper = ("CaRe-BN (Xu et al., ICLR 2026): batch normalisation of each synaptic layer's current, pooled over the "
             "batch and the T steps; batch statistics in the actor's loss, running statistics (Kalman-style gain, "
             "periodic recalibration) when acting; folded into the weights at export")
    option_help = ("care-bn (CaRe-BN, Xu et al. 2026: batch statistics in the actor's loss, running statistics moved "
                   "by a Kalman-style gain after each actor step and recalibrated from the replay every 5000 steps "
                   "when acting; on the output populations the feed-forward current only; folded into the weights on "
                   "export; spiking actors only)")
    spiking_only = True
    spiking_reason = "it normalises a spiking actor's synaptic currents"
    training = "ilcsan.rl.methods.care_bn:CareBN"
    actor_layer = "ilcsan.snn.normalization:CareBatchNorm"
    step_cost = 1.15
    """A training step's time with CaRe-BN over a plain one (ILC-SAN, Hopper, compiled, one thread): 1.05–1.11 for the
    step itself (``benchmarks/methods.py --methods plain,care-bn``: the batch statistics in the actor's loss and the
    Kalman update), and ≈ 8 % more for its recalibration every 5 000 steps (``benchmarks/recalibration.py``)."""

    @classmethod
    def check(cls, task: str, training) -> None:
        if training.batch_size < 2:
            raise UserError(f"--normalization care-bn estimates its statistics from the minibatch: --batch-size must "
                            f"be at least 2, got {training.batch_size}")
