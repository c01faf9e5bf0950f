"""The curve of one metrics.csv column for a group of runs: each run smoothed, the runs aligned on one grid, their
mean and a band around it.

The numerics are pure functions over numpy arrays, each tested against a plain reference:

- `moving_average(y, window)`: trailing window over a run's own logged rows (row i averages rows i-W+1..i that
  are not NaN; the first rows average what exists so far), applied per run before anything else, as in report 002
  ("values reported every 2048 steps and smoothed with a window of 50").
- `common_grid` / `interpolate`: runs of one group log at different steps (autoreset steps are not counted, so
  seeds drift apart; wall time starts after a compile of varying length), so each run is linearly interpolated
  onto one evenly spaced grid over the union of their x ranges (as fine as the finest run logs) before
  averaging. A run's range and spacing are those of its rows that hold a value: an evaluation column's are its
  evaluations. A run counts inside its own range, and up to one of its own logging intervals beyond either end,
  where it holds its first or last value: seeds of one budget stop up to an iteration apart, and without that
  the last grid points would average only the seed that logged last, drawing a spike. Further out a run does
  not count (no extrapolation), so where only some runs reach, the mean and band are over those runs.
- the band around a group's mean: with fewer than 5 runs, `range_band(samples)`, the range (min to max) of the
  runs, since a bootstrap over 2-4 runs is little more than that range and covers far less than it claims; with 5 or
  more, `bootstrap_band(samples)`, a 95% percentile bootstrap confidence band of the mean, resampling runs with
  replacement from a seeded generator.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from canter.errors import CanterError
from canter.use.experiments import Experiment
from canter.use.statistics import MIN_RUNS_FOR_INTERVAL

# Evaluations during training (`run.eval_every`) are drawn unsmoothed: each point already averages its episodes,
# and they lie many logged rows apart.
EVAL_PREFIX = "eval/"
# The x axes of --x: the metrics.csv column a curve is drawn against, and its axis label.
X_AXES = {"steps": ("global_step", "environment steps"), "wall": ("wall_time", "wall time (s)")}
CONFIDENCE = 0.95
BOOTSTRAP_SAMPLES = 2000
# Band kinds (`Band.kind`): what a group's number of runs earns it (`band_kind`).
RANGE, BOOTSTRAP, SINGLE = "range", "bootstrap", "single"


@dataclass(frozen=True)
class Band:
    x: np.ndarray
    mean: np.ndarray
    low: np.ndarray
    high: np.ndarray
    runs: int
    kind: str  # RANGE, BOOTSTRAP or SINGLE


def trailing_sums(values: np.ndarray, window: int) -> np.ndarray:
    """Row i sums values[i-window+1..i] (those that exist). Each window is one block's suffix plus the next block's
    prefix, with blocks of `window` rows (van Herk, Gil-Werman), so the rounding of a huge value stays in the windows
    that hold it: differences of one running total would lose every later window's small values to it."""
    count = len(values)
    padded = np.concatenate([np.zeros(window - 1), values, np.zeros(-(count + window - 1) % window)])
    blocks = padded.reshape(-1, window)
    prefix = np.cumsum(blocks, axis=1).ravel()
    suffix = np.cumsum(blocks[:, ::-1], axis=1)[:, ::-1].ravel()
    starts = np.arange(count)  # in the padded rows, row i's window starts at i and ends at i + window - 1
    ends = starts + window - 1
    return np.where(starts % window == 0, prefix[ends], suffix[starts] + prefix[ends])


