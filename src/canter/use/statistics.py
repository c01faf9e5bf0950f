"""Aggregate scores with 95% stratified-bootstrap confidence intervals, performance profiles and the probability
of improvement, as rliable (Agarwal et al. 2021, "Deep RL at the Edge of the Statistical Precipice") computes them,
to the last bit.

Scores are matrices [runs, tasks] (tasks: envs). The bootstrap resamples runs with replacement within each task
(stratified), `reps` times, and the interval is the percentile interval of the resampled statistic. rliable draws
its resamples from numpy's global generator, so each call seeds that generator and restores its state afterwards:
the same seed gives the same interval, and nothing else that uses the global generator is disturbed.

canter replays those draws rather than have rliable make them, and computes every resample's statistic at once:
rliable scores one resample after another, about 0.1 ms each, and a grid of 100 methods has 600 aggregates, 100
profiles and 4,950 pairs of methods to compare, 2,000 resamples each (a scoreboard took 4 minutes, now seconds).
The resampled statistics are computed along one axis of contiguous rows, so numpy adds, partitions and sorts each
resample's values as it would for that resample alone, and the intervals are rliable's to the last bit
(tests/test_statistics.py).

The statistics of each resample are rliable's definitions written in plain numpy (`interquartile_mean`,
`task_mean`, `task_median`, `optimality_gap`, `improvement_probability`), equal to rliable's own to the last bit.
rliable's versions go through scipy's trim_mean and mannwhitneyu, whose argument handling costs about 0.2 ms a
call.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

CONFIDENCE = 0.95
# Bootstrap resamples of every interval. rliable's own default (50,000) takes minutes for a grid; 2,000 puts the
# 2.5% and 97.5% quantiles near their limit. Over a few runs the resampled estimates take few distinct values, so a
# bound can land on either of two neighbours from one resampling seed to the next.
REPS = 2000
# Fewer runs than this get no interval in what canter prints: a bootstrap over two or three runs only restates
# their spread (with 3 runs the 95% interval of the mean is their min and max), so it reads as a precision the runs
# do not have. The intervals are still computed and kept in the JSON, beside the number of runs.
MIN_RUNS_FOR_INTERVAL = 5


@dataclass(frozen=True)
class Interval:
    """A point estimate and its confidence interval."""

    estimate: float
    low: float
    high: float

    def show(self, digits: int = 1, *, runs: int) -> str:
        """'1,234.5 [1,100.0, 1,300.2]'; the estimate alone from fewer than MIN_RUNS_FOR_INTERVAL runs."""
        if runs < MIN_RUNS_FOR_INTERVAL:
            return f"{self.estimate:,.{digits}f}"
        return f"{self.estimate:,.{digits}f} [{self.low:,.{digits}f}, {self.high:,.{digits}f}]"

    def as_dict(self) -> dict[str, float]:
        return {"estimate": self.estimate, "low": self.low, "high": self.high}


@dataclass(frozen=True)
class Aggregates:
    """IQM, mean, median and optimality gap of a score matrix [runs, tasks], each with its interval. The mean is of
    the per-task means, and so is the median over several tasks (rliable's definitions); over one task the median is
    of its runs. The IQM and the optimality gap pool all runs."""

    runs: int
    tasks: int
    iqm: Interval
    mean: Interval
    median: Interval  # of the per-task means across tasks; of the runs for one task
    optimality_gap: Interval | None  # None without a threshold
    gamma: float | None  # the optimality gap's threshold: the mean shortfall of the scores below it

    def as_dict(self) -> dict[str, Any]:
        return {
            "runs": self.runs,
            "tasks": self.tasks,
            "iqm": self.iqm.as_dict(),
            "mean": self.mean.as_dict(),
            "median": self.median.as_dict(),
            "optimality_gap": self.optimality_gap.as_dict() if self.optimality_gap else None,
            "gamma": self.gamma,
        }


@dataclass(frozen=True)
class Profile:
    """A performance profile: the fraction of runs (over all tasks) whose score exceeds each threshold τ."""

    taus: tuple[float, ...]
    fraction: tuple[float, ...]
    low: tuple[float, ...]
    high: tuple[float, ...]

    def as_dict(self) -> dict[str, list[float]]:
        return {"tau": list(self.taus), "fraction": list(self.fraction), "low": list(self.low), "high": list(self.high)}


@contextlib.contextmanager
def seeded_global_generator(seed: int) -> Iterator[None]:
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(state)


def _matrix(scores: np.ndarray | Sequence[Sequence[float]]) -> np.ndarray:
    matrix = np.asarray(scores, float)
    if matrix.ndim != 2 or matrix.shape[0] < 1 or matrix.shape[1] < 1 or not np.isfinite(matrix).all():
        raise ValueError(f"scores must be a finite matrix [runs, tasks], got shape {matrix.shape}")
    return matrix


def interquartile_mean(scores: np.ndarray) -> float:
    """The mean of the middle half of all scores, pooled over runs and tasks (scipy's trim_mean at 0.25)."""
    flat = np.ravel(scores)
    cut = int(0.25 * flat.size)
    middle = np.partition(flat, (cut, flat.size - cut - 1))[cut : flat.size - cut]
    return float(np.mean(middle))


def task_mean(scores: np.ndarray) -> float:
    """The mean over tasks of each task's mean score."""
    return float(np.mean(np.mean(scores, axis=0)))


def task_median(scores: np.ndarray) -> float:
    """The median over tasks of each task's mean score."""
    return float(np.median(np.mean(scores, axis=0)))


def run_median(scores: np.ndarray) -> float:
    """The median of the runs of one task: rliable's median over tasks would be their mean."""
    return float(np.median(scores))


def optimality_gap(scores: np.ndarray, gamma: float) -> float:
    """How far the scores fall short of `gamma` on average, a score above `gamma` counting as `gamma`."""
    return float(gamma - np.mean(np.minimum(scores, gamma)))


def improvement_probability(x: np.ndarray, y: np.ndarray) -> float:
    """The share of pairs (a run of X, a run of Y) on the same task in which X scores higher, ties counting half,
    averaged over tasks: each task's Mann-Whitney U statistic over the number of pairs."""
    higher = (x[:, None, :] > y[None, :, :]).sum(axis=(0, 1))
    tied = (x[:, None, :] == y[None, :, :]).sum(axis=(0, 1))
    return float(np.mean((higher + 0.5 * tied) / (x.shape[0] * y.shape[0])))


def aggregates(scores: np.ndarray, gamma: float | None = None, reps: int = REPS, seed: int = 0) -> Aggregates:
    """IQM, mean, median and (with `gamma`) optimality gap of `scores` [runs, tasks], with intervals. The median is
    of the per-task means across tasks (rliable's), and of the runs for a single task.

    The intervals are rliable's `get_interval_estimates` to the last bit: its draws are replayed
    (`_resample_indices`) and every resample's statistics are computed at once, in the same arithmetic as the
    functions above apply to one resample (`_resampled_aggregates`)."""
    matrix = _matrix(scores)
    median = run_median if matrix.shape[1] == 1 else task_median
    point = [interquartile_mean(matrix), task_mean(matrix), median(matrix)]
    if gamma is not None:
        point.append(optimality_gap(matrix, gamma))
    with seeded_global_generator(seed):
        indices = _resample_indices(matrix.shape, reps)
    low, high = _percentile_interval(_resampled_aggregates(_resampled(matrix, indices), gamma))
    found = [Interval(p, float(lo), float(hi)) for p, lo, hi in zip(point, low, high)]
    return Aggregates(
        matrix.shape[0],
        matrix.shape[1],
        found[0],
        found[1],
        found[2],
        found[3] if gamma is not None else None,
        gamma,
    )


def _resample_indices(shape: tuple[int, ...], reps: int) -> np.ndarray:
    """[reps, runs, tasks]: the run drawn for each place of each resample of a matrix [runs, tasks], as rliable's
    StratifiedBootstrap draws them from numpy's global generator (one np.random.choice per resample). One call of
    np.random.choice for all resamples takes the same numbers from the generator in the same order."""
    runs, tasks = shape
    return np.random.choice(runs, (reps, runs, tasks))


def _resampled(matrix: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """[reps, runs, tasks]: each resample of `matrix` as rliable indexes it, each run drawn within its own task."""
    return matrix[indices, np.arange(matrix.shape[1])]


def _resampled_aggregates(resampled: np.ndarray, gamma: float | None) -> np.ndarray:
    """[reps, 3 or 4]: IQM, mean, median and optimality gap of each resample [runs, tasks] of `resampled`.

    Each is computed along one axis of contiguous rows, so numpy adds, partitions and sorts every resample's values
    in the order in which the functions above handle a single one, and the sums agree to the last bit."""
    reps, runs, tasks = resampled.shape
    flat = resampled.reshape(reps, runs * tasks)
    cut = int(0.25 * flat.shape[1])
    middle = np.partition(flat, (cut, flat.shape[1] - cut - 1), axis=1)[:, cut : flat.shape[1] - cut]
    task_means = np.mean(resampled, axis=1)  # [reps, tasks], each summed down its runs as for one resample
    median = np.median(flat if tasks == 1 else task_means, axis=1)  # run_median or task_median
    columns = [np.mean(middle, axis=1), np.mean(task_means, axis=1), median]
    if gamma is not None:
        columns.append(gamma - np.mean(np.minimum(flat, gamma), axis=1))
    return np.stack(columns, axis=1)


def _percentile_interval(resampled: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The percentile interval of each column of `resampled` [reps, statistics], as arch computes it for rliable."""
    alpha = (1.0 - CONFIDENCE) / 2
    low, high = np.percentile(resampled, [100 * alpha, 100 * (1.0 - alpha)], axis=0)
    return low, high


def performance_profiles(
    scores: Mapping[str, np.ndarray], taus: Sequence[float], reps: int = REPS, seed: int = 0
) -> dict[str, Profile]:
    """Each method's score distribution (the fraction of its runs, over all tasks, scoring above τ) at `taus`,
    with intervals.

    rliable's `create_performance_profile` to the last bit: it draws every method's resamples in turn from one
    seeding of the global generator, which is replayed here in the same order; a resample's fraction above τ is a
    count of runs over their number, exact whatever the order of the sum."""
    matrices = {name: _matrix(s) for name, s in scores.items()}
    thresholds = np.asarray(taus, float)
    with seeded_global_generator(seed):
        drawn = {name: _resample_indices(m.shape, reps) for name, m in matrices.items()}
    as_tuple = lambda values: tuple(float(v) for v in values)  # noqa: E731
    profiles = {}
    for name, matrix in matrices.items():
        flat = _resampled(matrix, drawn[name]).reshape(reps, matrix.size)
        above = np.stack([np.count_nonzero(flat > tau, axis=1) for tau in thresholds], axis=1) / matrix.size
        low, high = _percentile_interval(above)
        fraction = [np.mean(matrix > tau) for tau in thresholds]
        profiles[name] = Profile(as_tuple(thresholds), as_tuple(fraction), as_tuple(low), as_tuple(high))
    return profiles


def probability_of_improvement(x: np.ndarray, y: np.ndarray, reps: int = REPS, seed: int = 0) -> Interval:
    """P(X > Y): the probability that a run of X scores higher than a run of Y on the same task (ties count half),
    averaged over tasks, with an interval that resamples the runs of X and of Y independently within each task.
    X and Y need the same tasks, in the same order, and may have different numbers of runs."""
    return probabilities_of_improvement([(x, y)], reps, seed)[0]


def probabilities_of_improvement(
    pairs: Sequence[tuple[np.ndarray, np.ndarray]], reps: int = REPS, seed: int = 0
) -> list[Interval]:
    """`probability_of_improvement` of each pair (X, Y), to the last bit, without rliable's loop over resamples.

    rliable's bootstrap draws, for each resample, the runs of X [runs, tasks] and then those of Y from numpy's
    global generator, seeded anew for each pair: the draws depend only on the shapes of X and Y, so pairs of the same
    shapes share them, and are drawn once. A resample's U statistic on a task is then a sum over the runs of X and Y
    of how often each was drawn times whether it wins, which numpy computes for all resamples at once."""
    matrices = [(_matrix(x), _matrix(y)) for x, y in pairs]
    for x, y in matrices:
        if x.shape[1] != y.shape[1]:
            raise ValueError(f"X and Y need the same tasks; got {x.shape[1]} and {y.shape[1]}")
    draws: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]] = {}
    found = []
    for x, y in matrices:
        shape = (x.shape[0], y.shape[0], x.shape[1])
        if shape not in draws:
            draws[shape] = _resample_counts(*shape, reps, seed)
        resampled = _resampled_improvement(x, y, *draws[shape])
        low, high = _percentile_interval(resampled[:, None])
        found.append(Interval(improvement_probability(x, y), float(low[0]), float(high[0])))
    return found


def _resample_counts(runs_x: int, runs_y: int, tasks: int, reps: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """How many times each run of X and of Y is drawn on each task in each resample, [reps, tasks, runs] each: the
    draws of rliable's StratifiedIndependentBootstrap (one np.random.choice of run indices [runs, tasks] for X, then
    one for Y, per resample), made in the same order from the same seed."""
    with seeded_global_generator(seed):
        drawn = [
            (np.random.choice(runs_x, (runs_x, tasks)), np.random.choice(runs_y, (runs_y, tasks))) for _ in range(reps)
        ]
    return _counts(np.stack([d[0] for d in drawn]), runs_x), _counts(np.stack([d[1] for d in drawn]), runs_y)


def _counts(indices: np.ndarray, runs: int) -> np.ndarray:
    """[reps, tasks, runs]: how often each run index occurs in each resample's [runs, tasks] indices."""
    reps, _, tasks = indices.shape
    cell = (np.arange(reps)[:, None, None] * tasks + np.arange(tasks)[None, None, :]) * runs
    return np.bincount((cell + indices).ravel(), minlength=reps * tasks * runs).reshape(reps, tasks, runs).astype(float)


def _resampled_improvement(x: np.ndarray, y: np.ndarray, counts_x: np.ndarray, counts_y: np.ndarray) -> np.ndarray:
    """`improvement_probability` of each resample [reps], from the runs' draw counts [reps, tasks, runs]."""
    # Twice a task's U statistic over the runs as drawn: each pair of runs (k of X, l of Y) adds 2 when X is higher
    # and 1 on a tie, times how often both were drawn. The sums are small integers, exact in float64, and half of
    # them is exactly improvement_probability's higher + 0.5 * tied, so what follows is its arithmetic.
    wins = 2 * (x[:, None, :] > y[None, :, :]) + (x[:, None, :] == y[None, :, :])
    weighted = np.matmul(counts_x.transpose(1, 0, 2), wins.transpose(2, 0, 1).astype(float))  # [tasks, reps, runs_y]
    # Contiguous rows, so that np.mean sums each resample's tasks as it sums improvement_probability's (pairwise
    # from 8 tasks on); down a column it would add them one by one, and differ in the last bit.
    doubled = np.ascontiguousarray((weighted * counts_y.transpose(1, 0, 2)).sum(axis=2).T)  # [reps, tasks]
    return np.mean(doubled * 0.5 / (x.shape[0] * y.shape[0]), axis=1)


def normalized(raw: np.ndarray | Sequence[float] | float, random: float, reference: float) -> np.ndarray:
    """(raw - random) / (reference - random): 0 is the random policy's return, 1 the reference's."""
    return (np.asarray(raw, float) - random) / (reference - random)
