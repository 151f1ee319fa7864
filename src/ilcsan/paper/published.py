"""The paper's published numbers, transcribed by hand from ``ilc-san.tex`` as typed literals.

Nothing here is parsed or computed at import time: every number is written out as printed in the
paper (Chen, Peng, Huang, Tian, "Fully Spiking Actor Network with Intra-layer Connections for
Reinforcement Learning", IEEE TNNLS), so that the report can put the paper's value beside ours and
the tests can check the transcription against the paper's own arithmetic (APR, op totals, energy).

Tables, by their LaTeX label:

``tab:task``      :data:`TASKS` — state dimension N and action dimension M per task.
``tab:perf``      :data:`REWARD_TABLES` ``["perf"]`` — max average reward, DAN / SANs, eight tasks.
``tab:decode``    ``["decode"]`` — decoding methods without intra-layer connections.
``tab:dec_intra`` ``["dec_intra"]`` — decoding methods with intra-layer connections.
``tab:intra``     ``["intra"]`` — ablation of the intra-layer connections.
``tab:layer``     ``["layer"]`` — number of hidden layers of the backbone SNN.
``tab:fr``        :data:`FIRING_RATES` — firing rate of the layer feeding each FC layer.
``tab:op``        :data:`OP_COUNTS` — operations per FC layer (SOP, or FLOP for PopSAN's Group FC).
``tab:power``     :data:`ENERGY_NJ` — energy per inference in nJ.

Row keys are the stable slugs of the grids in :mod:`ilcsan.paper.layouts`, so a run made by ``ilcsan reproduce``
finds its published cell by ``(table, row slug, task)``. Rewards are "max average reward over 10 random seeds":
each seed's best evaluation (mean over 10 episodes), then mean ± std over the seeds. APR is printed in
percent; for ``decode``/``dec_intra``/``intra``/``layer`` it is relative to the DAN row of ``perf``
(the only DAN row in the paper). Every published APR follows from its row to within 0.02 percentage
points (``tests/test_grids.py`` checks this); the largest gap is ``intra``/``self+bias`` (85.76 %
printed, 85.78 % from the rounded means), which is beyond the rounding of the printed APR itself, so
the authors probably averaged unrounded rewards.

Cross-table identities in the paper (the same runs reused): perf ``popsan`` = decode ``fr``;
decode ``last-1.0`` = intra ``none``; perf ``ilc-san-pop-det`` = dec_intra ``last-1.0`` = intra ``intra``
= layer ``hidden-2``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

from ..config import intra_label

PAPER_TASK_NAMES: tuple[str, ...] = (
    "Ant",
    "HalfCheetah",
    "Hopper",
    "Walker2d",
    "Humanoid",
    "HumanoidStandup",
    "InvertedDoublePendulum",
    "BipedalWalker",
)
"""The eight tasks of Table ``tab:perf``, in the paper's order, by short name."""

FIRST_FOUR: tuple[str, ...] = PAPER_TASK_NAMES[:4]
"""The four tasks of every other table (Ant, HalfCheetah, Hopper, Walker2d)."""


@dataclass(frozen=True)
class TaskDims:
    """One row of Table ``tab:task``: the paper's Gym id, state dimension N, action dimension M."""

    paper_id: str
    n: int
    m: int


TASKS: dict[str, TaskDims] = {
    "Ant": TaskDims("Ant-v3", 111, 8),
    "HalfCheetah": TaskDims("HalfCheetah-v3", 17, 6),
    "Hopper": TaskDims("Hopper-v3", 11, 3),
    "Walker2d": TaskDims("Walker2d-v3", 17, 6),
    "Humanoid": TaskDims("Humanoid-v3", 376, 17),
    "HumanoidStandup": TaskDims("HumanoidStandup-v2", 376, 17),
    "InvertedDoublePendulum": TaskDims("InvertedDoublePendulum-v2", 11, 1),
    "BipedalWalker": TaskDims("BipedalWalker-v3", 24, 4),
}


@dataclass(frozen=True)
class Stat:
    """A published cell: mean ± std of the max average reward over the paper's 10 seeds."""

    mean: float
    std: float


@dataclass(frozen=True)
class PaperRow:
    """One row of a reward table: the printed cells per task and the printed APR (percent)."""

    slug: str
    label: str
    cells: Mapping[str, Stat]
    apr: float


@dataclass(frozen=True)
class PaperTable:
    """One reward table of the paper (``tab:<name>``)."""

    name: str
    caption: str
    tasks: tuple[str, ...]
    rows: tuple[PaperRow, ...]

    def row(self, slug: str) -> PaperRow:
        """The row with this slug; KeyError if the paper has none."""
        for row in self.rows:
            if row.slug == slug:
                return row
        raise KeyError(f"table {self.name!r} has no row {slug!r}")

    @property
    def slugs(self) -> tuple[str, ...]:
        return tuple(row.slug for row in self.rows)


