"""The training methods and algorithms, each declared once in its own module, and their registry.

A declaration (:class:`~ilcsan.methods.declaration.Declared`) is everything the package knows of a method or an
algorithm before it trains: its name and paper, its settings, its cost and the matrix products it adds. From the
registry come the training settings' fields and choices (:func:`ilcsan.config.td3_config_class`), the ``train``
command line, grid rows' keys, a run's identity in reports, ``ilcsan actors``, the estimates of ``reproduce --list``
and the products a run's matmul path is measured on. Its training (the hooks, with torch) is in
:mod:`ilcsan.rl.methods` and :mod:`ilcsan.rl.algorithms`, imported only when a run trains, so that this package, the
configuration and the command line stay torch-free.

Adding a method: a module here with its declaration, named ``<Method>Declaration`` (its hooks, a module beside the
others, are the class named ``<Method>``), and one line below. The first declaration registered of a kind is that
kind's default, the ILC-SAN paper's choice (:data:`DEFAULT_ALGORITHM`, :data:`NO_NORMALIZATION` name two).
"""

from __future__ import annotations

import math
from typing import Any

from ..errors import UserError
from . import care_bn, defaults, noisysan, preaction_penalty, proxy_target, sac, td3
from .declaration import KINDS, TD3_SELECTORS, Declared, MethodProducts
from .defaults import DEFAULT_ALGORITHM, NO_NORMALIZATION

__all__ = ["DEFAULT_ALGORITHM", "KINDS", "NO_NORMALIZATION", "TD3_SELECTORS", "Declared", "MethodProducts",
           "check_run", "declared", "default", "either", "every", "of_run", "papers", "register", "registered",
           "relative_cost", "selected", "unregister"]

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


def selected(td3: Any, kinds: tuple[str, ...] = ("loss_term", *TD3_SELECTORS)) -> list[type[Declared]]:
    """The methods of ``kinds`` that training settings ``td3`` choose: the loss terms they weigh above 0, the target
    actor and the exploration."""
    return [method for kind in kinds for method in _REGISTRY[kind].values() if method.active(td3)]


def of_run(config: Any) -> list[type[Declared]]:
    """Every declaration a run (a :class:`~ilcsan.config.RunConfig`) trains with: its algorithm, its actor's
    normalisation and :func:`selected`."""
    return [_REGISTRY["algorithm"][config.algorithm], _REGISTRY["normalization"][config.actor.normalization],
            *selected(config.td3)]


def relative_cost(td3: Any) -> float:
    """The time of a training step with the methods ``td3`` chooses over a plain step's (their costs multiply)."""
    return math.prod(method.relative_cost(td3) for method in selected(td3))


def check_run(task: str, algorithm: str, actor: Any, td3: Any) -> None:
    """:class:`~ilcsan.errors.UserError` for a run on ``task`` that its declarations cannot train: the algorithm's own
    refusals first (an algorithm with its ``own_exploration``, SAC, refuses TD3's target actors and explorations),
    then a method chosen for a deep actor (DAN) that needs a spiking one (``spiking_only``), then the refusals of the
    actor's normalisation, the loss terms, the target actor and the exploration (:meth:`Declared.check`). ``actor``:
    an :class:`~ilcsan.config.ActorConfig` (its ``network`` and ``normalization``); ``td3``: the training settings."""
    trainer = declared("algorithm", algorithm)
    for kind in TD3_SELECTORS if trainer.own_exploration else ():
        method = declared(kind, getattr(td3, kind))
        if method.name != default(kind):
            takers = " and ".join(other.title for other in _REGISTRY["algorithm"].values() if not other.own_exploration)
            raise UserError(f"{method.option()} is a method for {takers}; {trainer.own_exploration}: drop "
                            f"{method.flag()}, or use --algorithm {default('algorithm')}")
    trainer.check(task, td3)
    chosen = [declared("normalization", actor.normalization), *selected(td3)]
    if actor.network != "spiking":
        for method in chosen:
            if method.spiking_only:
                raise UserError(f"{method.option()} is a training method for spiking actors "
                                f"({method.spiking_reason}); DAN trains with TD3's own: drop {method.flag()} for DAN")
    for method in chosen:
        method.check(task, td3)


for _method in (td3.TD3Declaration, td3.DDPGDeclaration, sac.SACDeclaration,
                defaults.PolyakTargetDeclaration, proxy_target.ProxyTargetDeclaration,
                defaults.GaussianActionNoiseDeclaration, noisysan.NoisySANDeclaration,
                defaults.NoNormalizationDeclaration, care_bn.CareBNDeclaration,
                preaction_penalty.PreactionPenaltyDeclaration):
    register(_method)
