"""A user's grid of runs from a TOML file: read, and every key and value checked, into a :class:`TableSpec`.

A grid file has the shape of the paper's tables as grids (:mod:`ilcsan.paper.layouts`): tasks × rows × seeds
with the evaluation protocol, each row an actor preset plus overrides of the actor's switches (the fields of
:class:`~ilcsan.config.ActorConfig`) and, optionally, its TD3 training method. :func:`load_grid` documents the format.
"""

from __future__ import annotations

import dataclasses
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .. import methods
from ..config import (
    OLD_TRAINING_KEY,
    ActorConfig,
    actor_config,
    check_settings,
    described_fields,
    method_settings,
    setting_type,
    training_config_class,
)
from ..errors import UserError
from ..paper.layouts import EVAL_EPISODES, EVAL_EVERY, SEEDS, STEPS, TABLES, RowSpec, TableSpec
from ..paper.published import PAPER_TASK_NAMES


def _actor_switches() -> dict[str, tuple[str, type]]:
    """Every switch a row's ``overrides`` may set → (the :class:`~ilcsan.config.ActorConfig` field it sets, the type
    of its value): the actor's settings but the preset (a row's own key), a setting offered as switches replaced by
    them (``hidden`` by ``hidden_layers`` and ``hidden_width``), as on the command line."""
    switches: dict[str, tuple[str, type]] = {}
    for item in described_fields(ActorConfig):
        for part in item.metadata["switches"]:
            switches[part.flag.replace("-", "_")] = item.name, type(part.default_of(item.default))
        if not item.metadata["switches"] and item.name != "preset":
            switches[item.name] = item.name, setting_type(ActorConfig, item)
    return switches


_SWITCHES = _actor_switches()
OVERRIDE_KEYS: tuple[str, ...] = tuple(_SWITCHES)
"""The keys of a row's ``overrides``: the actor's switches, each checked by building the actor."""
DEEP_ACTOR_SETTINGS: tuple[str, ...] = ("network", "hidden", "learning_rate")
"""The actor settings the deep actor (DAN, :class:`~ilcsan.snn.actor.DeepActor`) reads; the others are spiking ones."""
DAN_OVERRIDE_KEYS: tuple[str, ...] = tuple(key for key, (name, _) in _SWITCHES.items() if name in DEEP_ACTOR_SETTINGS)
"""The only switches that mean something for the deep actor."""
_TYPE_WORDS = {int: "an integer", float: "a number", str: "a string"}

_SLUG = re.compile(r"^[a-z0-9][a-z0-9._+-]*$")
_GYM_ID = re.compile(r"^(?:[A-Za-z0-9_.-]+[:/])?[A-Za-z][A-Za-z0-9_.-]*-v\d+$")

_TOP_KEYS = tuple(item.name for item in dataclasses.fields(TableSpec))  # name, caption, tasks, rows, protocol
_ROW_KEYS = ("slug", "label", "preset", "overrides", "algorithm", "training")


def is_task_name(task: str) -> bool:
    """True for one of the paper's short names or anything shaped like a Gymnasium id (``Name-vN``)."""
    return task in PAPER_TASK_NAMES or bool(_GYM_ID.match(task))