def _cells(tasks: tuple[str, ...], *values: tuple[float, float]) -> dict[str, Stat]:
    """Pair the printed ``(mean, std)`` literals with their tasks, in column order."""
    if len(values) != len(tasks):
        raise ValueError(f"expected {len(tasks)} cells, got {len(values)}")
    return {task: Stat(float(mean), float(std)) for task, (mean, std) in zip(tasks, values, strict=True)}


def _r(slug: str, label: str, apr: float, *values: tuple[float, float], tasks=FIRST_FOUR) -> PaperRow:
    return PaperRow(slug, label, _cells(tasks, *values), apr)


def _intra(variant: str, apr: float, *values: tuple[float, float]) -> PaperRow:
    """A row of Table intra: its slug is the intra-layer variant, its label the paper's name of that variant."""
    return _r(variant, intra_label(variant), apr, *values)


_P8 = PAPER_TASK_NAMES
_AC_BCQ_TASKS = FIRST_FOUR  # AC-BCQ prints "−" for the last four tasks; its APR is over these four.

PERF = PaperTable(
    name="perf",
    caption="Max average rewards over 10 random seeds for DAN, ILC-SAN and other SANs",
    tasks=PAPER_TASK_NAMES,
    rows=(
        #                                          Ant           HalfCheetah     Hopper        Walker2d
        #                                          Humanoid      HumanoidStandup InvDblPendulum BipedalWalker
        _r("dan", "DAN", 100.00,
           (5472, 653), (10471, 1695), (3520, 105), (4999, 842),
           (3681, 2258), (129271, 13021), (8425, 2950), (194, 146), tasks=_P8),
        _r("popsan", "PopSAN", 101.81,
           (4848, 1023), (10523, 1142), (517, 1057), (4199, 1426),
           (5821, 440), (155387, 21632), (9327, 3), (267, 93), tasks=_P8),
        _r("mdc-san", "MDC-SAN", 114.48,
           (5410, 748), (10472, 1146), (3554, 153), (4604, 809),
           (5879, 225), (149815, 10404), (9323, 6), (267, 98), tasks=_P8),
        _r("akl", "Akl et al.", 63.90,
           (3820, 942), (3220, 1857), (2713, 1424), (3208, 1514),
           (135, 123), (73620, 33564), (9338, 8), (190, 86), tasks=_P8),
        _r("ac-bcq", "AC-BCQ", 74.63,
           (4070, 34), (10610, 63), (2527, 455), (2551, 932), tasks=_AC_BCQ_TASKS),
        _r("ilc-san-layer", "ILC-SAN (E_layer)", 112.77,
           (5752, 258), (10120, 1864), (3518, 182), (5263, 869),
           (5872, 236), (156062, 18252), (9335, 10), (202, 151), tasks=_P8),
        _r("ilc-san-pop", "ILC-SAN (E_pop)", 114.47,
           (5387, 529), (10422, 909), (3547, 163), (4919, 627),
           (5241, 1633), (161889, 31302), (9336, 13), (272, 100), tasks=_P8),
        _r("ilc-san-pop-det", "ILC-SAN (E_pop_det)", 118.05,
           (5653, 533), (10376, 1163), (3583, 86), (4511, 462),
           (5874, 395), (160974, 22132), (9327, 5), (301, 10), tasks=_P8),
    ),
)

DECODE = PaperTable(
    name="decode",
    caption="Max average rewards over 10 random seeds for various decoding methods without "
    "intra-layer connections",
    tasks=FIRST_FOUR,
    rows=(
        #                                                 Ant          HalfCheetah    Hopper        Walker2d
        _r("fr", "D_fr", 71.94, (4848, 1023), (10523, 1142), (517, 1057), (4199, 1426)),
        _r("last-1.0", "D_last (α_V=1.0)", 94.95, (5433, 619), (9932, 1238), (3249, 1082), (4668, 702)),
        _r("last-0.75", "D_last (α_V=0.75)", 94.50, (5001, 667), (9944, 1215), (3190, 1075), (5049, 426)),
        _r("last-0.5", "D_last (α_V=0.5)", 94.81, (5183, 903), (9936, 1308), (3217, 1089), (4910, 654)),
        _r("max-1.0", "D_max (α_V=1.0)", 94.59, (5222, 464), (9540, 1564), (3506, 158), (4609, 604)),
        _r("max-0.75", "D_max (α_V=0.75)", 92.03, (5021, 910), (8775, 1661), (3453, 156), (4723, 439)),
        _r("max-0.5", "D_max (α_V=0.5)", 94.16, (5268, 752), (9694, 1827), (3200, 1085), (4843, 797)),
        _r("mean-1.0", "D_mean (α_V=1.0)", 87.03, (5297, 544), (9995, 1169), (2183, 1712), (4691, 770)),
        _r("mean-0.75", "D_mean (α_V=0.75)", 88.21, (5635, 350), (9181, 1301), (2514, 1410), (4537, 1388)),
        _r("mean-0.5", "D_mean (α_V=0.5)", 71.73, (5278, 809), (9394, 1351), (512, 1001), (4309, 553)),
    ),
)

