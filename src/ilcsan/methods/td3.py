"""TD3 and DDPG as declared (training: :mod:`ilcsan.rl.algorithms.td3`). Their settings are the protocol every
algorithm shares (:class:`ilcsan.config.TrainingProtocol`)."""

from __future__ import annotations

from .declaration import Declared
from .defaults import DEFAULT_ALGORITHM


class TD3Declaration(Declared):
    kind, name, title = "algorithm", DEFAULT_ALGORITHM, "TD3"
    paper = ("TD3 (Fujimoto, van Hoof, Meger, ICML 2018): twin critics, target policy smoothing, delayed actor "
             "updates; how the ILC-SAN paper trains every actor")
    option_help = "td3 (the paper's)"
    training = "ilcsan.rl.algorithms.td3:TD3"


class DDPGDeclaration(Declared):
    kind, name, title = "algorithm", "ddpg", "DDPG"
    paper = ("DDPG (Lillicrap et al., ICLR 2016) as TD3's paper re-implements it: one critic, no target policy "
             "smoothing, the actor and targets updated at every critic update")
    option_help = "ddpg (one critic, no target smoothing or delay)"
    training = "ilcsan.rl.algorithms.td3:DDPG"
    step_cost = 1.2
    """A training step's time with DDPG over TD3's (ILC-SAN, Hopper, compiled, one thread; ``benchmarks/methods.py``):
    one critic, but an actor step at every update instead of every second."""
