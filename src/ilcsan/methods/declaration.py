"""What a training method or an algorithm declares (:class:`Declared`), and the products hook's record
(:class:`MethodProducts`). Torch-free: everything here is read before anything trains."""

from __future__ import annotations

import dataclasses
import importlib
import typing
from dataclasses import dataclass, field
from typing import Any, ClassVar

KINDS: tuple[str, ...] = ("loss_term", "target_actor", "exploration", "normalization", "algorithm")
"""The kinds of declaration, in the order their settings follow the protocol's in the training settings:

- ``loss_term``: a term added to the actor's loss, on when its weight setting is above 0 (any number at once);
- ``target_actor``: the actor π' in TD3's and DDPG's target values, chosen by ``training.target_actor``;
- ``exploration``: how TD3 and DDPG explore, chosen by ``training.exploration``;
- ``normalization``: what training does for the actor's normalisation, chosen by ``actor.normalization``;
- ``algorithm``: the off-policy algorithm, chosen by ``algorithm``."""
KINDS_CHOSEN_BY_TRAINING: tuple[str, ...] = ("target_actor", "exploration")
"""The kinds chosen by a training setting of the same name (the others: by the actor's ``normalization``, the run's
``algorithm``, a loss term's weight)."""


@dataclass(frozen=True)
class NoSettings:
    """The settings of a declaration that has none."""


@dataclass
class MethodProducts:
    """What a run's methods change in the matrix products of an environment step (:meth:`Declared.products` fills it
    in; :func:`~ilcsan.rl.matmul_choice.run_products` counts them), beside what every algorithm computes.

    ``next_actions_by_actor``: times per update a copy of the actor computes the target values' next actions over
    T·B rows (1; a method that gives them from a network of its own sets 0). ``actor_forwards``: further forward passes
    of the actor, each (rows per seed before the T steps, times per environment step). ``networks``: networks of the
    method's own, each (layer widths, rows per seed, times per step of a layer's three products, times of its forward
    product once more)."""

    next_actions_by_actor: float = 1.0
    actor_forwards: list[tuple[int, float]] = field(default_factory=list)
    networks: list[tuple[tuple[int, ...], int, float, float]] = field(default_factory=list)


class Declared:
    """A training method or an algorithm as everything outside its training knows it, declared once in its own
    module and registered with a line in :mod:`ilcsan.methods`:

    ``kind`` (one of :data:`KINDS`) and ``name``, the choice (``--exploration gaussian``; a loss term's name is its
    own); ``title``, how prose and ``reproduce --list`` call it; ``paper``, where it comes from (``ilcsan actors``);
    ``option_help``, its part of the help of the setting that chooses it; ``renamed``, its earlier names, still
    accepted. ``Settings``: a frozen dataclass of its own settings, each declared with
    :func:`~ilcsan.settings.setting` (help, default, bounds, flag), which join the training settings
    (:func:`ilcsan.config.training_config_class`), the ``train`` command line, grid rows and a run's identity in
    reports. ``step_cost``: a training step's time with it over a plain step's, as measured
    (``benchmarks/methods.py``); ``relative_cost(training)`` returns it, or computes the ratio from settings when it
    depends on them; ``cost_note``, the same as a phrase for ``reproduce --list`` (from ``step_cost`` unless given;
    "" when it costs nothing extra).
    ``products(training, state_dim, action_dim, products)``: what it changes in a step's matrix products
    (:class:`MethodProducts`). ``spiking_only`` and ``spiking_reason``: it needs a spiking actor, and why.
    ``check(task, training)``: raise :class:`~ilcsan.errors.UserError` for settings it cannot train with.
    ``training``: its hooks (:mod:`ilcsan.rl.methods`, :mod:`ilcsan.rl.algorithms`), as ``module:Class``, imported
    when a run trains (torch), or the class itself.
    """

    kind: ClassVar[str]
    name: ClassVar[str]
    title: ClassVar[str]
    paper: ClassVar[str]
    option_help: ClassVar[str] = ""
    training: ClassVar[str | type]
    renamed: ClassVar[tuple[str, ...]] = ()
    Settings: ClassVar[type] = NoSettings
    step_cost: ClassVar[float] = 1.0
    cost_note: ClassVar[str] = ""
    spiking_only: ClassVar[bool] = False
    spiking_reason: ClassVar[str] = ""
    weight: ClassVar[str] = ""
    """A loss term's setting that weighs it (on when above 0)."""
    actor_layer: ClassVar[str | type] = ""
    """A normalisation's module of one synaptic layer, ``Class(ensemble, width, v_th)``, as ``module:Class`` (imported
    when an actor is built) or the class itself; "" for a normalisation that adds none."""
    own_exploration: ClassVar[str] = ""
    """An algorithm that explores by its own means and has no target actor: why, in words. It refuses every target
    actor and exploration method but the first registered of each (the paper's, which stands for "none" there)."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "step_cost" in vars(cls) and "cost_note" not in vars(cls) and cls.step_cost != 1.0:
            cls.cost_note = f"{cls.step_cost:g}"

    @classmethod
    def relative_cost(cls, training: Any) -> float:
        return cls.step_cost

    @classmethod
    def products(cls, training: Any, state_dim: int, action_dim: int, products: MethodProducts) -> None:
        return None

    @classmethod
    def check(cls, task: str, training: Any) -> None:
        return None

    @classmethod
    def active(cls, training: Any) -> bool:
        """Whether a run with training settings ``training`` uses it: a loss term when its weight is above 0, a chosen
        kind when chosen (algorithms and normalisations are chosen outside ``training``: see
        :func:`ilcsan.methods.of_run`)."""
        if cls.kind == "loss_term":
            return getattr(training, cls.weight) > 0
        return getattr(training, cls.kind) == cls.name

    @classmethod
    def flag(cls) -> str:
        """The command-line flag that chooses it (a loss term's: its weight's)."""
        return "--" + (cls.weight if cls.kind == "loss_term" else cls.kind).replace("_", "-")

    @classmethod
    def option(cls) -> str:
        """How a user asks for it: ``--exploration gaussian``; a loss term, ``--<its weight> λ``."""
        return f"{cls.flag()} {'λ' if cls.kind == 'loss_term' else cls.name}"

    @classmethod
    def setting_fields(cls) -> list[tuple[str, Any, dataclasses.Field]]:
        """Its settings as (name, type, a new field with the same default and description), to join a dataclass."""
        hints = typing.get_type_hints(cls.Settings)
        return [(item.name, hints[item.name], field(default=item.default, metadata=item.metadata))
                for item in dataclasses.fields(cls.Settings)]

    @classmethod
    def training_class(cls) -> type:
        """The class of its training hooks, imported now when named by path."""
        return _imported(cls.training)

    @classmethod
    def actor_layer_class(cls) -> type | None:
        """The class of a normalisation's :attr:`actor_layer`, imported now when named by path; None if it has none."""
        return _imported(cls.actor_layer) if cls.actor_layer else None


def _imported(spec: str | type) -> type:
    """``spec`` itself, or the class its ``module:Class`` names, imported now."""
    if not isinstance(spec, str):
        return spec
    module, _, name = spec.partition(":")
    return getattr(importlib.import_module(module), name)
