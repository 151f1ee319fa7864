"""Telling the rows of a reward table apart: interval estimates over seeds (rliable).

A table's cell (:mod:`.reward_tables`) is a mean ± std over seeds; whether two rows differ by more than their seeds
do is a question for an interval. Per table, with the library of Agarwal et al., *Deep Reinforcement Learning at the
Edge of the Statistical Precipice* (NeurIPS 2021), ``rliable``:

* per row, the **IQM** (interquartile mean over runs × tasks, ``rliable.metrics.aggregate_iqm``) and the **mean**
  (``rliable.metrics.aggregate_mean``) of its normalised scores, each task's scores divided by

  - our DAN's mean on that task (the table's APR reference, all its seeds): the ratio the paper's APR averages,
    ``APR = 1/N_T Σ_task AN_task / DAN_task`` (Section V-A); for the spiking rows (DAN's own would be 1 by
    construction);
  - the paper's published DAN mean on that task (Table ``perf``), a scale that needs no DAN runs of ours;

* the **probability of improvement** of one row X over another Y (``rliable.metrics.probability_of_improvement``):
  per task the chance that a run of X scores above a run of Y (ties count ½; the Mann–Whitney U over n_X n_Y
  pairs), averaged over tasks. A positive per-task scale does not change it, so it is computed on raw scores; 0.5 is
  even. For each spiking row against DAN, and for ILC-SAN (row ``ilc-san-pop-det``, or ``ilc-san`` in our grids)
  against every other spiking row with runs;
* the paper's **APR** of each spiking row on the same runs: 100 × mean over tasks of mean(row's scores) / mean(DAN's
  scores); 100 % is even.

Each comparison also gives its statistic per task (:attr:`Comparison.per_task`, the values its whole averages), so
that a reader sees which tasks decide it: P(improvement) weighs every margin alike, so a task where both rows sit at
the task's ceiling and one is higher by a few points counts as a full win of that row.

**Intervals**: percentile intervals of rliable's stratified bootstrap (``rliable.library.get_interval_estimates``):
each task's runs are resampled with replacement within the task (a pair's two rows independently),
:attr:`Bootstrap.reps` times. rliable draws from NumPy's global random state (not from its ``random_state``
argument), so each statistic seeds that state with :attr:`Bootstrap.seed` and restores it after: a report is
reproducible, and one statistic's interval does not depend on which others were computed. With 2 000 replicates
an interval end moves by at most about 0.01 from one bootstrap seed to another (measured over 5 seeds on 3 seeds × 8
tasks: 0.01 for IQM and mean, one step of 1/72 for P(improvement), 1.5 points of APR; at 10 000 replicates, five
times slower: 0.005, the same step, 0.5 points).
A comparison is *better* when its interval lies entirely above even, *worse* when entirely below, else the rows
*cannot be told apart on these seeds*.

**Which runs** (:func:`select_seeds`): a score matrix is runs × tasks, the same number of runs on every task, while
cells have different seed counts (Hopper 10, Humanoid 1, a row without some tasks). For a set of rows (one row for
its IQM and mean, two for a comparison), each task offers the seeds all of them ran, so that runs of the same seed
pair across rows; tasks without a normaliser, or without runs of one of the rows, are left out. Every task with at
least 2 such seeds is kept (one run per task has no spread to resample; a statistic over tasks, as the paper's APR,
should see as many tasks as it can), and k is the fewest common seeds among them: each kept task contributes its
first k common seeds. The tasks, k, the seeds and the tasks left out (and why) are part of every sentence; with
fewer than 2 common seeds on every task, the sentence says so instead of a number.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from ..paper.published import APR_REFERENCE, published_cell

if TYPE_CHECKING:  # at run time only their instances are needed: the CLI imports this module's defaults, not torch
    from .collect import RunRecord
    from .reward_tables import RowResult, TableResult

BOOTSTRAP_REPS = 2_000
"""Default bootstrap replicates (rliable's own default, 50 000, takes minutes for a full table)."""
BOOTSTRAP_SEED = 0
"""Default seed of the bootstrap's draws."""
MIN_SEEDS = 2
"""Fewest runs per task a matrix may have: one run per task has no spread to resample."""
ILC_SAN_ROWS = ("ilc-san-pop-det", "ilc-san")
"""Row keys of ILC-SAN, compared with every other row: Table perf's E_pop_det row, our grids' ILC-SAN row."""
DAN = "DAN"
OUR_DAN = "our DAN mean"
PAPER_DAN = "the paper's DAN mean"
IMPROVEMENT = "probability_of_improvement"
APR = "apr"
EVEN: dict[str, float] = {IMPROVEMENT: 0.5, APR: 100.0}
"""The value of each comparison (:data:`IMPROVEMENT`, :data:`APR`) at which the two rows are even."""

Scores = Mapping[str, Mapping[int, float]]
"""A row's scores: task → seed → the seed run's max average reward."""


@dataclass(frozen=True)
class Bootstrap:
    """Settings of the stratified bootstrap: replicates, the seed of its draws, the interval's coverage."""

    reps: int = BOOTSTRAP_REPS
    seed: int = BOOTSTRAP_SEED
    confidence: float = 0.95

    @property
    def text(self) -> str:
        """``95 % intervals of a stratified bootstrap (rliable), 2000 replicates, seed 0``."""
        return (f"{self.confidence * 100:g} % intervals of a stratified bootstrap (rliable), "
                f"{self.reps} replicates, seed {self.seed}")


DEFAULT_BOOTSTRAP = Bootstrap()


@dataclass(frozen=True)
class Interval:
    """A point estimate and its bootstrap interval."""

    estimate: float
    low: float
    high: float
    confidence: float = 0.95

    def verdict(self, even: float) -> str:
        """*better* when the interval lies entirely above ``even``, *worse* when entirely below."""
        if self.low > even:
            return "better"
        if self.high < even:
            return "worse"
        return "cannot tell apart on these seeds"

    def text(self, places: int, unit: str = "") -> str:
        """``0.62, 95 % CI 0.41–0.80``."""
        return (f"{self.estimate:.{places}f}{unit}, {self.confidence * 100:g} % CI "
                f"{self.low:.{places}f}–{self.high:.{places}f}{unit}")


@dataclass(frozen=True)
class Selection:
    """The runs a statistic was computed on: ``tasks``, each with its ``seeds`` (k of them), and the tasks left out
    with the reason."""

    tasks: tuple[str, ...]
    seeds: tuple[tuple[int, ...], ...]
    left_out: tuple[tuple[str, str], ...] = ()
    noun: str = "common seed"
    """What a task offers: the seeds all compared rows ran (``common seed``), or one row's (``seed``)."""

    @property
    def k(self) -> int:
        """Runs per task (0: no task has enough)."""
        return len(self.seeds[0]) if self.seeds else 0

    @property
    def left_out_text(self) -> str:
        """The tasks left out, grouped by reason: ``Humanoid, HumanoidStandup (1 common seed); BipedalWalker (no runs
        of DAN)``."""
        reasons = dict.fromkeys(reason for _, reason in self.left_out)
        return "; ".join(", ".join(task for task, why in self.left_out if why == reason) + f" ({reason})"
                         for reason in reasons)

    @property
    def text(self) -> str:
        """``6 tasks × 3 seeds (Ant, …, Walker2d; seeds 0, 1, 2; left out: Humanoid (1 common seed))``."""
        same = len(set(self.seeds)) == 1
        seeds = f"seeds {', '.join(map(str, self.seeds[0]))}" if same else f"the first {self.k} {self.noun}s of each"
        left = f"; left out: {self.left_out_text}" if self.left_out else ""
        return (f"{_count(len(self.tasks), 'task')} × {_count(self.k, 'seed')} "
                f"({', '.join(self.tasks)}; {seeds}{left})")

    @property
    def too_few(self) -> str:
        """Why nothing was computed: ``fewer than 2 common seeds on every task (Hopper (1 common seed), …)``."""
        return f"fewer than {MIN_SEEDS} {self.noun}s on every task" + (f" ({self.left_out_text})"
                                                                         if self.left_out else "")


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'s' * (n != 1)}"