def load_grid(path: str | Path) -> TableSpec:
    """Read a user's grid of runs from a TOML file and validate every key and value.

    The format mirrors :class:`TableSpec`: top-level ``name`` (a slug), ``tasks`` (short names such
    as ``Hopper`` or Gymnasium ids such as ``Pendulum-v1``) and at least one ``[[rows]]`` are
    required; ``caption``, ``seeds`` (10), ``steps`` (1 000 000), ``eval_every`` (10 000) and
    ``eval_episodes`` (10) are optional. Each row has a unique ``slug``, a ``preset``, an optional
    ``label`` (defaults to the slug), optional ``overrides`` of the actor switches, an optional ``algorithm``
    (``td3``, the default, ``ddpg`` or ``sac``: any registered one) and an optional ``training`` table of the settings
    that choose or tune a training method (``target_actor = "proxy"``, ``preaction_penalty = 0.1``, ...; grids written
    before that name call it ``td3``, read still)::

        name = "intra-small"
        caption = "Intra-layer ablation on two tasks, 3 seeds"
        tasks = ["Hopper", "Walker2d", "Pendulum-v1"]
        seeds = 3
        steps = 300_000

        [[rows]]
        slug = "ilc-san"
        label = "ILC-SAN"
        preset = "ilc-san"

        [[rows]]
        slug = "no-intra-mean"
        label = "No I_intra, D_mean"
        preset = "ilc-san"
        overrides = { intra = "none", decoder = "mean", alpha_v_li = 0.75 }

        [[rows]]
        slug = "ilc-san-sac"
        preset = "ilc-san"
        algorithm = "sac"

    The names of the paper's tables (``perf``, ``decode``, ...) are reserved: the report puts the
    paper's numbers beside a grid of that name. Raises :class:`~ilcsan.errors.UserError` (a
    ``ValueError``) with one sentence on any bad key or value.
    """
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as error:
        raise UserError(f"grid file {path} is not valid TOML: {error}") from None
    except UnicodeDecodeError:
        raise UserError(f"grid file {path} is not UTF-8 text; a grid is a TOML file") from None
    except RecursionError:
        raise UserError(f"grid file {path} nests arrays or tables too deeply to be a grid") from None
    except (OSError, ValueError) as error:  # missing, a folder, unreadable; ValueError: a NUL in the path
        raise UserError(f"grid file {path} cannot be read: {getattr(error, 'strerror', None) or error}") from None
    return grid_from_dict(data, source=str(path))


def grid_from_dict(data: Mapping[str, Any], source: str = "grid") -> TableSpec:
    """Validate a grid given as a mapping (the parsed TOML of :func:`load_grid`)."""
    _check_keys(data, _TOP_KEYS, f"{source}")
    for key in ("name", "tasks", "rows"):
        if key not in data:
            raise UserError(f"{source}: the key {key!r} is required")
    name = _slug(data["name"], f"{source}: name")
    if name in TABLES:
        raise UserError(f"{source}: the name {name!r} is reserved for the paper's table; choose another")
    caption = data.get("caption", name)
    if not isinstance(caption, str):
        raise UserError(f"{source}: caption must be a string, got {caption!r}")
    tasks, rows = _tasks(data["tasks"], source), _rows(data["rows"], source)
    for index, row in enumerate(rows):
        actor, training = actor_config(row.preset, **row.overrides), training_config_class()(**row.training)
        for task in tasks:
            try:
                methods.check_run(task, row.algorithm, actor, training)
            except UserError as error:
                raise UserError(f"{source}: rows[{index}] on {task}: {error}") from None
    return TableSpec(
        name=name,
        caption=caption,
        tasks=tasks,
        rows=rows,
        seeds=_positive_int(data, "seeds", SEEDS, source),
        steps=_positive_int(data, "steps", STEPS, source),
        eval_every=_positive_int(data, "eval_every", EVAL_EVERY, source),
        eval_episodes=_positive_int(data, "eval_episodes", EVAL_EPISODES, source),
    )


def _check_keys(data: Any, allowed: tuple[str, ...], where: str) -> None:
    if not isinstance(data, Mapping):
        raise UserError(f"{where} must be a table of keys, got {data!r}")
    unknown = sorted(set(data) - set(allowed))
    if unknown:
        raise UserError(f"{where}: unknown key {unknown[0]!r}; allowed keys are {', '.join(allowed)}")


def _slug(value: Any, where: str) -> str:
    if not isinstance(value, str) or not _SLUG.match(value):
        raise UserError(f"{where} must be a lowercase slug (letters, digits, '.', '_', '+', '-'), "
                        f"got {value!r}")
    return value


def _positive_int(data: Mapping[str, Any], key: str, default: int, source: str) -> int:
    value = data.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise UserError(f"{source}: {key} must be a positive integer, got {value!r}")
    return value


