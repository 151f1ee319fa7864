"""Numbers the papers after ILC-SAN published, for the report of our ``beyond`` grid: typed literals with their source.

Not our runs and not the same protocol: each set says where it comes from and how it was measured, and the report
prints it under our table, never inside its cells.

- **Proxy Target** (Xu, Bu, Hao, Ding, Yu, NeurIPS 2025, arXiv 2505.24161), Table 1, transcribed from the
  camera-ready PDF (read in the reproduction repository ``madao2333/Proxy-Target-with-PLIF`` at commit 553f52fd,
  ``graduation_thesis/references/``): TD3 on Gymnasium's ``-v4`` tasks, "max average returns over 5 random seeds",
  ± one standard deviation, 5 simulation steps, learning rates 3e-4, batch 256. The text does not state the
  training budget; its learning curves run to 1 000 000 steps. Its "pop-SAN" row is its vanilla CLIF actor
  (Table 9 repeats it as "Vanilla CLIF"), so "PT-CLIF" is that PopSAN-style actor with Proxy Target — not ILC-SAN
  with Proxy Target, which the paper does not report.
- **NoisySAN** (Chen, Peng, Huang, Tian, arXiv 2403.04162): its results table was in none of the sources we could
  read (SpikingJelly's example code has none); nothing is transcribed.
- **CaRe-BN** (Xu, Shi, Dong, Huang, Yu, ICLR 2026, arXiv 2509.23791): the stored copies of its arXiv pages end
  before its results, and its code's README (``xuzijie32/CaRe-BN``) has no table; nothing is transcribed. The
  report names the one figure a third-party summary of it gives for Hopper, marked as unverified.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..paper.published import Stat


@dataclass(frozen=True)
class PublishedSet:
    """One paper's published rows: ``rows[label][task]`` → mean ± std, with the source and protocol in words, and
    each row's printed average gain in percent over the ``reference`` row (mean over tasks of cell / reference − 1),
    which the tests recompute from the cells to check the transcription."""

    source: str
    protocol: str
    rows: dict[str, dict[str, Stat]]
    reference: str
    gains: dict[str, float]


_PT_TASKS = ("InvertedDoublePendulum", "Ant", "HalfCheetah", "Hopper", "Walker2d")


def _pt_row(*cells: tuple[float, float]) -> dict[str, Stat]:
    return {task: Stat(mean, std) for task, (mean, std) in zip(_PT_TASKS, cells, strict=True)}


PROXY_TARGET = PublishedSet(
    source="Xu et al., Proxy Target, NeurIPS 2025, Table 1",
    protocol="Gymnasium -v4 tasks, TD3, 5 seeds, max average return ± std; budget not stated (curves to 1M steps)",
    rows={
        "ANN (TD3)": _pt_row((7503, 3713), (4770, 1014), (10857, 475), (3410, 164), (4340, 383)),
        "pop-SAN (vanilla CLIF)": _pt_row((9351, 1), (4590, 1006), (9594, 689), (2772, 1263), (3307, 1514)),
        "MDC-SAN": _pt_row((9350, 1), (4800, 994), (9147, 231), (3446, 131), (3964, 1353)),
        "ILC-SAN": _pt_row((9352, 1), (5584, 272), (9222, 615), (3403, 148), (4200, 717)),
        "PT-CLIF (pop-SAN-style CLIF actor + Proxy Target)": _pt_row(
            (9351, 1), (5014, 1074), (9663, 426), (3526, 112), (4564, 555)),
        "PT-LIF": _pt_row((9348, 1), (5383, 250), (10103, 607), (3385, 157), (4314, 423)),
        "PT-DN": _pt_row((9350, 1), (5400, 277), (9347, 666), (3507, 144), (4277, 650)),
    },
    reference="ANN (TD3)",
    gains={"ANN (TD3)": 0.00, "pop-SAN (vanilla CLIF)": -6.66, "MDC-SAN": 0.37, "ILC-SAN": 4.64,
           "PT-CLIF (pop-SAN-style CLIF actor + Proxy Target)": 5.46, "PT-LIF": 5.84, "PT-DN": 5.06},
)

FOLLOW_UPS: dict[str, tuple[PublishedSet, ...]] = {"beyond": (PROXY_TARGET,)}
"""The published sets printed under each of our tables, by table name."""

NOT_FOUND: dict[str, tuple[str, ...]] = {
    "beyond": ("NoisySAN (Chen et al., arXiv 2403.04162): no results table in any source we could read; "
               "nothing transcribed.",),
    "algorithms": ("CaRe-BN (Xu et al., ICLR 2026, arXiv 2509.23791): its results table was in none of the sources "
                   "we could read; nothing transcribed. A third-party summary of it gives Hopper 3586 for a "
                   "PopSAN-style CLIF actor with CaRe-BN and TD3 (mean of 5 seeds' best average returns over "
                   "1 000 000 steps, no std): unverified, and another actor and budget than this grid's.",),
}
"""Papers whose numbers the report would print but that we could not read, said so under the table."""
