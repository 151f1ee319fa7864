"""The paper's reward tables as grids of runs (tasks × rows × seeds), and our ``beyond``, ``algorithms`` and
``fidelity`` grids.

Each reward table of the paper (``tab:perf``, ``tab:decode``, ``tab:dec_intra``, ``tab:intra``,
``tab:layer``) is a :class:`TableSpec`: its tasks, its rows, and the paper's protocol (10 seeds,
1 000 000 steps, an evaluation of 10 deterministic episodes every 10 000 steps, Section V-A). Its caption, tasks
and rows (slug, label, order) are the published table's (:mod:`.published`); what this module adds is the actor
each row runs: a preset (:data:`~ilcsan.config.PRESETS`) plus overrides of the actor's switches (fields of
:class:`~ilcsan.config.ActorConfig`, with ``hidden_layers`` and ``hidden_width`` for its hidden widths).
``ilcsan reproduce`` runs every (task, row, seed) and writes ``OUT/<table>/<task>/<row-slug>/seed<k>/``; the
report finds a run's published number by its table and row slug.

The ``ilc-san`` preset is E_pop_det, full intra-layer connections, D_last with α_V^LI = 1.0, 2×256;
``popsan`` is E_pop_det, no intra-layer connections, D_fr; ``mdc-san`` is E_pop with dynamic neurons
and D_fr; ``akl`` is Akl et al. 2023; ``dan`` is TD3's deep actor (MLP).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ..config import INTRA_VARIANTS, MAX_HIDDEN_LAYERS, RunConfig
from ..methods import DEFAULT_ALGORITHM
from . import published
from .published import PaperTable

SEEDS = 10
"""Seeds per cell in the paper (Section V-A); the protocol's budget and evaluation are the run defaults."""
STEPS, EVAL_EVERY, EVAL_EPISODES = RunConfig.steps, RunConfig.eval_every, RunConfig.eval_episodes


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
    training: Mapping[str, Any] = field(default_factory=dict, hash=False)
    """Training settings of this row (training methods such as ``target_actor``), over the grid's own."""
    algorithm: str = DEFAULT_ALGORITHM
    """The off-policy algorithm that trains this row's actor (``--algorithm``; :mod:`ilcsan.methods`)."""
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


Actor = tuple[str, dict[str, Any]]
"""What a row runs: an actor preset and overrides of its switches."""


def _actor(preset: str, **overrides: Any) -> Actor:
    return preset, overrides


def _paper_grid(table: PaperTable, actors: Mapping[str, Actor | None]) -> TableSpec:
    """A reward table of the paper as a grid: its caption, tasks and rows (slug, label, order) as published, each
    row running the actor ``actors`` gives for its slug (None: no code exists, the row carries the paper's numbers
    only)."""
    if set(actors) != set(table.slugs):
        raise ValueError(f"table {table.name!r}: actors for {sorted(actors)}, but its rows are {list(table.slugs)}")
    rows = tuple(RowSpec(row.slug, row.label, None, runnable=False) if actors[row.slug] is None
                 else RowSpec(row.slug, row.label, *actors[row.slug]) for row in table.rows)
    return TableSpec(table.name, table.caption, table.tasks, rows)


PERF = _paper_grid(published.PERF, {
    "dan": _actor("dan"),
    "popsan": _actor("popsan"),
    "mdc-san": _actor("mdc-san"),
    "akl": _actor("akl"),
    "ac-bcq": None,
    "ilc-san-layer": _actor("ilc-san", encoder="layer"),
    "ilc-san-pop": _actor("ilc-san", encoder="pop"),
    "ilc-san-pop-det": _actor("ilc-san", encoder="pop-det"),
})


def _decoders(decoders: tuple[str, ...], intra: str) -> dict[str, Actor]:
    """The rows ``<decoder>-<α_V^LI>`` of Tables decode and dec_intra."""
    return {f"{decoder}-{alpha}": _actor("ilc-san", decoder=decoder, alpha_v_li=alpha, intra=intra)
            for decoder in decoders for alpha in (1.0, 0.75, 0.5)}


DECODE = _paper_grid(published.DECODE, {"fr": _actor("popsan"), **_decoders(("last", "max", "mean"), intra="none")})
DEC_INTRA = _paper_grid(published.DEC_INTRA, {"fr": _actor("ilc-san", decoder="fr"),
                                              **_decoders(("last",), intra="intra")})
INTRA = _paper_grid(published.INTRA, {variant: _actor("ilc-san", intra=variant) for variant in INTRA_VARIANTS})
LAYER = _paper_grid(published.LAYER, {f"hidden-{layers}": _actor("ilc-san", hidden_layers=layers)
                                      for layers in range(1, MAX_HIDDEN_LAYERS + 1)})

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

ALGORITHMS = TableSpec(
    name="algorithms",
    caption="ILC-SAN trained by TD3, DDPG and SAC, and by TD3 with CaRe-BN",
    tasks=("Hopper",),
    rows=(
        RowSpec("ilc-san", "ILC-SAN (TD3)", "ilc-san", published=("perf", "ilc-san-pop-det")),
        RowSpec("ilc-san+ddpg", "ILC-SAN (DDPG)", "ilc-san", algorithm="ddpg"),
        RowSpec("ilc-san+sac", "ILC-SAN (SAC)", "ilc-san", algorithm="sac"),
        RowSpec("ilc-san+care-bn", "ILC-SAN + CaRe-BN (TD3)", "ilc-san", {"normalization": "care-bn"}),
    ),
    seeds=BEYOND.seeds,
    steps=BEYOND.steps,
)
"""Our grid (not a table of the paper): the same actor trained by DDPG and by SAC beside TD3
(:mod:`ilcsan.rl.algorithms`), and by TD3 with CaRe-BN (Xu et al., ICLR 2026), on Hopper with the ``beyond`` grid's
seeds and budget, so that its TD3 row is that grid's ILC-SAN row (``ilcsan report`` places those runs here by their
configuration)."""

FIDELITY = TableSpec(
    name="fidelity",
    caption="Hopper's collapsed start: Algorithm 1's intra-layer timing, the authors' code's, and two remedies",
    tasks=("Hopper",),
    rows=(
        RowSpec("paper", "ILC-SAN, intra timing of Algorithm 1", "ilc-san", {"intra_timing": "paper"}),
        RowSpec("authors", "ILC-SAN, intra timing of the authors' code", "ilc-san", {"intra_timing": "authors"}),
        RowSpec("penalty", "ILC-SAN, penalty 0.1·mean(O²) in the actor's loss", "ilc-san", {}, True,
                {"preaction_penalty": 0.1}),
        RowSpec("late-updates", "ILC-SAN, first update after the random phase", "ilc-san", {}, True,
                {"update_after": 10_000}),
    ),
    seeds=16,
    steps=50_000,
)
"""Our grid (not a table of the paper): how many Hopper seeds stay in the collapsed start under each intra-layer
timing (``--intra-timing``), and under two remedies that keep ILC-SAN's network: a penalty on the pre-tanh output
(``--preaction-penalty``) and no update before the random phase ends (``--update-after 10000``, as in Fujimoto et al.'s
TD3); 16 seeds × 50 000 steps by default (docs/fidelity-hopper/)."""

TABLES: dict[str, TableSpec] = {spec.name: spec
                                for spec in (PERF, DECODE, DEC_INTRA, INTRA, LAYER, BEYOND, ALGORITHMS, FIDELITY)}
"""The paper's five reward tables as grids, by name, and our ``beyond``, ``algorithms`` and ``fidelity`` grids."""
