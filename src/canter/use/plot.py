"""Learning curves of run folders: read metrics.csv, group seeds, smooth, align, bootstrap, draw.

The numerics are pure functions over numpy arrays, each tested against a plain reference:

- `moving_average(y, window)`: trailing window over a run's own logged rows (row i averages rows i-W+1..i that
  are not NaN; the first rows average what exists so far), applied per run before anything else, as in report 002
  ("values reported every 2048 steps and smoothed with a window of 50").
- `common_grid` / `interpolate`: runs of one group log at different steps (autoreset steps are not counted, so
  seeds drift apart; wall time starts after a compile of varying length), so each run is linearly interpolated
  onto one evenly spaced grid over the union of their x ranges (as fine as the finest run logs) before
  averaging. A run counts inside its own range, and up to one of its own logging intervals beyond either end,
  where it holds its first or last value: seeds of one budget stop up to an iteration apart, and without that
  the last grid points would average only the seed that logged last, drawing a spike. Further out a run does
  not count (no extrapolation), so where only some runs reach, the mean and band are over those runs.
- the band around a group's mean: with fewer than 5 runs, `range_band(samples)`, the range (min to max) of the
  runs, since a bootstrap over 2-4 runs is little more than that range and covers far less than it claims; with 5 or
  more, `bootstrap_band(samples)`, a 95% percentile bootstrap confidence band of the mean, resampling runs with
  replacement from a seeded generator. The legend names the band of each group and its number of runs.

Below the curves, the final score of every run (`canter.use.scoreboard`) is summarised with rliable's aggregates
and intervals, profiles and probabilities of improvement (`canter.use.score_plot`).

Runs that are seeds of one experiment (`canter.config.experiment`: equal in every key that changes what is
learned) form one group. Groups are labelled by the keys in which they differ (`experiment_labels`).
Drawing uses matplotlib's object API with the Agg canvas, so no global backend is touched.
"""

from __future__ import annotations

import io
import math
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from canter.config.algorithms import all_plot_labels, unused_metrics
from canter.config.build import preset_config
from canter.config.experiment import (
    BUDGET_KEY,
    comparison_key,
    differing_keys,
    experiment_key,
    flat_config,
    repeated_seed_note,
)
from canter.config.schema import Config
from canter.config.values import set_text
from canter.errors import CanterError
from canter.training.logger import lost_rows, read_rows, run_history, unreadable_steps
from canter.training.run_folder import list_checkpoints, metrics_file, read_config, step_of
from canter.use import score_plot
from canter.use.scoreboard import (
    DIVERGED,
    EVAL_SOURCE,
    LAST_EVAL_SOURCE,
    TRAINING_SOURCE,
    RunScore,
    Scoreboard,
    build_scoreboard,
    run_score,
)
from canter.use.statistics import MIN_RUNS_FOR_INTERVAL

if TYPE_CHECKING:
    from matplotlib.figure import Figure

# Keys that name an experiment; a label uses only these when they tell the groups apart.
HEADLINE_KEYS = ("env.id", "run.algo", "run.preset")
SHORT_NAMES = {"env.id": "env", "run.algo": "algo", "run.preset": "preset", BUDGET_KEY: "budget"}

# metrics.csv columns that are bookkeeping rather than curves.
NOT_CURVES = ("global_step", "iteration", "wall_time", "episodes", "eval/return_std", "eval/episodes")
# Evaluations during training (`run.eval_every`) are drawn unsmoothed: each point already averages its episodes,
# and they lie many logged rows apart.
EVAL_PREFIX = "eval/"
# The first panels, in this order, where the runs have them.
LEADING_PANELS = ("episodic_return", "eval/return_mean", "episodic_length", "eval/length_mean", "sps")
# (title, y-axis label with units) of the columns every run logs; each algorithm declares its own
# (`AlgorithmSpec.plot_labels`), and other columns get their column name.
PANEL_LABELS: dict[str, tuple[str, str]] = {
    "episodic_return": ("Episode return", "return per episode (sum of rewards)"),
    "episodic_length": ("Episode length", "steps per episode"),
    "eval/return_mean": ("Evaluation return", "mean return of deterministic eval episodes"),
    "eval/length_mean": ("Evaluation episode length", "steps per eval episode"),
    "sps": ("Training speed", "env steps / s"),
}
X_AXES = {"steps": ("global_step", "environment steps"), "wall": ("wall_time", "wall time (s)")}
CONFIDENCE = 0.95
BOOTSTRAP_SAMPLES = 2000
# Band kinds, and how the legend names them.
RANGE, BOOTSTRAP, SINGLE = "range", "bootstrap", "single"
BAND_NAMES = {RANGE: "band: range", BOOTSTRAP: f"band: {CONFIDENCE:.0%} CI", SINGLE: "no band"}