def _tasks(value: Any, source: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not value:
        raise UserError(f"{source}: tasks must be a non-empty list of task names, got {value!r}")
    for task in value:
        if not isinstance(task, str) or not is_task_name(task):
            raise UserError(f"{source}: unknown task {task!r}; use one of {', '.join(PAPER_TASK_NAMES)} "
                            "or a Gymnasium id such as 'Pendulum-v1'")
    if len(set(value)) != len(value):
        raise UserError(f"{source}: tasks are listed twice: {value!r}")
    return tuple(value)


def _rows(value: Any, source: str) -> tuple[RowSpec, ...]:
    if not isinstance(value, list) or not value:
        raise UserError(f"{source}: rows must be a non-empty array of tables ([[rows]]), got {value!r}")
    rows = tuple(_row_from_dict(item, f"{source}: rows[{index}]") for index, item in enumerate(value))
    slugs = [row.slug for row in rows]
    duplicate = next((slug for slug in slugs if slugs.count(slug) > 1), None)
    if duplicate is not None:
        raise UserError(f"{source}: the row slug {duplicate!r} is used twice; slugs must be unique")
    return rows


def _row_from_dict(item: Any, where: str) -> RowSpec:
    if isinstance(item, Mapping) and OLD_TRAINING_KEY in item:  # a row written before the name ``training``
        if "training" in item:
            raise UserError(f"{where}: give the training table once, as training (td3 is its old name)")
        item = {("training" if key == OLD_TRAINING_KEY else key): value for key, value in item.items()}
    _check_keys(item, _ROW_KEYS, where)
    if "slug" not in item or "preset" not in item:
        raise UserError(f"{where}: every row needs a 'slug' and a 'preset'")
    slug = _slug(item["slug"], f"{where}: slug")
    preset = _typed("preset", item["preset"], str, where)
    try:
        actor_config(preset)
    except UserError as error:
        raise UserError(f"{where}: {error}") from None
    label = item.get("label", slug)
    if not isinstance(label, str) or not label.strip():
        raise UserError(f"{where}: label must be a non-empty string, got {label!r}")
    return RowSpec(slug=slug, label=label, preset=preset,
                   overrides=_row_actor(preset, item.get("overrides", {}), f"{where}: overrides"),
                   algorithm=_row_algorithm(item, where), training=_row_training(item, where))


def _row_algorithm(item: Mapping[str, Any], where: str) -> str:
    """A row's ``algorithm`` (default ``td3``), one of the registered algorithms (:mod:`ilcsan.methods`)."""
    algorithm = _typed("algorithm", item.get("algorithm", methods.default("algorithm")), str, where)
    if algorithm not in methods.registered("algorithm"):
        raise UserError(f"{where}: algorithm {algorithm!r} is not one of: "
                        f"{', '.join(methods.registered('algorithm'))}")
    return algorithm


def _row_actor(preset: str, overrides: Any, where: str) -> dict[str, Any]:
    """A row's overrides, checked by building its actor (:func:`~ilcsan.config.actor_config`, whose errors name the
    switch; a deep actor takes only :data:`DAN_OVERRIDE_KEYS`)."""
    _check_keys(overrides, OVERRIDE_KEYS, where)
    checked = {key: _typed(key, value, _SWITCHES[key][1], where) for key, value in overrides.items()}
    try:
        network = actor_config(preset, **checked).network
    except UserError as error:
        raise UserError(f"{where}: {error}") from None
    spiking = sorted(set(checked) - set(DAN_OVERRIDE_KEYS))
    if network == "deep" and spiking:
        raise UserError(f"{where}: the deep actor (preset {preset!r}) has no spiking switch {spiking[0]!r}; "
                        f"it takes only {', '.join(DAN_OVERRIDE_KEYS)}")
    return checked


def _typed(key: str, value: Any, kind: type, where: str) -> Any:
    """``value`` if it has the type of its setting (an integer for ``int``, also not a boolean; any real number,
    made a float, for ``float``), else :class:`UserError`; its range and choices are the actor's to check."""
    accepted = (int, float) if kind is float else kind
    if not isinstance(value, accepted) or (isinstance(value, bool) and kind is not bool):
        raise UserError(f"{where}: {key} must be {_TYPE_WORDS.get(kind, kind.__name__)}, got {value!r}")
    return float(value) if kind is float else value


def _row_training(item: Mapping[str, Any], where: str) -> dict[str, Any]:
    """A row's ``training`` table (its training method), checked against the declared settings: a row may set the
    training settings that choose or tune a method (:func:`~ilcsan.config.method_settings`); the grid's others are
    shared. Whether its methods suit its actor, its algorithm and each task is checked with the grid's tasks
    (:func:`grid_from_dict`), and again run by run with the settings a grid's command adds
    (:func:`~ilcsan.experiments.grid.expand_grid`)."""
    training = item.get("training", {})
    _check_keys(training, method_settings(), f"{where}: training")
    try:
        check_settings(training_config_class()(**training))
    except (UserError, TypeError) as error:
        raise UserError(f"{where}: training: {error}") from None
    return dict(training)
