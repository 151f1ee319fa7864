"""A user's grid of runs from a TOML file: read, and every key and value checked, into a :class:`TableSpec`.

A grid file has the shape of the paper's tables as grids (:mod:`ilcsan.paper.layouts`): tasks × rows × seeds
with the evaluation protocol, each row an actor preset plus overrides of the actor's switches (the fields of
:class:`~ilcsan.config.ActorConfig`) and, optionally, its TD3 training method. :func:`load_grid` documents the format.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..config import (
    DECODERS,
    ENCODERS,
    INTRA_TIMINGS,
    INTRA_VARIANTS,
    PRESET_NAMES,
    TD3Config,
    check_settings,
)
from ..errors import UserError
from ..paper.layouts import EVAL_EPISODES, EVAL_EVERY, SEEDS, STEPS, TABLES, RowSpec, TableSpec
from ..paper.published import PAPER_TASK_NAMES

OVERRIDE_KEYS: tuple[str, ...] = (
    "encoder", "decoder", "alpha_v_li", "intra", "intra_timing", "hidden_layers", "hidden_width",
)
DAN_OVERRIDE_KEYS: tuple[str, ...] = ("hidden_layers", "hidden_width")
"""The only switches that mean something for the deep actor (DAN)."""

_SLUG = re.compile(r"^[a-z0-9][a-z0-9._+-]*$")
_GYM_ID = re.compile(r"^(?:[A-Za-z0-9_.-]+[:/])?[A-Za-z][A-Za-z0-9_.-]*-v\d+$")


_TOP_KEYS = ("name", "caption", "tasks", "rows", "seeds", "steps", "eval_every", "eval_episodes")
_ROW_KEYS = ("slug", "label", "preset", "overrides", "td3")
ROW_TD3_KEYS: tuple[str, ...] = ("target_actor", "proxy_iterations", "proxy_lr", "exploration", "noisy_sigma",
                                 "noisy_beta", "noisy_return_reference")
"""The TD3 settings a grid row may set (its training method); the grid's other TD3 settings are shared."""


def is_task_name(task: str) -> bool:
    """True for one of the paper's short names or anything shaped like a Gymnasium id (``Name-vN``)."""
    return task in PAPER_TASK_NAMES or bool(_GYM_ID.match(task))


def load_grid(path: str | Path) -> TableSpec:
    """Read a user's grid of runs from a TOML file and validate every key and value.

    The format mirrors :class:`TableSpec`: top-level ``name`` (a slug), ``tasks`` (short names such
    as ``Hopper`` or Gymnasium ids such as ``Pendulum-v1``) and at least one ``[[rows]]`` are
    required; ``caption``, ``seeds`` (10), ``steps`` (1 000 000), ``eval_every`` (10 000) and
    ``eval_episodes`` (10) are optional. Each row has a unique ``slug``, a ``preset``, an optional
    ``label`` (defaults to the slug) and optional ``overrides`` of the actor switches::

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
    rows = _rows(data["rows"], source)
    return TableSpec(
        name=name,
        caption=caption,
        tasks=_tasks(data["tasks"], source),
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
    _check_keys(item, _ROW_KEYS, where)
    if "slug" not in item or "preset" not in item:
        raise UserError(f"{where}: every row needs a 'slug' and a 'preset'")
    slug = _slug(item["slug"], f"{where}: slug")
    preset = item["preset"]
    if preset not in PRESET_NAMES:
        raise UserError(f"{where}: unknown preset {preset!r}; choose one of {', '.join(PRESET_NAMES)}")
    label = item.get("label", slug)
    if not isinstance(label, str) or not label.strip():
        raise UserError(f"{where}: label must be a non-empty string, got {label!r}")
    overrides = item.get("overrides", {})
    _check_keys(overrides, OVERRIDE_KEYS, f"{where}: overrides")
    checked = {key: _override(key, value, f"{where}: overrides") for key, value in overrides.items()}
    if preset == "dan":
        bad = sorted(set(checked) - set(DAN_OVERRIDE_KEYS))
        if bad:
            raise UserError(f"{where}: the deep actor (preset 'dan') has no spiking switch {bad[0]!r}; "
                            f"it takes only {', '.join(DAN_OVERRIDE_KEYS)}")
    return RowSpec(slug=slug, label=label, preset=preset, overrides=checked, td3=_row_td3(item, preset, where))


def _row_td3(item: Mapping[str, Any], preset: str, where: str) -> dict[str, Any]:
    """A row's ``td3`` table (its training method), checked against :class:`TD3Config`'s declared settings."""
    td3 = item.get("td3", {})
    _check_keys(td3, ROW_TD3_KEYS, f"{where}: td3")
    try:
        settings = TD3Config(**td3)
        check_settings(settings)
        settings.check_network("deep" if preset == "dan" else "spiking")
    except (UserError, TypeError) as error:
        raise UserError(f"{where}: td3: {error}") from None
    return dict(td3)


def _override(key: str, value: Any, where: str) -> Any:
    choices = {"encoder": ENCODERS, "decoder": DECODERS, "intra": INTRA_VARIANTS,
               "intra_timing": INTRA_TIMINGS}.get(key)
    if choices is not None:
        if value not in choices:
            raise UserError(f"{where}: {key} = {value!r} is not one of {', '.join(choices)}")
        return value
    if key == "alpha_v_li":
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        if not ok or not 0.0 <= value <= 1.0:
            raise UserError(f"{where}: alpha_v_li is a decay factor in [0, 1], got {value!r}")
        return float(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise UserError(f"{where}: {key} must be an integer, got {value!r}")
    if key == "hidden_layers" and not 1 <= value <= 4:
        raise UserError(f"{where}: hidden_layers must be 1 to 4, got {value}")
    if key == "hidden_width" and value < 1:
        raise UserError(f"{where}: hidden_width must be at least 1, got {value}")
    return value