@dataclass(frozen=True)
class RunCurves:
    run_dir: Path
    config: Config
    columns: dict[str, np.ndarray]  # numeric metrics.csv columns, NaN where a row has no value


@dataclass(frozen=True)
class Experiment:
    """The runs that are seeds of one experiment, with the label a plot gives them."""

    label: str
    runs: tuple[RunCurves, ...]


@dataclass(frozen=True)
class Band:
    x: np.ndarray
    mean: np.ndarray
    low: np.ndarray
    high: np.ndarray
    runs: int
    kind: str  # RANGE, BOOTSTRAP or SINGLE


# ------------------------------------------------------------------------------------------------------ reading


def _no_rows(path: Path) -> str:
    """Why a metrics.csv without rows has none, and what to do: a run that trained an iteration has logged one."""
    run = path.parent
    checkpoints = list_checkpoints(run)
    newest = step_of(checkpoints[-1]) if checkpoints else 0
    if newest > 0:
        return lost_rows(path, newest)
    # A run stopped in setup or in its first iteration (a signal, a non-finite start) has at most a step-0 checkpoint.
    go_on = f"train it on with canter train --resume {run}" if checkpoints else "train it again"
    return (
        f"{path} has no logged rows: the run has not finished an iteration (it is compiling, or it stopped before its "
        f"first one); leave it out, or {go_on}"
    )


def read_metrics(path: Path) -> dict[str, np.ndarray]:
    """The numeric columns of a metrics.csv; empty cells become NaN, columns with text are left out."""
    path = Path(path)
    if path.is_dir():  # a run folder with its file's name taken: sending the user to another run folder misleads
        raise CanterError(f"{path} is a folder, not a file; move it away and restore {path.name} from a copy")
    if not path.is_file():
        from canter.training.checkpoint import runs_inside

        inside = runs_inside(path.parent) if path.parent.is_dir() else []
        if inside:
            raise CanterError(
                f"{path.parent} is not a run folder but holds {len(inside)} (a bench's?): pass them, such as "
                f"{inside[0]}"
            )
        # plot and report both read curves here, so the message names no command.
        raise CanterError(f"no metrics.csv in {path.parent}; pass a run folder written by `canter train`")
    header, rows = read_rows(path)  # a half-written last line is left out
    if header and "global_step" not in header:
        raise CanterError(
            f"{path} has no global_step column in its first line, so it is not a metrics file canter wrote, or it "
            f"was edited or damaged; restore it from a copy"
        )
    if not header or not rows:
        raise CanterError(_no_rows(path))
    if damaged := unreadable_steps(rows):
        line, cell = damaged[0]
        raise CanterError(
            f"{path} has a row whose global_step is {cell!r} (line {line}), not a step: the file was edited or "
            f"damaged; delete that row or restore the file from a copy"
        )
    if "iteration" in header:
        rows = [row for row, _ in run_history(rows)]  # a format-1 run may hold rows of work lost before a resume
    columns: dict[str, np.ndarray] = {}
    for name in header:
        cells = [row.get(name) or "" for row in rows]
        try:
            columns[name] = np.array([float(c) if c.strip() else math.nan for c in cells])
        except ValueError:
            continue
    return columns


def load_run(run_dir: str | Path) -> RunCurves:
    run_dir = Path(run_dir)
    if run_dir.is_file():
        raise CanterError(
            f"{run_dir} is a file, not a run folder; pass the folder that holds config.toml and metrics.csv"
        )
    if not run_dir.is_dir():
        raise CanterError(f"run folder not found: {run_dir}")
    columns = read_metrics(metrics_file(run_dir))
    return RunCurves(run_dir, read_config(run_dir), columns)


