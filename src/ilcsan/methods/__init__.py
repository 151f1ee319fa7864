"""The training methods and algorithms, each declared once in its own module, and their registry.

A declaration (:class:`~ilcsan.methods.declaration.Declared`) is everything the package knows of a method or an
algorithm before it trains: its name and paper, its settings, its cost and the matrix products it adds. From the
registry come the training settings' fields and choices (:func:`ilcsan.config.training_config_class`), the ``train``
command line, grid rows' keys, a run's identity in reports, ``ilcsan actors``, the estimates of ``reproduce --list``
and the products a run's matmul path is measured on. Its training (the hooks, with torch) is in
:mod:`ilcsan.rl.methods` and :mod:`ilcsan.rl.algorithms`, imported only when a run trains, so that this package, the
configuration and the command line stay torch-free.

Adding a method: a module here with its declaration, named ``<Method>Declaration`` (its hooks, a module beside the
others, are the class named ``<Method>``), and one line below. The first declaration registered of a kind is that
kind's default, the ILC-SAN paper's choice (:data:`DEFAULT_ALGORITHM`, :data:`NO_NORMALIZATION` name two).
"""

from __future__ import annotations

import contextlib
import math
import warnings
from collections.abc import Iterator
from typing import Any

from ..errors import UserError
from . import care_bn, defaults, noisysan, preaction_penalty, proxy_target, sac, td3
from .declaration import KINDS, KINDS_CHOSEN_BY_TRAINING, Declared, MethodProducts
from .defaults import DEFAULT_ALGORITHM, NO_NORMALIZATION

__all__ = ["DEFAULT_ALGORITHM", "KINDS", "KINDS_CHOSEN_BY_TRAINING", "NO_NORMALIZATION", "Declared", "MethodProducts",
           "check_run", "declared", "default", "either", "every", "of_run", "papers", "register", "registered",
           "relative_cost", "selected", "unregister", "unused_settings", "while_registered"]

_REGISTRY: dict[str, dict[str, type[Declared]]] = {kind: {} for kind in KINDS}


def register(method: type[Declared]) -> type[Declared]:
    """Make ``method`` a choice of its kind (its settings join the training settings); returns it."""
    if method.kind not in _REGISTRY:
        raise ValueError(f"{method.__name__}: kind {method.kind!r} is not one of {', '.join(KINDS)}")
    if not getattr(method, "paper", ""):
        raise ValueError(f"method {method.name!r} needs the paper it comes from")
    if method.kind == "loss_term" and method.weight not in {name for name, _, _ in method.setting_fields()}:
        raise ValueError(f"loss term {method.name!r} needs its weight among its settings")
    if method.kind != "loss_term" and not method.option_help:
        raise ValueError(f"method {method.name!r} needs its phrase in the help of {method.flag()}")
    if method.name in _REGISTRY[method.kind]:
        raise ValueError(f"a {method.kind} named {method.name!r} is registered already")
    taken = {name for other in every() for name, _, _ in other.setting_fields()}
    clashes = sorted(taken & {name for name, _, _ in method.setting_fields()})
    if clashes:
        raise ValueError(f"{method.name}: settings {', '.join(clashes)} are another method's")
    _REGISTRY[method.kind][method.name] = method
    return method


def unregister(method: type[Declared]) -> None:
    """Undo :func:`register` (a test's own method)."""
    del _REGISTRY[method.kind][method.name]


@contextlib.contextmanager
def while_registered(method: type[Declared]) -> Iterator[str]:
    """:func:`register` ``method`` for the ``with`` block (a test's, or a notebook's trial), then :func:`unregister`
    it, whatever the block raised; yields its name."""
    register(method)
    try:
        yield method.name
    finally:
        unregister(method)


def registered(kind: str) -> dict[str, type[Declared]]:
    """The declarations of ``kind`` by name, in registration order; the mapping itself, which registering changes
    (a setting's choices)."""
    return _REGISTRY[kind]


def every() -> tuple[type[Declared], ...]:
    """Every declaration, kind by kind in :data:`KINDS` order."""
    return tuple(method for kind in KINDS for method in _REGISTRY[kind].values())


def declared(kind: str, name: str) -> type[Declared]:
    """The declaration of ``name`` among ``kind``'s."""
    return _REGISTRY[kind][name]


def default(kind: str) -> str:
    """The default choice of ``kind``: its first registered."""
    return next(iter(_REGISTRY[kind]))


def papers(kind: str) -> dict[str, str]:
    """Each choice of ``kind`` with its paper."""
    return {name: method.paper for name, method in _REGISTRY[kind].items()}