def moving_average(y: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average over the last `window` rows, ignoring NaNs (NaN only if all rows in it are NaN).
    `window=1` returns the input."""
    if window < 1:
        raise CanterError(f"--smooth must be >= 1 rows, got {window}")
    y = np.asarray(y, float)
    window = min(window, max(len(y), 1))  # a longer window is the whole series, and must not size an array
    valid = ~np.isnan(y)

    def in_window(values: np.ndarray) -> np.ndarray:
        return trailing_sums(values, window)

    # Infinite rows (a diverged or damaged run) are counted apart: summed in, they would make every later window
    # inf - inf, and a window holding one is what a plain mean of it gives (inf, -inf, or NaN for both).
    finite = np.isfinite(y)
    window_sums = in_window(np.where(finite, y, 0.0))
    window_counts = in_window(valid.astype(float))
    above, below = in_window((y == np.inf).astype(float)), in_window((y == -np.inf).astype(float))
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(window_counts > 0, window_sums / np.maximum(window_counts, 1), np.nan)
    mean = np.where(above > 0, np.inf, np.where(below > 0, -np.inf, mean))
    return np.where((above > 0) & (below > 0), np.nan, mean)


def logging_interval(x: np.ndarray) -> float:
    """The median spacing of a run's logged x values (0 with fewer than two)."""
    x = np.sort(np.asarray(x, float)[~np.isnan(x)])
    return float(np.median(np.diff(x))) if len(x) > 1 else 0.0


MAX_GRID_POINTS = 4000


def common_grid(xs: Sequence[np.ndarray], points: int | None = None) -> np.ndarray:
    """Evenly spaced x values from the earliest start to the latest end of the runs. Unless `points` is given, the
    spacing is the finest of the runs' median row spacings (so runs whose ranges barely overlap, as wall times can,
    keep their resolution), with at least as many points as the longest run has rows and at most MAX_GRID_POINTS."""
    xs = [np.asarray(x, float)[~np.isnan(x)] for x in xs]
    lo = min(x.min() for x in xs)
    hi = max(x.max() for x in xs)
    if hi <= lo:
        return np.array([lo])
    if points is None:
        spacings = [logging_interval(x) for x in xs]
        finest = min([d for d in spacings if d > 0], default=hi - lo)
        points = min(max(math.ceil((hi - lo) / finest) + 1, max(len(x) for x in xs)), MAX_GRID_POINTS)
    return np.linspace(lo, hi, max(points, 2))


def interpolate(x: np.ndarray, y: np.ndarray, grid: np.ndarray, hold: float = 0.0) -> np.ndarray:
    """Linear interpolation of y(x) onto grid, skipping NaN rows. Within `hold` beyond either end of the x range
    the run covers, the end value is held; further out NaN (no extrapolation). NaN everywhere if the run has no
    values."""
    keep = ~(np.isnan(x) | np.isnan(y))
    if not keep.any():
        return np.full(len(grid), np.nan)
    x, y = x[keep], y[keep]
    inside = (grid >= x.min() - hold) & (grid <= x.max() + hold)
    return np.where(inside, np.interp(grid, x, y), np.nan)


def range_band(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, minimum and maximum over runs (rows of `samples` [runs, points]) at each point, ignoring NaNs."""
    samples = np.asarray(samples, float)
    with warnings.catch_warnings():
        # Points where every run is NaN are expected (no episode finished yet there).
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(samples, axis=0), np.nanmin(samples, axis=0), np.nanmax(samples, axis=0)


RESAMPLE_SLICE_BYTES = 64 << 20


def bootstrap_band(
    samples: np.ndarray, confidence: float = CONFIDENCE, resamples: int = BOOTSTRAP_SAMPLES, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean over runs (rows of `samples` [runs, points]) and a percentile bootstrap band: draw `resamples` sets
    of runs with replacement (index matrix [resamples, runs] from `np.random.default_rng(seed)`), average each
    set, and take the (1 ± confidence)/2 quantiles of those averages at each point. NaNs are ignored."""
    samples = np.asarray(samples, float)
    n = samples.shape[0]
    with warnings.catch_warnings():
        # Points where every run is NaN are expected (no episode finished yet there).
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(samples, axis=0)
        if n == 1:
            return mean, mean.copy(), mean.copy()
        index = np.random.default_rng(seed).integers(0, n, size=(resamples, n))
        # The resampled sets [resamples, runs, points] a slice at a time: whole, 200 seeds on a 4,000-point grid
        # would take 12 GiB.
        per_slice = max(1, RESAMPLE_SLICE_BYTES // (8 * samples.size))
        means = np.concatenate(
            [np.nanmean(samples[index[i : i + per_slice]], axis=1) for i in range(0, resamples, per_slice)]
        )  # [resamples, points]
        tail = (1.0 - confidence) / 2.0
        low, high = np.nanquantile(means, [tail, 1.0 - tail], axis=0)
    return mean, low, high


def experiment_band(
    group: Experiment, column: str, x_axis: str = "steps", smooth: int = 1, seed: int = 0
) -> Band | None:
    """The curve of one column for one group: per-run smoothing, interpolation onto a common grid, then the mean
    over runs and its band: the range of the runs below MIN_RUNS_FOR_INTERVAL runs, a bootstrap CI from there on. None
    when no run of the group logged the column."""
    x_column = X_AXES[x_axis][0]
    runs = [
        r for r in group.runs if column in r.columns and x_column in r.columns and not np.isnan(r.columns[column]).all()
    ]
    if not runs:
        return None
    window = 1 if column.startswith(EVAL_PREFIX) else smooth
    # Each run's curve is its rows that hold a value: an evaluation column is empty on most rows, and the spacing
    # of every row would let the hold draw a run's first evaluation a metrics row before it happened.
    xs, ys = [], []
    for r in runs:
        x, y = r.columns[x_column], moving_average(r.columns[column], window)
        keep = ~(np.isnan(x) | np.isnan(y))
        if keep.any():
            xs.append(x[keep])
            ys.append(y[keep])
    if not xs:
        return None
    if len(xs) == 1:
        return Band(xs[0], ys[0], ys[0].copy(), ys[0].copy(), 1, SINGLE)
    grid = common_grid(xs)
    samples = np.stack([interpolate(x, y, grid, logging_interval(x)) for x, y in zip(xs, ys)])
    if len(xs) < MIN_RUNS_FOR_INTERVAL:
        return Band(grid, *range_band(samples), len(xs), RANGE)
    mean, low, high = bootstrap_band(samples, seed=seed)
    return Band(grid, mean, low, high, len(xs), BOOTSTRAP)


def band_kind(group: Experiment) -> str:
    """The band a group's curves get from its number of runs (a panel where fewer of them logged may get less)."""
    return SINGLE if len(group.runs) == 1 else RANGE if len(group.runs) < MIN_RUNS_FOR_INTERVAL else BOOTSTRAP