def select_seeds(candidates: Mapping[str, Sequence[int]], noun: str = "common seed") -> Selection:
    """The rectangular selection of the module docstring's rule: ``candidates`` maps each task (in table order) to
    the seeds all compared rows ran there; every task with ≥ :data:`MIN_SEEDS` of them is kept, k is the fewest among
    those, and each kept task keeps its first k seeds (in increasing order); the others are left out with their
    count. No task with ≥ 2 seeds: an empty selection (k = 0) with every task left out."""
    counts = {task: len(seeds) for task, seeds in candidates.items()}
    kept = [task for task in candidates if counts[task] >= MIN_SEEDS]
    k = min((counts[task] for task in kept), default=0)
    return Selection(tuple(kept), tuple(tuple(sorted(candidates[task])[:k]) for task in kept),
                     tuple((task, _count(counts[task], noun) if counts[task] else f"no {noun}")
                           for task in candidates if task not in kept), noun)


def common_selection(rows: Sequence[tuple[str, Scores]], tasks: Sequence[str],
                     excluded: Mapping[str, str] | None = None) -> Selection:
    """:func:`select_seeds` over the seeds that every one of ``rows`` (label, scores) ran on each of ``tasks``;
    ``excluded`` tasks (and tasks where a row has no runs) are left out with their reason, in table order."""
    excluded = excluded or {}
    reasons: dict[str, str] = {}
    candidates: dict[str, list[int]] = {}
    for task in tasks:
        without = [label for label, scores in rows if not scores.get(task)]
        if task in excluded:
            reasons[task] = excluded[task]
        elif without:
            reasons[task] = f"no runs of {without[0]}"
        else:
            candidates[task] = sorted(set.intersection(*(set(scores[task]) for _, scores in rows)))
    selection = select_seeds(candidates, "common seed" if len(rows) > 1 else "seed")
    reasons |= dict(selection.left_out)
    return replace(selection, left_out=tuple((task, reasons[task]) for task in tasks if task in reasons))


