"""The paper's tables as grids of runs (tasks × seeds × rows), as data; and user grids from TOML.

Each reward table of the paper (``tab:perf``, ``tab:decode``, ``tab:dec_intra``, ``tab:intra``,
``tab:layer``) is a :class:`TableSpec`: its tasks, its rows, and the paper's protocol (10 seeds,
1 000 000 steps, an evaluation of 10 deterministic episodes every 10 000 steps, Section V-A). A row
is an actor preset plus overrides of the actor's switches; ``ilcsan reproduce`` runs every
(task, row, seed) and writes ``OUT/<table>/<task>/<row-slug>/seed<k>/``. Row slugs are the keys of
:mod:`ilcsan.analysis.paper`, so the report puts the published number beside ours.

Actor switches (fields of the actor configuration): ``preset`` ∈ :data:`~ilcsan.config.PRESET_NAMES`; overrides
``encoder`` ∈ :data:`ENCODERS`, ``decoder`` ∈ :data:`DECODERS`, ``alpha_v_li`` (float),
``intra`` ∈ :data:`INTRA_VARIANTS`, ``hidden_layers`` (1-4), ``hidden_width`` (≥ 1).
``alpha_v_li`` is the decay factor α_V^LI of the decoder's LI neuron, in [0, 1].
The ``ilc-san`` preset is E_pop_det, full intra-layer connections, D_last with α_V^LI = 1.0, 2×256;
``popsan`` is E_pop_det, no intra-layer connections, D_fr; ``mdc-san`` is E_pop with dynamic neurons
and D_fr; ``akl`` is Akl et al. 2023; ``dan`` is TD3's deep actor (MLP).
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..analysis.paper import FIRST_FOUR, PAPER_TASKS
from ..config import (
    DECODERS,
    ENCODERS,
    INTRA_TIMINGS,
    INTRA_VARIANTS,
    PRESET_NAMES,
    RunConfig,
    TD3Config,
    check_settings,
)
from ..errors import UserError

OVERRIDE_KEYS: tuple[str, ...] = (
    "encoder", "decoder", "alpha_v_li", "intra", "intra_timing", "hidden_layers", "hidden_width",
)
DAN_OVERRIDE_KEYS: tuple[str, ...] = ("hidden_layers", "hidden_width")
"""The only switches that mean something for the deep actor (DAN)."""

SEEDS = 10
"""Seeds per cell in the paper (Section V-A); the protocol's budget and evaluation are the run defaults."""
STEPS, EVAL_EVERY, EVAL_EPISODES = RunConfig.steps, RunConfig.eval_every, RunConfig.eval_episodes

_SLUG = re.compile(r"^[a-z0-9][a-z0-9._+-]*$")
_GYM_ID = re.compile(r"^(?:[A-Za-z0-9_.-]+[:/])?[A-Za-z][A-Za-z0-9_.-]*-v\d+$")


@dataclass(frozen=True)
class RowSpec:
    """One row of a table: an actor (preset + switch overrides) and how the paper labels it.

    ``runnable`` is False for a row that only carries the paper's numbers (AC-BCQ: no code exists);
    such a row has ``preset`` None.
    """

    slug: str
    label: str
    preset: str | None
    overrides: Mapping[str, Any] = field(default_factory=dict, hash=False)
    runnable: bool = True
    td3: Mapping[str, Any] = field(default_factory=dict, hash=False)
    """TD3 settings of this row (training methods such as ``target_actor``), over the grid's own."""
    published: tuple[str, str] | None = None
    """In a grid that is not a table of the paper: the paper's (table, row) that ran this same actor and method,
    whose published cells a report shows beside this row's (its APR, over other tasks, is not shown)."""

    def actor(self) -> dict[str, Any]:
        """The actor switches of this row: ``{"preset": ..., **overrides}``."""
        if self.preset is None:
            raise ValueError(f"row {self.slug!r} has no actor (it carries the paper's numbers only)")
        return {"preset": self.preset, **self.overrides}


@dataclass(frozen=True)
class TableSpec:
    """A table as a grid of runs: tasks × rows × seeds, with the evaluation protocol."""

    name: str
    caption: str
    tasks: tuple[str, ...]
    rows: tuple[RowSpec, ...]
    seeds: int = SEEDS
    steps: int = STEPS
    eval_every: int = EVAL_EVERY
    eval_episodes: int = EVAL_EPISODES

    def row(self, slug: str) -> RowSpec:
        """The row with this slug; KeyError if none."""
        for row in self.rows:
            if row.slug == slug:
                return row
        raise KeyError(f"table {self.name!r} has no row {slug!r}")

    @property
    def runnable_rows(self) -> tuple[RowSpec, ...]:
        return tuple(row for row in self.rows if row.runnable)

    def runs(self) -> list[tuple[str, RowSpec, int]]:
        """Every (task, row, seed) of the grid that can run, seeds numbered from 0."""
        return [(task, row, seed) for task in self.tasks for row in self.runnable_rows
                for seed in range(self.seeds)]


def _row(slug: str, label: str, preset: str | None, runnable: bool = True, **overrides: Any) -> RowSpec:
    return RowSpec(slug, label, preset, dict(overrides), runnable)


