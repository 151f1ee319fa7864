"""Training methods as strategies: how the actor explores, which actor gives TD3's target values, and what training
does for the actor's normalisation.

TD3 and DDPG (:mod:`ilcsan.rl.algorithms.td3`) have two places where the methods that followed ILC-SAN change them,
and each is a strategy object with a small set of hooks, chosen by name in the run's TD3 settings:

- **exploration** (``td3.exploration``, :class:`Exploration`): how the actor acts while training (TD3's Gaussian
  action noise; NoisySAN's noise inside the neurons), what the actor's loss adds, and any parameters of its own;
- **target actor** (``td3.target_actor``, :class:`TargetActor`): the actor π' in TD3's target values (the
  Polyak-averaged copy of the actor; Proxy Target's continuous proxy), and what it does before each update.

A third, for every algorithm (SAC too), is chosen by the actor's ``normalization``:

- **normalisation** (``actor.normalization``, :class:`Normalization`): which statistics the actor's loss normalises
  with, how the statistics kept beside the weights move after each actor step and at intervals, and which of them a
  Polyak-averaged target follows (CaRe-BN, :mod:`.care_bn`; ``none`` does nothing).

Each method is one module with one class (its hooks: :mod:`.base`), registered here by name with the paper it comes from
(:func:`register_exploration`, :func:`register_target_actor`, :func:`register_normalization`); registering also makes
the name a valid choice of the setting (a normalisation also needs the actor to implement it,
:mod:`ilcsan.snn.normalization`). Every hook has a do-nothing default in :class:`Method`, so a method writes only what
it changes.
"""

from __future__ import annotations

from ...config import EXPLORATION_PAPERS, NORMALIZATION_PAPERS, TARGET_ACTOR_PAPERS, TD3Config
from ...errors import UserError
from .base import Exploration, Method, MethodContext, Normalization, TargetActor
from .care_bn import CareBN
from .noisysan import NoisySAN
from .proxy_target import ProxyTarget
from .td3_own import GaussianActionNoise, PolyakTarget

__all__ = ["EXPLORATION_METHODS", "NORMALIZATION_METHODS", "TARGET_ACTOR_METHODS", "CareBN", "Exploration",
           "GaussianActionNoise", "Method", "MethodContext", "NoisySAN", "Normalization", "PolyakTarget", "ProxyTarget",
           "TargetActor", "check_methods", "exploration_method", "normalization_method", "register_exploration",
           "register_normalization", "register_target_actor", "relative_cost", "target_actor_method"]

EXPLORATION_METHODS: dict[str, type[Exploration]] = {}
"""The exploration methods by the name ``td3.exploration`` takes."""
TARGET_ACTOR_METHODS: dict[str, type[TargetActor]] = {}
"""The target-actor methods by the name ``td3.target_actor`` takes."""
NORMALIZATION_METHODS: dict[str, type[Normalization]] = {}
"""What training does for each normalisation, by the name ``actor.normalization`` takes."""


def _register(methods: dict, papers: dict[str, str], name: str, method: type, paper: str | None) -> None:
    if paper is None and name not in papers:
        raise ValueError(f"method {name!r} needs the paper it comes from")
    papers[name] = papers[name] if paper is None else paper
    methods[name] = method


def register_exploration(name: str, method: type[Exploration], paper: str | None = None) -> None:
    """Make ``name`` a choice of ``td3.exploration`` (``--exploration``) that runs ``method``; ``paper`` says where it
    comes from (the built-in methods' papers are declared in :data:`ilcsan.config.EXPLORATION_PAPERS`)."""
    _register(EXPLORATION_METHODS, EXPLORATION_PAPERS, name, method, paper)


def register_target_actor(name: str, method: type[TargetActor], paper: str | None = None) -> None:
    """Make ``name`` a choice of ``td3.target_actor`` (``--target-actor``) that runs ``method``, as
    :func:`register_exploration` does."""
    _register(TARGET_ACTOR_METHODS, TARGET_ACTOR_PAPERS, name, method, paper)


def register_normalization(name: str, method: type[Normalization], paper: str | None = None) -> None:
    """Make training run ``method`` for the actor's ``normalization`` ``name``, as :func:`register_exploration` does
    (the built-in normalisations' papers are declared in :data:`ilcsan.config.NORMALIZATION_PAPERS`)."""
    _register(NORMALIZATION_METHODS, NORMALIZATION_PAPERS, name, method, paper)


def exploration_method(name: str) -> type[Exploration]:
    return EXPLORATION_METHODS[name]


def target_actor_method(name: str) -> type[TargetActor]:
    return TARGET_ACTOR_METHODS[name]


def normalization_method(name: str) -> type[Normalization]:
    return NORMALIZATION_METHODS[name]


def check_methods(td3: TD3Config, network: str) -> None:
    """:class:`~ilcsan.errors.UserError` if a method chosen in ``td3`` needs a spiking actor (``spiking_only``) and
    ``network`` is DAN's (deep)."""
    if network == "spiking":
        return
    for flag, name, method in (("--target-actor", td3.target_actor, target_actor_method(td3.target_actor)),
                               ("--exploration", td3.exploration, exploration_method(td3.exploration))):
        if method.spiking_only:
            raise UserError(f"{flag} {name} is a training method for spiking actors ({method.spiking_reason}); DAN "
                            f"trains with TD3's own: drop {flag} for DAN")


def relative_cost(td3: TD3Config) -> float:
    """The time of a training step with the run's methods over a plain step's (their costs multiply)."""
    return exploration_method(td3.exploration).relative_cost(td3) * target_actor_method(td3.target_actor).relative_cost(
        td3)


register_exploration("gaussian", GaussianActionNoise)
register_exploration("noisy", NoisySAN)
register_target_actor("polyak", PolyakTarget)
register_target_actor("proxy", ProxyTarget)
register_normalization("none", Normalization)
register_normalization("care-bn", CareBN)
