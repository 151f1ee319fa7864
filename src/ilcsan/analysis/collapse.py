"""Seeds that stay in a task's collapsed start: how many per row, how sure we are, and what their actors look like.

On Hopper a spiking actor can sit for tens of thousands of steps (or for ever) in one constant, saturated action:
the hopper falls after about 20 steps and the evaluation return stays below 100. A row's *collapsed share* at step
s is the share of its seeds whose evaluation at s returned less than the threshold; with n seeds and k collapsed,
the 95 % interval is Wilson's score interval and two rows are compared by Fisher's exact test (two-sided, the
probability under equal shares of a table at most as likely as the one seen). The figure draws the actors'
diagnostics (:mod:`ilcsan.snn.diagnostics`) over the first steps, collapsed seeds against the rest.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import COLLAPSE_RETURN
from ..files import atomic_write_file
from ..runs.directory import DIAGNOSTICS
from .collect import RunRecord
from .reward_tables import seed_std

Z_95 = 1.959963984540054
"""The standard normal quantile of a two-sided 95 % interval."""


def wilson_interval(collapsed: int, seeds: int, z: float = Z_95) -> tuple[float, float]:
    """Wilson's score interval for a share ``collapsed / seeds`` (95 % by default)."""
    if seeds <= 0:
        return math.nan, math.nan
    share = collapsed / seeds
    centre = (share + z * z / (2 * seeds)) / (1 + z * z / seeds)
    half = z * math.sqrt(share * (1 - share) / seeds + z * z / (4 * seeds * seeds)) / (1 + z * z / seeds)
    return max(0.0, centre - half), min(1.0, centre + half)


def fisher_exact(first: tuple[int, int], second: tuple[int, int]) -> float:
    """Two-sided p-value of Fisher's exact test for the 2×2 table of (collapsed, seeds) of two rows: the total
    probability, with the margins fixed, of the tables at most as likely as the observed one."""
    (a, n1), (c, n2) = first, second
    total, collapsed = n1 + n2, a + c

    def probability(k: int) -> float:
        return math.comb(n1, k) * math.comb(n2, collapsed - k) / math.comb(total, collapsed)

    observed = probability(a)
    low, high = max(0, collapsed - n2), min(n1, collapsed)
    p = sum(probability(k) for k in range(low, high + 1) if probability(k) <= observed * (1 + 1e-9))
    return min(1.0, p)


def return_at(run: RunRecord, step: int) -> float | None:
    """The run's evaluation return at ``step`` (None if it did not evaluate there)."""
    values = dict(zip(run.steps, run.returns, strict=True))
    return values.get(step)


@dataclass(frozen=True)
class CollapseRow:
    """One row's seeds at the steps asked for: collapsed count, seeds evaluated there, the interval; and each seed's
    best and last evaluation."""

    label: str
    counts: Mapping[int, tuple[int, int]]
    best: tuple[float, ...]
    last: tuple[float, ...]

    def share(self, step: int) -> str:
        collapsed, seeds = self.counts[step]
        low, high = wilson_interval(collapsed, seeds)
        return f"{collapsed}/{seeds} ({100 * collapsed / seeds:.0f} %, 95 % CI {100 * low:.0f}–{100 * high:.0f} %)" \
            if seeds else "—"


def collapse_rows(groups: Mapping[str, Sequence[RunRecord]], steps: Sequence[int],
                  threshold: float = COLLAPSE_RETURN, until: int | None = None) -> list[CollapseRow]:
    """Each group's collapsed counts at ``steps`` and its seeds' best and last evaluations up to ``until`` (every
    evaluation when None)."""
    rows = []
    for label, runs in groups.items():
        counts = {}
        for step in steps:
            values = [value for value in (return_at(run, step) for run in runs) if value is not None]
            counts[step] = (sum(value < threshold for value in values), len(values))
        best, last = [], []
        for run in runs:
            kept = [(s, r) for s, r in zip(run.steps, run.returns, strict=True) if until is None or s <= until]
            if kept:
                best.append(max(r for _, r in kept))
                last.append(kept[-1][1])
        rows.append(CollapseRow(label, counts, tuple(best), tuple(last)))
    return rows


def _mean_std(values: Sequence[float]) -> str:
    if not values:
        return "—"
    spread = seed_std(values)
    return f"{np.mean(values):.0f}" if spread is None else f"{np.mean(values):.0f} ± {spread:.0f}"