PERF = TableSpec(
    name="perf",
    caption="Max average rewards over 10 random seeds for DAN, ILC-SAN and other SANs",
    tasks=PAPER_TASKS,
    rows=(
        _row("dan", "DAN", "dan"),
        _row("popsan", "PopSAN", "popsan"),
        _row("mdc-san", "MDC-SAN", "mdc-san"),
        _row("akl", "Akl et al.", "akl"),
        _row("ac-bcq", "AC-BCQ", None, runnable=False),
        _row("ilc-san-layer", "ILC-SAN (E_layer)", "ilc-san", encoder="layer"),
        _row("ilc-san-pop", "ILC-SAN (E_pop)", "ilc-san", encoder="pop"),
        _row("ilc-san-pop-det", "ILC-SAN (E_pop_det)", "ilc-san", encoder="pop-det"),
    ),
)


def _decoder_rows(decoders: tuple[str, ...], intra: str) -> tuple[RowSpec, ...]:
    return tuple(
        _row(f"{decoder}-{alpha}", f"D_{decoder} (α_V={alpha})", "ilc-san",
             decoder=decoder, alpha_v_li=alpha, intra=intra)
        for decoder in decoders for alpha in (1.0, 0.75, 0.5)
    )


DECODE = TableSpec(
    name="decode",
    caption="Max average rewards over 10 random seeds for various decoding methods without "
    "intra-layer connections",
    tasks=FIRST_FOUR,
    rows=(_row("fr", "D_fr", "popsan"), *_decoder_rows(("last", "max", "mean"), intra="none")),
)

DEC_INTRA = TableSpec(
    name="dec_intra",
    caption="Max average rewards over 10 random seeds for different decoding methods with "
    "intra-layer connections",
    tasks=FIRST_FOUR,
    rows=(_row("fr", "D_fr", "ilc-san", decoder="fr"), *_decoder_rows(("last",), intra="intra")),
)

_INTRA_LABELS = {
    "none": "No I_intra", "self": "I_self", "lateral": "I_lateral", "bias": "I_bias",
    "lateral+bias": "I_lateral+I_bias", "self+bias": "I_self+I_bias",
    "self+lateral": "I_self+I_lateral", "intra": "I_intra",
}

INTRA = TableSpec(
    name="intra",
    caption="Max average rewards over 10 random seeds for ablation study on intra-layer connections",
    tasks=FIRST_FOUR,
    rows=tuple(_row(variant, label, "ilc-san", intra=variant) for variant, label in _INTRA_LABELS.items()),
)

LAYER = TableSpec(
    name="layer",
    caption="Max average rewards over 10 random seeds for comparative experiments on the backbone SNN",
    tasks=FIRST_FOUR,
    rows=tuple(_row(f"hidden-{n}", f"N_hidden={n}", "ilc-san", hidden_layers=n) for n in range(1, 5)),
)

BEYOND = TableSpec(
    name="beyond",
    caption="Beyond the paper: ILC-SAN with the training methods that followed it, against DAN",
    tasks=("Hopper",),
    rows=(
        RowSpec("ilc-san", "ILC-SAN", "ilc-san", published=("perf", "ilc-san-pop-det")),
        RowSpec("ilc-san+proxy", "ILC-SAN + Proxy Target", "ilc-san", {}, True, {"target_actor": "proxy"}),
        RowSpec("ilc-san+noisy", "ILC-SAN + NoisySAN", "ilc-san", {}, True, {"exploration": "noisy"}),
        RowSpec("dan", "DAN", "dan", published=("perf", "dan")),
    ),
    seeds=5,
    steps=200_000,
)
"""Our grid (not a table of the paper): Proxy Target (Xu et al., NeurIPS 2025) and NoisySAN exploration (Chen et
al. 2024) against plain ILC-SAN and DAN on Hopper, 5 seeds × 200 000 steps by default."""

FIDELITY = TableSpec(
    name="fidelity",
    caption="Hopper's collapsed start: the intra-layer timing of Algorithm 1 against the authors' code's",
    tasks=("Hopper",),
    rows=(
        RowSpec("paper", "ILC-SAN, intra timing of Algorithm 1", "ilc-san", {"intra_timing": "paper"}),
        RowSpec("authors", "ILC-SAN, intra timing of the authors' code", "ilc-san", {"intra_timing": "authors"}),
    ),
    seeds=16,
    steps=50_000,
)
"""Our grid (not a table of the paper): how many Hopper seeds stay in the collapsed start under each intra-layer
timing (``--intra-timing``), 16 seeds × 50 000 steps by default (docs/fidelity-hopper/)."""

TABLES: dict[str, TableSpec] = {spec.name: spec
                                for spec in (PERF, DECODE, DEC_INTRA, INTRA, LAYER, BEYOND, FIDELITY)}
"""The paper's five reward tables as grids, by name, and our ``beyond`` and ``fidelity`` grids."""


# ----------------------------------------------------------------------------------------------
# User grids from TOML

_TOP_KEYS = ("name", "caption", "tasks", "rows", "seeds", "steps", "eval_every", "eval_episodes")
_ROW_KEYS = ("slug", "label", "preset", "overrides", "td3")
ROW_TD3_KEYS: tuple[str, ...] = ("target_actor", "proxy_iterations", "proxy_lr", "exploration", "noisy_sigma",
                                 "noisy_beta", "noisy_return_reference")
"""The TD3 settings a grid row may set (its training method); the grid's other TD3 settings are shared."""


def is_task_name(task: str) -> bool:
    """True for one of the paper's short names or anything shaped like a Gymnasium id (``Name-vN``)."""
    return task in PAPER_TASKS or bool(_GYM_ID.match(task))


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
            raise UserError(f"{source}: unknown task {task!r}; use one of {', '.join(PAPER_TASKS)} "
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