DEC_INTRA = PaperTable(
    name="dec_intra",
    caption="Max average rewards over 10 random seeds for different decoding methods with "
    "intra-layer connections",
    tasks=FIRST_FOUR,
    rows=(
        #                                                 Ant          HalfCheetah    Hopper        Walker2d
        _r("fr", "D_fr", 82.13, (5279, 508), (10111, 1065), (1394, 1394), (4794, 407)),
        _r("last-1.0", "D_last (α_V=1.0)", 98.61, (5653, 533), (10376, 1163), (3583, 86), (4511, 462)),
        _r("last-0.75", "D_last (α_V=0.75)", 94.38, (4796, 751), (10304, 803), (3527, 163), (4563, 835)),
        _r("last-0.5", "D_last (α_V=0.5)", 98.24, (5341, 532), (10200, 1399), (3479, 128), (4955, 664)),
    ),
)

INTRA = PaperTable(
    name="intra",
    caption="Max average rewards over 10 random seeds for ablation study on intra-layer connections",
    tasks=FIRST_FOUR,
    rows=(  # labelled by ilcsan.config.intra_label, the one place a variant's name in the paper is declared
        #                                Ant          HalfCheetah    Hopper        Walker2d
        _intra("none", 94.95, (5433, 619), (9932, 1238), (3249, 1082), (4668, 702)),
        _intra("self", 97.40, (5245, 769), (10168, 1465), (3512, 146), (4843, 757)),
        _intra("lateral", 95.55, (5389, 747), (9384, 987), (3521, 145), (4702, 728)),
        _intra("bias", 90.56, (4935, 862), (9906, 1208), (3141, 1034), (4409, 1527)),
        _intra("lateral+bias", 97.34, (5549, 404), (9685, 998), (3464, 151), (4851, 907)),
        # Printed APR 85.76 %; the printed means give 85.78 % (see the module docstring).
        _intra("self+bias", 85.76, (5114, 729), (8431, 1410), (2645, 1439), (4699, 504)),
        _intra("self+lateral", 93.90, (5067, 727), (9117, 2923), (3525, 133), (4788, 745)),
        _intra("intra", 98.61, (5653, 533), (10376, 1163), (3583, 86), (4511, 462)),
    ),
)

LAYER = PaperTable(
    name="layer",
    caption="Max average rewards over 10 random seeds for comparative experiments on the backbone SNN",
    tasks=FIRST_FOUR,
    rows=(
        #                                            Ant          HalfCheetah    Hopper        Walker2d
        _r("hidden-1", "N_hidden=1", 78.55, (4205, 809), (7455, 549), (3014, 719), (4026, 621)),
        _r("hidden-2", "N_hidden=2", 98.61, (5653, 533), (10376, 1163), (3583, 86), (4511, 462)),
        _r("hidden-3", "N_hidden=3", 95.73, (5402, 722), (10580, 1727), (3192, 951), (4623, 724)),
        _r("hidden-4", "N_hidden=4", 89.76, (4760, 997), (10057, 1081), (3223, 776), (4221, 1281)),
    ),
)

REWARD_TABLES: dict[str, PaperTable] = {
    table.name: table for table in (PERF, DECODE, DEC_INTRA, INTRA, LAYER)
}
"""The five reward tables by name (``perf``, ``decode``, ``dec_intra``, ``intra``, ``layer``)."""

APR_REFERENCE = ("perf", "dan")
"""Every published APR is relative to this row (Table ``tab:perf``, DAN)."""


def published_cell(table: str, row: str, task: str) -> Stat | None:
    """The paper's mean ± std for ``(table, row slug, task)``, or None where the paper has none."""
    paper_table = REWARD_TABLES.get(table)
    if paper_table is None:
        return None
    try:
        return paper_table.row(row).cells.get(task)
    except KeyError:
        return None