def score_matrix(scores: Scores, selection: Selection) -> np.ndarray:
    """``scores`` as rliable's (runs × tasks) matrix: column j the selected seeds of task j, in seed order."""
    return np.array([[scores[task][seeds[run]] for task, seeds in zip(selection.tasks, selection.seeds, strict=True)]
                     for run in range(selection.k)], dtype=float)


def task_improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per task (column), the chance that a run of ``x`` scores above a run of ``y``: Σ over run pairs of [x > y]
    + ½ [x = y], over n_x n_y (the Mann–Whitney U statistic over n_x n_y), by broadcasting."""
    above = (x[:, None, :] > y[None, :, :]).sum(axis=(0, 1))
    ties = (x[:, None, :] == y[None, :, :]).sum(axis=(0, 1))
    return (above + 0.5 * ties) / (x.shape[0] * y.shape[0])


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``rliable.metrics.probability_of_improvement(x, y)`` as a 1-element array: :func:`task_improvement` averaged
    over tasks (the same number as one ``scipy.stats.mannwhitneyu`` per task, 100× faster, which a bootstrap of
    thousands of replicates needs)."""
    return np.array([np.mean(task_improvement(x, y))])


def task_apr(x: np.ndarray, dan: np.ndarray) -> np.ndarray:
    """Per task (column), 100 × mean(x) / mean(DAN): the ratios the APR averages."""
    return 100.0 * x.mean(axis=0) / dan.mean(axis=0)


def apr(x: np.ndarray, dan: np.ndarray) -> np.ndarray:
    """The paper's APR in percent (Section V-A): 100 × mean over tasks of mean(x) / mean(DAN), as a 1-element array."""
    return np.array([np.mean(task_apr(x, dan))])