# ------------------------------------------------------------------------------------------------------ grouping


def _show(key: str, value: Any) -> str:
    return f"{SHORT_NAMES.get(key, key)}={set_text(value)}"


def _label_keys(flats: Sequence[dict[str, Any]], configs: Sequence[Config]) -> list[list[str]]:
    """The keys that label each config (see `experiment_labels`)."""
    if len(configs) == 1:
        return [list(HEADLINE_KEYS)]
    diff = differing_keys(configs, comparison_key)
    headline = [k for k in HEADLINE_KEYS if any(f.get(k) != flats[0].get(k) for f in flats[1:])]
    keys = []
    for flat in flats:
        same_headline = [f for f in flats if all(f.get(k) == flat.get(k) for k in headline)]
        extra = [k for k in diff if k not in headline and k in flat and any(f.get(k) != flat[k] for f in same_headline)]
        keys.append(headline + extra)
    return keys


def experiment_labels(configs: Sequence[Config]) -> list[str]:
    """One label per config, from the keys in which they differ: the headline keys (env, algo, preset) when they
    tell the configs apart, plus any other differing key needed to tell apart configs whose headline is equal.
    A single config is labelled by its env, algo and preset."""
    flats = [flat_config(c) for c in configs]
    if len(configs) == 1:
        return [" ".join(_show(k, flats[0][k]) for k in HEADLINE_KEYS)]
    return [
        ", ".join(_show(k, flat[k]) for k in keys) or "same config"
        for flat, keys in zip(flats, _label_keys(flats, configs))
    ]


def method_keys(configs: Sequence[Config]) -> list[tuple[tuple[str, Any], ...]]:
    """What each run's method is on any env: its algorithm, preset and budget, the learning keys that some runs of
    one algorithm and preset on one env set to different values (a grid's keys: every run names its value), and
    the keys it sets apart from what its preset gives its env (a preset may give each env its own values; those
    stay the same method)."""
    by_env: dict[tuple[str, str, str], list[Config]] = {}
    for config in configs:
        by_env.setdefault((config.env.id, config.run.algo, config.run.preset), []).append(config)
    varied = {key for same_env in by_env.values() for key in differing_keys(same_env)}
    missing = object()
    keys = []
    for config in configs:
        preset = preset_config(config)
        base = flat_config(preset) if preset is not None else {}  # every key it sets counts as its own then
        changed = [
            (k, v) for k, v in experiment_key(config) if k != "env.id" and (k in varied or base.get(k, missing) != v)
        ]
        head = (("run.algo", config.run.algo), ("run.preset", config.run.preset))
        keys.append((*head, *changed, (BUDGET_KEY, config.run.total_steps)))
    return keys


_PER_ENV = "preset's per env"


def method_labels(configs: Sequence[Config]) -> list[str]:
    """One label per config, equal for the configs of one method (`method_keys`), whose scores on several envs the
    statistics aggregate. A label names the keys whose values tell the methods apart (the algorithm, the preset,
    and the keys some method changed from its preset); a single method is labelled by its algorithm and preset."""
    keys = method_keys(configs)
    methods = list(dict.fromkeys(keys))
    if len(methods) == 1:
        return [", ".join(_show(k, v) for k, v in keys[0][:2])] * len(configs)
    flats = [flat_config(c) for c in configs]

    def value(method: tuple, key: str) -> Any:
        seen = list(dict.fromkeys(repr(f.get(key)) for f, k in zip(flats, keys) if k == method))
        return next(f.get(key) for f, k in zip(flats, keys) if k == method) if len(seen) == 1 else _PER_ENV

    names = list(dict.fromkeys(name for method in methods for name, _ in method))
    values = {m: {name: value(m, name) for name in names} for m in methods}
    telling = [name for name in names if len({repr(values[m][name]) for m in methods}) > 1]
    labels = {m: ", ".join(_show(name, values[m][name]) for name in telling) for m in methods}
    if len(set(labels.values())) < len(methods):  # values that coincide across envs: name the changes themselves
        shared = set.intersection(*(set(m) for m in methods))
        labels = {m: ", ".join(_show(k, v) for k, v in [i for i in m if i not in shared] or m[:2]) for m in methods}
    return [labels[k] for k in keys]