def collapse_markdown(rows: Sequence[CollapseRow], steps: Sequence[int], threshold: float = COLLAPSE_RETURN) -> str:
    """The rows as a Markdown table (collapsed share at each step, best and last mean ± std with ddof = 1) and
    Fisher's exact test between every pair of rows at each step."""
    header = ["Row", *(f"collapsed at {step:,} (return < {threshold:g})".replace(",", " ") for step in steps),
              "best, mean ± std", "last, mean ± std"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        lines.append("| " + " | ".join([row.label, *(row.share(step) for step in steps), _mean_std(row.best),
                                        _mean_std(row.last)]) + " |")
    lines += ["", "Fisher's exact test (two-sided) between rows, collapsed against not:", ""]
    for index, first in enumerate(rows):
        for second in rows[index + 1:]:
            tests = ", ".join(f"at {step:,}: p = {fisher_exact(first.counts[step], second.counts[step]):.3f}"
                              .replace(",", " ", 1) for step in steps
                              if first.counts[step][1] and second.counts[step][1])
            lines.append(f"- {first.label} vs {second.label}: "
                         + (tests or "no test: one of them has no evaluation at these steps yet"))
    return "\n".join(lines) + "\n"


def plot_diagnostics(groups: Mapping[str, Sequence[RunRecord]], path: str | Path, collapsed_at: int,
                     until: int, threshold: float = COLLAPSE_RETURN) -> Path:
    """A figure of the diagnostics over the first ``until`` steps: one column per diagnostic the runs logged (runs
    older than a diagnostic lack its column), one row per group,
    seeds still collapsed at ``collapsed_at`` in red, the others in blue (one thin line per seed, thick: median)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labelled, drawn = diagnostic_panels(groups, until)
    drawn = drawn or list(DIAGNOSTICS)
    figure, axes = plt.subplots(len(labelled) or 1, len(drawn), figsize=(4 * len(drawn), 3 * max(1, len(labelled))),
                                squeeze=False)
    for row_axes, (label, runs) in zip(axes, labelled.items(), strict=False):
        for axis, name in zip(row_axes, drawn, strict=True):
            for collapsed, colour in ((True, "tab:red"), (False, "tab:blue")):
                chosen = [run for run in runs
                          if ((return_at(run, collapsed_at) or 0.0) < threshold) is collapsed]
                series = [_series(run, name, until) for run in chosen]
                for steps, values in series:
                    axis.plot(steps, values, color=colour, alpha=0.3, linewidth=0.8)
                median = _median_series(series)
                if median is not None:
                    state = "collapsed" if collapsed else "left"
                    axis.plot(*median, color=colour, linewidth=2.2,
                              label=f"{state} at {collapsed_at // 1000}k ({len(chosen)})")
            if not any(_series(run, name, until)[0] for run in runs):
                axis.text(0.5, 0.5, "not logged by these runs", ha="center", va="center", transform=axis.transAxes)
            axis.set_title(f"{label}\n{name}", fontsize=9)
            axis.set_xlabel("environment steps")
            axis.grid(alpha=0.3)
        row_axes[0].legend(fontsize=8)
    figure.tight_layout()
    path = Path(path)
    atomic_write_file(path, lambda temporary: figure.savefig(temporary, dpi=110, format="png"))
    plt.close(figure)
    return path


def diagnostic_panels(groups: Mapping[str, Sequence[RunRecord]],
                      until: int) -> tuple[dict[str, list[RunRecord]], list[str]]:
    """What the figure draws: each group's runs that logged a diagnostic up to ``until`` (groups with none, such as
    runs of the authors' code, left out), and every diagnostic one of them logged, in :data:`DIAGNOSTICS` order."""
    logged = {label: [run for run in runs if any(_series(run, name, until)[0] for name in DIAGNOSTICS)]
              for label, runs in groups.items()}
    logged = {label: runs for label, runs in logged.items() if runs}
    names = [name for name in DIAGNOSTICS
             if any(_series(run, name, until)[0] for runs in logged.values() for run in runs)]
    return logged, names


def _series(run: RunRecord, name: str, until: int) -> tuple[list[int], list[float]]:
    pairs = [(step, value) for step, value in zip(run.steps, run.diagnostics.get(name, ()), strict=False)
             if step <= until and math.isfinite(value)]
    return [step for step, _ in pairs], [value for _, value in pairs]


def _median_series(series: Sequence[tuple[list[int], list[float]]]) -> tuple[list[int], list[float]] | None:
    by_step: dict[int, list[float]] = {}
    for steps, values in series:
        for step, value in zip(steps, values, strict=True):
            by_step.setdefault(step, []).append(value)
    if not by_step:
        return None
    ordered = sorted(by_step)
    return ordered, [float(np.median(by_step[step])) for step in ordered]