def iqm_and_mean(scores: np.ndarray) -> np.ndarray:
    """``rliable.metrics.aggregate_iqm`` and ``aggregate_mean`` of a (runs × tasks) matrix of normalised scores. The
    IQM is rliable's, ``scipy.stats.trim_mean(scores, 0.25, axis=None)``: the mean of all scores once the lowest and
    the highest ⌊n/4⌋ of the n are dropped, here by one sort (scipy's checks cost 30× more per call; a table's
    bootstrap calls it tens of thousands of times)."""
    ordered = np.sort(scores, axis=None)
    cut = int(0.25 * ordered.size)
    return np.array([ordered[cut:ordered.size - cut].mean(), scores.mean(axis=0).mean()])


@contextmanager
def _numpy_seeded(seed: int) -> Iterator[None]:
    """NumPy's global random state seeded for the duration (rliable resamples with ``np.random.choice``)."""
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(state)


def bootstrap_intervals(scores: np.ndarray | tuple[np.ndarray, ...], statistic: Callable[..., np.ndarray],
                        bootstrap: Bootstrap) -> tuple[Interval, ...]:
    """``statistic`` of ``scores`` (one runs × tasks matrix, or a tuple of them, resampled independently) with its
    stratified bootstrap interval, one :class:`Interval` per element of the statistic."""
    from rliable import library

    with _numpy_seeded(bootstrap.seed):
        points, intervals = library.get_interval_estimates({"x": scores}, statistic, reps=bootstrap.reps,
                                                           confidence_interval_size=bootstrap.confidence)
    point, ends = np.atleast_1d(points["x"]), np.asarray(intervals["x"]).reshape(2, -1)
    return tuple(Interval(float(value), float(low), float(high), bootstrap.confidence)
                 for value, low, high in zip(point, ends[0], ends[1], strict=True))


@dataclass(frozen=True)
class Aggregate:
    """One row's IQM and mean of scores divided by a normaliser (:data:`OUR_DAN` or :data:`PAPER_DAN`)."""

    row: str
    normaliser: str
    selection: Selection
    iqm: Interval | None = None
    mean: Interval | None = None

    def sentence(self) -> str:
        """``ILC-SAN, score / our DAN mean: IQM 1.08, 95 % CI 0.95–1.20; mean 1.12, 95 % CI 0.99–1.25 on …``."""
        head = f"{self.row}, score / {self.normaliser}"
        if self.iqm is None or self.mean is None:
            return f"{head}: not computed: {self.selection.too_few}"
        return f"{head}: IQM {self.iqm.text(2)}; mean {self.mean.text(2)} on {self.selection.text}"


@dataclass(frozen=True)
class Comparison:
    """One row against another: ``statistic`` :data:`IMPROVEMENT` or :data:`APR` with its interval."""

    statistic: str
    row: str
    against: str
    selection: Selection
    interval: Interval | None = None
    per_task: tuple[float, ...] = ()
    """The statistic on each of :attr:`selection`'s tasks, in its order, on the selected runs (no bootstrap): a pair's
    P(improvement) per task, or mean(row) / mean(DAN) in percent; the whole statistic is their mean."""

    @property
    def verdict(self) -> str | None:
        """better / worse / cannot tell apart on these seeds (None when not computed)."""
        return None if self.interval is None else self.interval.verdict(EVEN[self.statistic])

    def sentence(self) -> str:
        """``ILC-SAN over DAN: P(improvement) = 0.62, 95 % CI 0.41–0.80 on 6 tasks × 3 seeds (…): cannot tell apart
        on these seeds``."""
        if self.statistic == IMPROVEMENT:
            head, places, unit = f"{self.row} over {self.against}: P(improvement)", 2, ""
        else:
            head, places, unit = f"{self.row} against {self.against}: APR", 1, " %"
        if self.interval is None:
            return f"{head}: not computed: {self.selection.too_few}"
        caveat = (f" (every pair of runs agreed, which leaves the bootstrap no other answer; with "
                  f"{_count(self.selection.k, 'seed')} per task that is not certainty)" if self.unanimous else "")
        return (f"{head} = {self.interval.text(places, unit)} on {self.selection.text}: {self.verdict}{caveat}; "
                f"per task: {self.per_task_text(places, unit)}")

    def per_task_text(self, places: int, unit: str = "") -> str:
        """``Ant 0.78, Hopper 0.67`` (with ``unit`` after each value): :attr:`per_task` beside its tasks."""
        return ", ".join(f"{task} {value:.{places}f}{unit}"
                         for task, value in zip(self.selection.tasks, self.per_task, strict=True))

    @property
    def unanimous(self) -> bool:
        """True for a P(improvement) of exactly 0 or 1: every run of one row above every run of the other on every
        task, so every bootstrap resample gives the same value and the interval has no width, however few the
        seeds."""
        return self.statistic == IMPROVEMENT and self.interval is not None and self.interval.estimate in (0.0, 1.0)