def published_apr(table: str, row: str) -> float | None:
    """The paper's APR in percent for ``(table, row slug)``, or None where the paper has none."""
    paper_table = REWARD_TABLES.get(table)
    if paper_table is None:
        return None
    try:
        return paper_table.row(row).apr
    except KeyError:
        return None


# ----------------------------------------------------------------------------------------------
# Energy analysis (Section V-F): Tables tab:fr, tab:op, tab:power. Actors: "popsan", "ilc-san".

ENERGY_TASKS: tuple[str, ...] = FIRST_FOUR


@dataclass(frozen=True)
class LayerRates:
    """One row of Table ``tab:fr``: firing rate of the layer *feeding* each FC layer, as a fraction.

    The paper prints percent rounded to 0.1 %; these are those values divided by 100. ``intra_fc`` is
    None for PopSAN, which has no intra-layer connections.
    """

    fc1: float
    fc2: float
    fc3: float
    group_fc: float
    intra_fc: float | None


FIRING_RATES: dict[str, dict[str, LayerRates]] = {
    "popsan": {
        "Ant": LayerRates(0.030, 0.388, 0.583, 0.839, None),
        "HalfCheetah": LayerRates(0.197, 0.335, 0.510, 0.694, None),
        "Hopper": LayerRates(0.298, 0.687, 0.567, 0.459, None),
        "Walker2d": LayerRates(0.187, 0.512, 0.678, 0.528, None),
    },
    "ilc-san": {
        "Ant": LayerRates(0.028, 0.355, 0.490, 0.413, 0.315),
        "HalfCheetah": LayerRates(0.187, 0.259, 0.391, 0.400, 0.307),
        "Hopper": LayerRates(0.165, 0.208, 0.369, 0.421, 0.328),
        "Walker2d": LayerRates(0.159, 0.274, 0.475, 0.471, 0.370),
    },
}


@dataclass(frozen=True)
class LayerOps:
    """One row of Table ``tab:op``: operations per inference of each FC layer.

    FC1-FC3 and Intra FC are synaptic operations (SOP). ``group_fc_unit`` says how the paper counts
    the Group FC: "SOP" for ILC-SAN (spikes in), "FLOP" for PopSAN (firing rates in; the paper counts
    it as T·fr·Din·Dout, e.g. Ant 336 = 5 · 0.839 · 80, but Table ``tab:power`` charges Din·Dout).
    ``total_sop`` and ``total_flop`` are the printed totals.
    """

    fc1: int
    fc2: int
    fc3: int
    group_fc: int
    group_fc_unit: Literal["SOP", "FLOP"]
    intra_fc: int | None
    total_sop: int
    total_flop: int


OP_COUNTS: dict[str, dict[str, LayerOps]] = {
    "popsan": {
        "Ant": LayerOps(42624, 127140, 59699, 336, "FLOP", None, 229463, 336),
        "HalfCheetah": LayerOps(42867, 109773, 39168, 208, "FLOP", None, 191808, 208),
        "Hopper": LayerOps(41958, 225116, 21773, 69, "FLOP", None, 288847, 69),
        "Walker2d": LayerOps(40604, 167772, 52070, 158, "FLOP", None, 260447, 158),
    },
    "ilc-san": {
        "Ant": LayerOps(40351, 116326, 50176, 165, "SOP", 1260, 208278, 0),
        "HalfCheetah": LayerOps(40691, 84869, 30029, 120, "SOP", 921, 156630, 0),
        "Hopper": LayerOps(23232, 68157, 14170, 63, "SOP", 492, 106114, 0),
        "Walker2d": LayerOps(34598, 89784, 36480, 141, "SOP", 1110, 162114, 0),
    },
}

ENERGY_NJ: dict[str, dict[str, float]] = {
    "dan": {"Ant": 1200.0, "HalfCheetah": 892.8, "Hopper": 864.0, "Walker2d": 892.8},
    "popsan": {"Ant": 18.7, "HalfCheetah": 15.5, "Hopper": 22.6, "Walker2d": 20.8},
    "ilc-san": {"Ant": 16.0, "HalfCheetah": 12.1, "Hopper": 8.2, "Walker2d": 12.5},
}
"""Table ``tab:power``: energy per inference in nanojoule, by actor then task."""

ENERGY_PER_FLOP_PJ = 12.5
"""Energy of one FLOP in pJ (FPGA figure used by the paper, Section V-F)."""

ENERGY_PER_SOP_PJ = 0.077
"""Energy of one SOP in pJ (77 fJ, ROLLS, Section V-F)."""

TIMESTEPS = 5
"""Simulation time T of every spiking actor in the paper."""

POPULATION = 10
"""Population size P_in = P_out per state/action dimension."""
