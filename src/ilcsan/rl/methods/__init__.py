"""Training methods as strategies: how the actor explores, which actor gives TD3's target values, what training does
for the actor's normalisation, and what the actor's loss adds.

TD3 and DDPG (:mod:`ilcsan.rl.algorithms.td3`) have two places where the methods that followed ILC-SAN change them,
and each is a strategy object with a small set of hooks, chosen by name in the run's training settings:

- **exploration** (``training.exploration``, :class:`Exploration`): how the actor acts while training, what the actor's
  loss adds, and any parameters of its own;
- **target actor** (``training.target_actor``, :class:`TargetActor`): the actor π' in TD3's target values, and what it
  does before each update.

Two more run under every algorithm (SAC too):

- **normalisation** (``actor.normalization``, :class:`Normalization`): which statistics the actor's loss normalises
  with, how the statistics kept beside the weights move after each actor step and at intervals, and which of them a
  Polyak-averaged target follows (``none`` does nothing);
- **loss terms** (:class:`LossTerm`, each on when its weight setting is above 0): a term of the actor's pre-tanh
  output added to the actor's loss.

Each method is declared (name, paper, settings, cost, products: :mod:`ilcsan.methods`, torch-free) and registered
there with one line; its declaration names the class of its hooks here (:mod:`.base`), one module per method (and
one for the coloured noise series NoisySAN draws, :mod:`.coloured_noise`), but for TD3's own two, the paper's
Gaussian action noise and Polyak-averaged target actor, which are TD3's and live beside it
(:mod:`ilcsan.rl.algorithms.td3`). Every hook has a do-nothing default in :class:`Method`, so a method writes only
what it changes.
"""

from __future__ import annotations

from typing import Any

from ... import methods
from .base import Exploration, LossTerm, Method, MethodContext, Normalization, TargetActor

__all__ = ["Exploration", "LossTerm", "Method", "MethodContext", "Normalization", "TargetActor", "exploration_method",
           "loss_term_methods", "normalization_method", "target_actor_method"]


def exploration_method(name: str) -> type[Exploration]:
    """The hooks of ``training.exploration`` ``name``."""
    return methods.declared("exploration", name).training_class()


def target_actor_method(name: str) -> type[TargetActor]:
    """The hooks of ``training.target_actor`` ``name``."""
    return methods.declared("target_actor", name).training_class()


def normalization_method(name: str) -> type[Normalization]:
    """The hooks of ``actor.normalization`` ``name``."""
    return methods.declared("normalization", name).training_class()


def loss_term_methods(training: Any) -> list[type[LossTerm]]:
    """The hooks of every loss term training settings ``training`` weigh above 0."""
    return [method.training_class() for method in methods.registered("loss_term").values() if method.active(training)]