def either(kind: str) -> str:
    """The choices of ``kind`` as the help of the setting that chooses them: 'a (…), b (…), or c (…)'."""
    phrases = [method.option_help for method in _REGISTRY[kind].values()]
    return phrases[0] if len(phrases) == 1 else f"{', '.join(phrases[:-1])}, or {phrases[-1]}"


def selected(training: Any,
             kinds: tuple[str, ...] = ("loss_term", *KINDS_CHOSEN_BY_TRAINING)) -> list[type[Declared]]:
    """The methods of ``kinds`` that training settings ``training`` choose: the loss terms they weigh above 0, the
    target actor and the exploration."""
    return [method for kind in kinds for method in _REGISTRY[kind].values() if method.active(training)]


def unused_settings(algorithm: str) -> tuple[str, ...]:
    """The training settings a run of ``algorithm`` does not use, which its config.json leaves out: for an algorithm
    with its ``own_exploration`` (SAC), the settings that choose a target actor and an exploration
    (:data:`KINDS_CHOSEN_BY_TRAINING`) and the settings of every declaration of those kinds; none for the others and
    for an algorithm not registered."""
    trainer = _REGISTRY["algorithm"].get(algorithm)
    if trainer is None or not trainer.own_exploration:
        return ()
    unused: list[str] = []
    for kind in KINDS_CHOSEN_BY_TRAINING:
        unused += [kind, *(name for method in _REGISTRY[kind].values() for name, _, _ in method.setting_fields())]
    return tuple(unused)


def of_run(config: Any) -> list[type[Declared]]:
    """Every declaration a run (a :class:`~ilcsan.config.RunConfig`) trains with: its algorithm, its actor's
    normalisation and :func:`selected`."""
    return [_REGISTRY["algorithm"][config.algorithm], _REGISTRY["normalization"][config.actor.normalization],
            *selected(config.training)]


def relative_cost(training: Any) -> float:
    """The time of a training step with the methods ``training`` chooses over a plain step's (their costs multiply)."""
    return math.prod(method.relative_cost(training) for method in selected(training))


def check_run(task: str, algorithm: str, actor: Any, training: Any) -> None:
    """:class:`~ilcsan.errors.UserError` for a run on ``task`` that its declarations cannot train: the algorithm's own
    refusals first (an algorithm with its ``own_exploration``, SAC, refuses TD3's target actors and explorations),
    then a method chosen for a deep actor (DAN) that needs a spiking one (``spiking_only``), then the refusals of the
    actor's normalisation, the loss terms, the target actor and the exploration (:meth:`Declared.check`). ``actor``:
    an :class:`~ilcsan.config.ActorConfig` (its ``network`` and ``normalization``); ``training``: the training
    settings."""
    trainer = declared("algorithm", algorithm)
    for kind in KINDS_CHOSEN_BY_TRAINING if trainer.own_exploration else ():
        method = declared(kind, getattr(training, kind))
        if method.name != default(kind):
            takers = " and ".join(other.title for other in _REGISTRY["algorithm"].values() if not other.own_exploration)
            raise UserError(f"{method.option()} is a method for {takers}; {trainer.own_exploration}: drop "
                            f"{method.flag()}, or use --algorithm {default('algorithm')}")
    trainer.check(task, training)
    chosen = [declared("normalization", actor.normalization), *selected(training)]
    if actor.network != "spiking":
        for method in chosen:
            if method.spiking_only:
                raise UserError(f"{method.option()} is a training method for spiking actors "
                                f"({method.spiking_reason}); DAN trains with TD3's own: drop {method.flag()} for DAN")
    for method in chosen:
        method.check(task, training)


for _method in (td3.TD3Declaration, td3.DDPGDeclaration, sac.SACDeclaration,
                defaults.PolyakTargetDeclaration, proxy_target.ProxyTargetDeclaration,
                defaults.GaussianActionNoiseDeclaration, noisysan.NoisySANDeclaration,
                defaults.NoNormalizationDeclaration, care_bn.CareBNDeclaration,
                preaction_penalty.PreactionPenaltyDeclaration):
    register(_method)


def __getattr__(name: str) -> Any:
    """``TD3_SELECTORS``, the deprecated name of :data:`KINDS_CHOSEN_BY_TRAINING`."""
    if name == "TD3_SELECTORS":
        warnings.warn("ilcsan.methods.TD3_SELECTORS is deprecated: use KINDS_CHOSEN_BY_TRAINING", DeprecationWarning,
                      stacklevel=2)
        return KINDS_CHOSEN_BY_TRAINING
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