@dataclass(frozen=True)
class TableComparison:
    """What the bootstrap says about one table's rows: aggregates per row, comparisons between rows, and one-line
    notes where a statistic lacks what it needs (no DAN runs, no row to compare with)."""

    table: str
    aggregates: tuple[Aggregate, ...]
    comparisons: tuple[Comparison, ...]
    notes: tuple[str, ...]
    bootstrap: Bootstrap
    rows: tuple[str, ...] = ()
    """The table's row labels in its order (which gives each row its colour in every figure)."""

    def sentences(self, escape: Callable[[str], str] = str) -> list[str]:
        """Every statistic and note as a plain sentence, aggregates first; ``escape`` for the output's format."""
        return [escape(sentence) for sentence in
                (*(item.sentence() for item in (*self.aggregates, *self.comparisons)), *self.notes)]


def seed_scores(runs: Sequence[RunRecord]) -> dict[int, float]:
    """Seed → max average reward; a seed found twice counts once (its first run)."""
    scores: dict[int, float] = {}
    for run in runs:
        scores.setdefault(run.seed, run.best_return)
    return scores


def row_scores(row: RowResult) -> dict[str, dict[int, float]]:
    """A row's :data:`Scores`, over the tasks where it has runs."""
    return {cell.task: seed_scores(cell.runs) for cell in row.cells if cell.runs}


@dataclass(frozen=True)
class Normaliser:
    """What scores are divided by: a positive mean per task, and why the other tasks have none (a ratio to a
    negative mean would reverse the order of rows)."""

    name: str
    means: Mapping[str, float]
    excluded: Mapping[str, str]

    @classmethod
    def of(cls, name: str, means: Mapping[str, float], tasks: Sequence[str], absent: str) -> Normaliser:
        excluded = {task: absent if task not in means else "DAN mean ≤ 0"
                    for task in tasks if means.get(task, 0.0) <= 0}
        return cls(name, {task: mean for task, mean in means.items() if mean > 0}, excluded)


def normalisers(result: TableResult) -> tuple[Normaliser, Normaliser]:
    """Our DAN's mean per task (the table's APR reference, every seed) and the paper's published DAN mean."""
    from .reward_tables import dan_means

    ours = dan_means(result.dan)
    paper = {task: stat.mean for task in result.tasks if (stat := published_cell(*APR_REFERENCE, task))}
    return (Normaliser.of(OUR_DAN, ours, result.tasks, f"no runs of {DAN}"),
            Normaliser.of(PAPER_DAN, paper, result.tasks, "no published DAN value"))


def aggregate(label: str, scores: Scores, tasks: Sequence[str], normaliser: Normaliser,
              bootstrap: Bootstrap) -> Aggregate:
    """A row's IQM and mean of its scores divided by ``normaliser``'s means, on its own seeds."""
    selection = common_selection([(label, scores)], tasks, normaliser.excluded)
    if not selection.k:
        return Aggregate(label, normaliser.name, selection)
    divisors = np.array([normaliser.means[task] for task in selection.tasks])
    iqm, mean = bootstrap_intervals(score_matrix(scores, selection) / divisors, iqm_and_mean, bootstrap)
    return Aggregate(label, normaliser.name, selection, iqm, mean)


