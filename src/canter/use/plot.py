"""Learning curves of run folders: read metrics.csv, group seeds, smooth, align, bootstrap, draw.

The runs' curves are read by `canter.use.curves`, grouped into experiments and labelled by
`canter.use.experiments`, and each group's mean curve and band come from `canter.use.bands`; this module chooses the
panels and draws them. The legend names the band of each group and its number of runs.

Below the curves, the final score of every run (`canter.use.scoreboard`) is summarised with rliable's aggregates
and intervals, profiles and probabilities of improvement (`canter.use.score_plot`).

Drawing uses matplotlib's object API with the Agg canvas, so no global backend is touched.
"""

from __future__ import annotations

import io
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from canter.config.algorithms import all_plot_labels, unused_metrics
from canter.errors import CanterError
from canter.use import score_plot
from canter.use.bands import (
    BOOTSTRAP,
    BOOTSTRAP_SAMPLES,
    CONFIDENCE,
    RANGE,
    SINGLE,
    X_AXES,
    band_kind,
    experiment_band,
)
from canter.use.curves import RunCurves, load_run
from canter.use.experiments import Experiment, experiments_of, method_labels
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

# metrics.csv columns that are bookkeeping rather than curves.
NOT_CURVES = ("global_step", "iteration", "wall_time", "episodes", "eval/return_std", "eval/episodes")
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
# How the legend names each band kind.
BAND_NAMES = {RANGE: "band: range", BOOTSTRAP: f"band: {CONFIDENCE:.0%} CI", SINGLE: "no band"}


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

    _check_x_axis([run for group in groups for run in group.runs], x_axis)
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
            lone = len(band.x) == 1  # a line through one point draws nothing: a run with one logged row
            ax.plot(band.x, band.mean, color=color, linestyle=line_style, linewidth=1.6, marker="o" if lone else None)
            if band.kind != SINGLE and lone:
                ax.vlines(band.x, band.low, band.high, color=color, alpha=0.5, linewidth=4)
            elif band.kind != SINGLE:
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
    axis would span those 1e-19 steps ("1e-16+3e-4"); give it 5% of its value on each side instead. The span is
    that of everything drawn, bands included (a lone point's band is a vertical bar)."""
    low, high = (float(v) for v in ax.dataLim.intervaly)
    if not (math.isfinite(low) and math.isfinite(high)) or high - low > 1e-9 * max(abs(low), abs(high)):
        return
    center = (low + high) / 2
    pad = abs(center) * 0.05 or 1.0
    ax.set_ylim(center - pad, center + pad)


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


def _check_x_axis(runs: Sequence[RunCurves], x_axis: str) -> None:
    """Refuse an x axis that no run logged, and name the runs that the panels leave out for lacking it (a
    metrics.csv that a user's script wrote or cut), rather than drawing panels without them in silence."""
    if x_axis not in X_AXES:
        raise CanterError(f"--x must be one of {', '.join(X_AXES)}, got {x_axis!r}")
    column = X_AXES[x_axis][0]
    lacking = [r.run_dir for r in runs if column not in r.columns or np.isnan(r.columns[column]).all()]
    if lacking and len(lacking) == len(runs):
        other = [name for name in X_AXES if name != x_axis]
        raise CanterError(
            f"no {column} values in the metrics.csv of {lacking[0]}"
            + (f" or of the {len(lacking) - 1} other runs" if len(lacking) > 1 else "")
            + f", which --x {x_axis} draws against; plot with --x {other[0]}"
        )
    if lacking:
        _note_runs(lacking, f"no {column} values in metrics.csv: left out of the panels, which --x {x_axis} draws")


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
