"""SAC as declared (training: :mod:`ilcsan.rl.algorithms.sac`): its entropy tuning's two settings."""

from __future__ import annotations

from dataclasses import dataclass

from ..settings import setting
from .declaration import Declared


class SACDeclaration(Declared):
    kind, name, title = "algorithm", "sac", "SAC"
    paper = ("SAC (Haarnoja et al. 2018, arXiv 1812.05905): the output populations decode a mean and a log-std of a "
             "tanh-squashed Gaussian, twin critics, automatic entropy tuning; acts deterministically when evaluated")
    option_help = ("sac (squashed Gaussian actor: the output populations decode a mean and a log-std; entropy "
                   "tuned)")
    training = "ilcsan.rl.algorithms.sac:SAC"
    step_cost = 1.4
    """A training step's time with SAC over TD3's (ILC-SAN, Hopper, compiled, one thread; ``benchmarks/methods.py``):
    its actor steps at every update, with twice the output populations and both critics in the actor's loss."""
    own_exploration = "SAC explores with its own stochastic actor and has no target actor"

    @dataclass(frozen=True)
    class Settings:
        entropy_lr: float = setting(3e-4, "SAC: Adam learning rate of the entropy coefficient's logarithm log α "
                                          "(SAC's paper: 3e-4)", bounds="positive")
        initial_entropy_coefficient: float = setting(1.0, "SAC: the entropy coefficient α at the start; it then "
                                                          "tunes itself toward the target entropy −M",
                                                     bounds="positive")