def compare(statistic: str, row: tuple[str, Scores], other: tuple[str, Scores], tasks: Sequence[str],
            bootstrap: Bootstrap, excluded: Mapping[str, str] | None = None) -> Comparison:
    """``statistic`` (:data:`IMPROVEMENT` or :data:`APR`) of ``row`` against ``other`` (label, scores) on their common
    seeds; the two matrices are resampled independently."""
    selection = common_selection([row, other], tasks, excluded)
    if not selection.k:
        return Comparison(statistic, row[0], other[0], selection)
    pair = (score_matrix(row[1], selection), score_matrix(other[1], selection))
    function, per_task = ((probability_of_improvement, task_improvement) if statistic == IMPROVEMENT
                          else (apr, task_apr))
    (interval,) = bootstrap_intervals(pair, function, bootstrap)
    return Comparison(statistic, row[0], other[0], selection, interval, tuple(map(float, per_task(*pair))))


def compare_table(result: TableResult, bootstrap: Bootstrap = DEFAULT_BOOTSTRAP) -> TableComparison:
    """The statistics of the module docstring for one table: each row with runs normalised both ways, each spiking
    row against DAN (the table's APR reference) by P(improvement) and APR, and ILC-SAN against every other spiking
    row by P(improvement)."""
    name = result.name or result.caption
    rows = [row for row in result.rows if any(cell.runs for cell in row.cells)]
    if not rows:
        return TableComparison(name, (), (), (), bootstrap)
    dan_rows = {row.label for row in rows if all(run.is_dan for cell in row.cells for run in cell.runs)}
    scored = [(row.label, row_scores(row)) for row in rows]
    spiking = [(label, scores) for label, scores in scored if label not in dan_rows]
    ours, paper = normalisers(result)
    aggregates = tuple(aggregate(label, scores, result.tasks, normaliser, bootstrap)
                       for label, scores in scored for normaliser in (ours, paper)
                       if normaliser.means and not (normaliser is ours and label in dan_rows))
    dan = (DAN, {task: seed_scores(runs) for task, runs in result.dan.items()})
    comparisons = [comparison for row in spiking if dan[1]
                   for comparison in (compare(IMPROVEMENT, row, dan, result.tasks, bootstrap),
                                      compare(APR, row, dan, result.tasks, bootstrap, ours.excluded))]
    ilc_san = next((row.label for row in result.rows if row.key in ILC_SAN_ROWS), None)
    others = [item for item in spiking if item[0] != ilc_san]
    ilc_san_scores = next((item for item in spiking if item[0] == ilc_san), None)
    if ilc_san_scores is not None:
        comparisons += [compare(IMPROVEMENT, ilc_san_scores, other, result.tasks, bootstrap) for other in others]
    notes = _notes(bool(dan[1]), bool(paper.means), ilc_san, ilc_san_scores is not None, bool(others))
    return TableComparison(name, aggregates, tuple(comparisons), notes, bootstrap,
                           tuple(row.label for row in result.rows))


def _notes(dan: bool, published: bool, ilc_san: str | None, ilc_san_ran: bool, others: bool) -> tuple[str, ...]:
    """One line per statistic that lacks what it needs, for a table with runs."""
    notes = []
    if not dan:
        notes.append(f"No DAN runs: score / {OUR_DAN}, P(improvement) over DAN and the APR's interval not computed.")
    if not published:
        notes.append(f"The paper has no DAN value for these tasks: score / {PAPER_DAN} not computed.")
    if ilc_san is not None and not ilc_san_ran and others:
        notes.append(f"{ilc_san} has no runs: not compared with the other rows.")
    elif ilc_san_ran and not others:
        notes.append(f"No spiking row besides {ilc_san} has runs to compare it with.")
    return tuple(notes)