def experiments_of(runs: Sequence[RunCurves]) -> list[Experiment]:
    """Runs that are seeds of one experiment trained to one budget (`canter.config.experiment.comparison_key`) form
    one group, in first-seen order; a seed that is there twice is noted."""
    note = repeated_seed_note([run.config for run in runs], [str(run.run_dir) for run in runs])
    if note is not None:
        print(f"canter: note: {note}", file=sys.stderr)
    keyed: dict[tuple, list[RunCurves]] = {}
    for run in runs:
        keyed.setdefault(comparison_key(run.config), []).append(run)
    members = list(keyed.values())
    labels = experiment_labels([m[0].config for m in members])
    return [Experiment(label, tuple(m)) for label, m in zip(labels, members)]


# ------------------------------------------------------------------------------------------------------ numerics


def moving_average(y: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average over the last `window` rows, ignoring NaNs (NaN only if all rows in it are NaN).
    `window=1` returns the input."""
    if window < 1:
        raise CanterError(f"--smooth must be >= 1 rows, got {window}")
    y = np.asarray(y, float)
    window = min(window, max(len(y), 1))  # a longer window is the whole series, and must not size an array
    valid = ~np.isnan(y)

    def in_window(values: np.ndarray) -> np.ndarray:
        sums = np.cumsum(values)
        return sums - np.concatenate([np.zeros(window), sums[:-window]])[: len(y)]

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
        means = np.nanmean(samples[index], axis=1)  # [resamples, points]
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
    xs = [r.columns[x_column] for r in runs]
    window = 1 if column.startswith(EVAL_PREFIX) else smooth
    ys = [moving_average(r.columns[column], window) for r in runs]
    if len(runs) == 1:
        keep = ~(np.isnan(xs[0]) | np.isnan(ys[0]))
        x, y = xs[0][keep], ys[0][keep]
        return Band(x, y, y.copy(), y.copy(), 1, SINGLE)
    grid = common_grid(xs)
    samples = np.stack([interpolate(x, y, grid, logging_interval(x)) for x, y in zip(xs, ys)])
    if len(runs) < MIN_RUNS_FOR_INTERVAL:
        return Band(grid, *range_band(samples), len(runs), RANGE)
    mean, low, high = bootstrap_band(samples, seed=seed)
    return Band(grid, mean, low, high, len(runs), BOOTSTRAP)


# ------------------------------------------------------------------------------------------------------ panels


def available_metrics(runs: Sequence[RunCurves]) -> list[str]:
    """Columns that can be drawn, in panel order: training and evaluation return, their lengths and speed
    first, then the algorithms' diagnostics in logged order; `info/*` columns last."""
    seen: list[str] = []
    for run in runs:
        for name, values in run.columns.items():
            if name not in NOT_CURVES and name not in seen and not np.isnan(values).all():
                seen.append(name)
    first = [c for c in LEADING_PANELS if c in seen]
    rest = [c for c in seen if c not in first and not c.startswith("info/")]
    return first + rest + [c for c in seen if c.startswith("info/")]


def unused_diagnostic(runs: Sequence[RunCurves], column: str) -> bool:
    """A diagnostic that the config of every run logging it turns off (`AlgorithmSpec.unused_metrics`), such as
    ppo's symmetry loss without sym.coef, which it logs as 0."""
    logging = [r for r in runs if column in r.columns and not np.isnan(r.columns[column]).all()]
    return all(column in unused_metrics(r.config) for r in logging)  # runs of algorithms without it do not count


def choose_metrics(runs: Sequence[RunCurves], requested: Sequence[str] | None) -> list[str]:
    """The requested columns, each a name or a glob such as `info/*` (checked), or by default every available
    column except the env's info/* terms and the diagnostics that the runs do not use."""
    import fnmatch

    available = available_metrics(runs)
    if not requested:
        return [c for c in available if not c.startswith("info/") and not unused_diagnostic(runs, c)]
    chosen: list[str] = []
    missing = []
    for pattern in requested:
        matches = [c for c in available if fnmatch.fnmatchcase(c, pattern)]
        if not matches:
            missing.append(pattern)
        chosen += [c for c in matches if c not in chosen]
    if missing:
        raise CanterError(
            f"no column {', '.join(missing)} with values in these runs; choose from: {', '.join(available)}"
        )
    return chosen


def panel_labels(column: str) -> tuple[str, str]:
    labels = {**all_plot_labels(), **PANEL_LABELS}
    if column in labels:
        return labels[column]
    if column.startswith("info/"):
        return f"Env term: {column[5:]}", "per-episode value"
    return column.replace("_", " ").capitalize(), column


# ------------------------------------------------------------------------------------------------------ drawing

FORMATS = {".png": "png", ".svg": "svg", ".pdf": "pdf"}


def figure_format(path: str | Path) -> str:
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise CanterError(f"cannot tell the image format of {path}; end the name in {', '.join(FORMATS)}")
    return FORMATS[suffix]


LineStyle = Literal["-", "--", ":", "-."]
LINE_STYLES: tuple[LineStyle, ...] = ("-", "--", ":", "-.")


@dataclass(frozen=True)
class Styles:
    """How a plot tells its groups apart: each group's colour and line style, and the colour of each method, which
    the statistics below the curves use for its rows, so that a row and its curves look alike."""

    colors: tuple[str, ...]
    line_styles: tuple[LineStyle, ...]
    method_colors: dict[str, str]


def group_styles(groups: Sequence[Experiment]) -> Styles:
    """Colour by method and line style by env, as papers draw algorithms on several tasks: the statistics
    aggregate methods across envs, so a colour per group would give their rows colours no curve has. Where one
    method has two groups on one env (runs that differ in a key the method does not name), each group gets its own
    colour instead, and the statistics their own palette; so do groups that colours and line styles cannot tell apart
    (more than 10 methods, or more than 4 envs)."""
    methods = method_labels([g.runs[0].config for g in groups])
    envs = [g.runs[0].config.env.id for g in groups]
    method_colors = {m: f"C{i % 10}" for i, m in enumerate(dict.fromkeys(methods))}
    env_styles = {e: LINE_STYLES[i % len(LINE_STYLES)] for i, e in enumerate(dict.fromkeys(envs))}
    styles = Styles(tuple(method_colors[m] for m in methods), tuple(env_styles[e] for e in envs), method_colors)
    if len(set(zip(methods, envs))) < len(groups) or len(set(zip(styles.colors, styles.line_styles))) < len(groups):
        return Styles(tuple(f"C{i % 10}" for i in range(len(groups))), (LINE_STYLES[0],) * len(groups), {})
    return styles


def draw(
    groups: Sequence[Experiment],
    metrics: Sequence[str],
    x_axis: str = "steps",
    smooth: int = 1,
    seed: int = 0,
    columns: int = 3,
    board: Scoreboard | None = None,
) -> Figure:
    """A matplotlib Figure with one panel per metric and one line (mean) plus band per group (the range of its runs
    below MIN_RUNS_FOR_INTERVAL runs, a 95% bootstrap CI from there on), and below them the statistics of `board` when
    some group has several runs."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import EngFormatter

    if x_axis not in X_AXES:
        raise CanterError(f"--x must be one of {', '.join(X_AXES)}, got {x_axis!r}")
    if not metrics:
        runs = ", ".join(str(run.run_dir) for group in groups for run in group.runs)
        raise CanterError(f"no metric with values to plot in {runs}; check their metrics.csv (damaged or empty?)")
    columns = max(1, min(columns, len(metrics)))
    rows = math.ceil(len(metrics) / columns)
    # One panel alone is widened so that the legend and its caption fit without being cut at the edges.
    with_statistics = board is not None and any(len(c.scores) > 1 for c in board.cells)
    # The statistics row needs the width of three panels, and a line per row of intervals.
    width = max(5.0 * columns, 15.0 if with_statistics else 7.5)
    statistics_height = score_plot.statistics_height(board) if board else 0.0
    height = 3.4 * rows + 1.0 + (statistics_height if with_statistics else 0.0)
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)  # headless: no pyplot, no display, no global backend switch
    curves: Any = fig
    styles = group_styles(groups)
    if with_statistics:
        assert board is not None
        parts: Any = fig.subfigures(2, 1, height_ratios=[3.4 * rows, statistics_height])
        curves = parts[0]
        score_plot.draw_scoreboard(parts[1], board, styles.method_colors)
    axes = curves.subplots(rows, columns, squeeze=False).ravel()
    for ax, metric in zip(axes, metrics):
        title, unit = panel_labels(metric)
        for group, color, line_style in zip(groups, styles.colors, styles.line_styles):
            band = experiment_band(group, metric, x_axis, smooth, seed)
            if band is None:
                continue
            ax.plot(band.x, band.mean, color=color, linestyle=line_style, linewidth=1.6)
            if band.kind != SINGLE:
                ax.fill_between(band.x, band.low, band.high, color=color, alpha=0.22, linewidth=0)
        ax.set_title(title, fontsize=11)
        ax.set_ylabel(unit, fontsize=9)
        ax.set_xlabel(X_AXES[x_axis][1], fontsize=9)
        ax.xaxis.set_major_formatter(EngFormatter(sep=""))
        _widen_if_flat(ax)
        ax.grid(True, alpha=0.3)
        ax.tick_params(labelsize=8)
    for ax in axes[len(metrics) :]:
        ax.set_visible(False)
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=c, linestyle=ls, linewidth=2.5) for c, ls in zip(styles.colors, styles.line_styles)]
    names = [
        f"{g.label} ({len(g.runs)} run{'s' if len(g.runs) > 1 else ''}), {BAND_NAMES[band_kind(g)]}" for g in groups
    ]
    smoothing = f"moving average over {smooth} logged rows" if smooth > 1 else "unsmoothed"
    kinds = {band_kind(g) for g in groups}
    band_note = "".join(
        note
        for kind, note in (
            (RANGE, f"; band 'range' (groups of fewer than {MIN_RUNS_FOR_INTERVAL} runs): min to max of the runs"),
            (
                BOOTSTRAP,
                f"; band '{CONFIDENCE:.0%} CI' (groups of {MIN_RUNS_FOR_INTERVAL} runs or more): percentile "
                f"bootstrap CI of the mean, {BOOTSTRAP_SAMPLES:,} resamples",
            ),
        )
        if kind in kinds
    )
    envs = list(dict.fromkeys(r.config.env.id for g in groups for r in g.runs))
    import textwrap

    line = int(width * 13)  # characters of 10-point text across the figure
    caption = textwrap.fill(f"{', '.join(envs)}. Lines: mean over runs, {smoothing}{band_note}", width=line)
    # As many columns as the longest name leaves room for, so that no name is cut at the figure's edges.
    names = [textwrap.fill(name, width=line - 8) for name in names]
    longest = max(len(row) for name in names for row in name.splitlines())
    fig.legend(
        handles,
        names,
        loc="outside upper center",
        ncols=max(1, min(len(groups), 3, line // (longest + 8))),
        fontsize=10,
        title=caption,
        title_fontsize=10,
        frameon=False,
    )
    return fig


def _widen_if_flat(ax: Any) -> None:
    """A constant curve (a learning rate that is not annealed) varies by rounding alone after interpolation, and its
    axis would span those 1e-19 steps ("1e-16+3e-4"); give it 5% of its value on each side instead."""
    values = [np.asarray(line.get_ydata(), float) for line in ax.lines]
    ys = np.concatenate(values) if values else np.array([])
    ys = ys[np.isfinite(ys)]
    if ys.size == 0 or ys.max() - ys.min() > 1e-9 * max(abs(ys.max()), abs(ys.min())):
        return
    center = float(np.median(ys))
    pad = abs(center) * 0.05 or 1.0
    ax.set_ylim(center - pad, center + pad)


def band_kind(group: Experiment) -> str:
    """The band a group's curves get from its number of runs (a panel where fewer of them logged may get less)."""
    return SINGLE if len(group.runs) == 1 else RANGE if len(group.runs) < MIN_RUNS_FOR_INTERVAL else BOOTSTRAP


def final_score(run: RunCurves) -> tuple[float, str] | None:
    """(a run's score, what it is): its final deterministic evaluation (eval.json, as `canter bench` writes it),
    else the last evaluation during training (`eval/return_mean`), else its recent training return."""
    found = run_score(run.run_dir)
    evaluations = run.columns.get("eval/return_mean")
    if (found is None or found[1] != EVAL_SOURCE) and evaluations is not None and not np.isnan(evaluations).all():
        return float(evaluations[~np.isnan(evaluations)][-1]), LAST_EVAL_SOURCE
    return found


def scoreboard_of(
    groups: Sequence[Experiment], scores: dict[Path, tuple[float, str]] | None = None, seed: int = 0
) -> Scoreboard | None:
    """The statistics of the groups' final scores: `scores` by run folder where given, else each run's
    `final_score`. Groups whose labels differ only in the env are one method. None unless some group has two or
    more scored runs: a single run has no interval."""
    methods = method_labels([g.runs[0].config for g in groups])
    runs = [(method, run) for group, method in zip(groups, methods) for run in group.runs]
    found = {run.run_dir: scores.get(run.run_dir) if scores is not None else final_score(run) for _, run in runs}
    # A diverged run's score stands, whatever the others are scored by: its training return would hide the failure.
    diverged = [path for path, score in found.items() if score is not None and not np.isfinite(score[0])]
    untested = [path for path, score in found.items() if score is not None and score[1] == TRAINING_SOURCE]
    if untested and len(untested) < sum(score is not None for score in found.values()):
        # An evaluation and a training return (stochastic actions) are not samples of one score.
        _note_runs(untested, "no evaluation, so every run is scored by its training return")
        found = {path: found[path] if path in diverged else run_score(path, (TRAINING_SOURCE,)) for path in found}
        unscored = [path for path, score in found.items() if score is None]
        if unscored:
            _note_runs(
                unscored, "no training return (no finished episode, or no summary.json yet): left out of the statistics"
            )
    if diverged:
        _note_runs(diverged, f"{DIVERGED}: left out of the statistics")
    rows, sources = [], []
    for method, run in runs:
        score = found[run.run_dir]
        if score is None or not np.isfinite(score[0]):
            continue
        rows.append(RunScore(method, run.config.env.id, run.config.run.algo, score[0], run.run_dir.name))
        sources.append(score[1])
    cells = [(r.method, r.env_id) for r in rows]
    if all(cells.count(cell) < 2 for cell in cells):
        return None
    return build_scoreboard(rows, "; ".join(dict.fromkeys(sources)), seed=seed)


def _note_runs(paths: Sequence[Path], what: str) -> None:
    subject = f"{paths[0]} has" if len(paths) == 1 else f"{paths[0]} and {len(paths) - 1} more runs have"
    print(f"canter: note: {subject} {what}", file=sys.stderr)


def render(
    run_dirs: Sequence[str | Path],
    fmt: str = "png",
    metrics: Sequence[str] | None = None,
    x_axis: str = "steps",
    smooth: int = 1,
    seed: int = 0,
) -> bytes:
    """Read runs, group them, draw the chosen panels and the statistics of their final scores (each run's
    `final_score`); the image file's bytes."""
    return render_runs([load_run(r) for r in run_dirs], fmt, metrics, x_axis, smooth, seed)[0]


def render_runs(
    runs: Sequence[RunCurves],
    fmt: str = "png",
    metrics: Sequence[str] | None = None,
    x_axis: str = "steps",
    smooth: int = 1,
    seed: int = 0,
    scores: dict[Path, tuple[float, str]] | None = None,
) -> tuple[bytes, Scoreboard | None]:
    """`render` of runs already read, their final scores `scores` by run folder where given (`scoreboard_of`), and
    the scoreboard it drew."""
    groups = experiments_of(runs)
    board = scoreboard_of(groups, scores, seed)
    fig = draw(groups, choose_metrics(runs, metrics), x_axis, smooth, seed, board=board)
    buffer = io.BytesIO()
    fig.savefig(buffer, format=fmt, dpi=110)
    return buffer.getvalue(), board
