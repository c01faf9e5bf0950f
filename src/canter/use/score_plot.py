"""Draw a `canter.use.scoreboard.Scoreboard` into a matplotlib (sub)figure, in the style of rliable's plots: one
axis per aggregate (IQM, mean, median, optimality gap) with a row per method and its 95% interval, the
performance profiles, and the probability of improvement of every pair of methods. Rows of fewer than
MIN_RUNS_FOR_INTERVAL runs show their estimate alone, as the tables do."""

from __future__ import annotations

import textwrap
from collections.abc import Mapping
from typing import Any

from canter.use.scoreboard import Scoreboard
from canter.use.statistics import CONFIDENCE, MIN_RUNS_FOR_INTERVAL, Aggregates, Interval

NORMALIZED = "normalized score"
LABEL_WIDTH = 40  # characters of a row label before it wraps
AGGREGATES = (("iqm", "IQM"), ("mean", "Mean"), ("median", "Median"), ("optimality_gap", "Optimality gap"))


def _rows(board: Scoreboard) -> tuple[list[str], list[Aggregates], str]:
    """(row labels, their aggregates, the x-axis label): methods on normalized scores when the board spans several
    envs and has them, else one row per env and method on returns."""
    if len(board.envs) > 1 and board.methods:
        labels = [f"{m.method} (n={m.normalized.runs}×{m.normalized.tasks} envs)" for m in board.methods]
        return labels, [m.normalized for m in board.methods], NORMALIZED
    labels = [
        f"{c.method} (n={c.returns.runs})" if len(board.envs) == 1 else f"{c.method}, {c.env_id} (n={c.returns.runs})"
        for c in board.cells
    ]
    return labels, [c.returns for c in board.cells], "final return"


def statistics_height(board: Scoreboard) -> float:
    """Inches the drawing needs: room for the caption, and for the wrapped labels of its rows and of its pairs."""
    labels = [textwrap.fill(label, width=LABEL_WIDTH) for label in _rows(board)[0]]
    pairs = [_pair_label(c.x, c.y) for c in board.comparisons]
    lines = max(sum(text.count("\n") + 1 for text in texts) for texts in (labels, pairs or [""]))
    return 1.4 + 0.17 * max(lines, 12)


def _pair_label(x: str, y: str) -> str:
    return textwrap.fill(f"P({x} > {y})", width=LABEL_WIDTH)


def _interval_row(ax: Any, y: int, interval: Interval, color: str, runs: int) -> None:
    if runs < MIN_RUNS_FOR_INTERVAL:
        ax.plot([interval.estimate], [y], marker="o", color=color, markersize=6)
        return
    ax.plot([interval.low, interval.high], [y, y], color=color, linewidth=6, alpha=0.45, solid_capstyle="butt")
    ax.plot([interval.estimate], [y], marker="|", color="black", markersize=12)


def _colors(methods: list[str], method_colors: Mapping[str, str]) -> list[str]:
    """Each method's colour where the curves gave one to every method drawn, else a colour per entry."""
    if not all(m in method_colors for m in methods):
        return [f"C{i % 10}" for i in range(len(methods))]
    return [method_colors[m] for m in methods]


def draw_scoreboard(fig: Any, board: Scoreboard, method_colors: Mapping[str, str] | None = None) -> None:
    """Fill `fig` (a Figure or SubFigure) with the board's aggregates, profiles and comparisons, each method in its
    colour from `method_colors` where that names them all."""
    labels, found, unit = _rows(board)
    # Long method names (a grid's keys) are wrapped: unwrapped, they squeeze the first axis to nothing.
    labels = [textwrap.fill(label, width=LABEL_WIDTH) for label in labels]
    extra = int(bool(board.profiles)) + int(bool(board.comparisons))
    axes = fig.subplots(1, len(AGGREGATES) + extra, squeeze=False)[0]
    methods = [m.method for m in board.methods] if unit == NORMALIZED else [c.method for c in board.cells]
    colors = _colors(methods, method_colors or {})
    profile_colors = dict(zip(board.profiles, _colors(list(board.profiles), method_colors or {})))
    for i, (ax, (key, title)) in enumerate(zip(axes, AGGREGATES)):
        for y, (aggregates, color) in enumerate(zip(found, colors)):
            interval = getattr(aggregates, key)
            if interval is not None:
                _interval_row(ax, y, interval, color, aggregates.runs)
            else:  # an optimality gap needs a reference return
                ax.text(0.5, y, "no published reference", transform=ax.get_yaxis_transform(), ha="center", fontsize=7)
        ax.set_yticks(range(len(labels)), labels if i == 0 else [""] * len(labels), fontsize=8)
        ax.set_ylim(len(labels) - 0.5, -0.5)
        ax.set_title(title, fontsize=10)
        if i == 0 or key == "optimality_gap":
            ax.set_xlabel(f"{unit} below reference" if key == "optimality_gap" else unit, fontsize=8)
        ax.tick_params(axis="x", labelsize=7)
        ax.grid(True, axis="x", alpha=0.3)
    next_axis = len(AGGREGATES)
    if board.profiles:
        ax = axes[next_axis]
        next_axis += 1
        for name, profile in board.profiles.items():
            color = profile_colors[name]
            ax.plot(profile.taus, profile.fraction, color=color, linewidth=1.5, label=name)
            if board.runs_per_env(name) >= MIN_RUNS_FOR_INTERVAL:
                ax.fill_between(profile.taus, profile.low, profile.high, color=color, alpha=0.2, linewidth=0)
        ax.set_title("Performance profile", fontsize=10)
        ax.set_xlabel("normalized score τ", fontsize=8)
        ax.set_ylabel("fraction of runs > τ", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, frameon=False, loc="lower left")
    if board.comparisons:
        ax = axes[next_axis]
        pairs = [_pair_label(c.x, c.y) for c in board.comparisons]
        for y, comparison in enumerate(board.comparisons):
            _interval_row(ax, y, comparison.probability, "C7", min(comparison.runs))
        ax.axvline(0.5, color="black", linewidth=0.8, linestyle=":")
        ax.set_xlim(-0.03, 1.03)
        ax.set_yticks(range(len(pairs)), pairs, fontsize=8)
        ax.set_ylim(len(pairs) - 0.5, -0.5)
        ax.set_title("Probability of improvement", fontsize=10)
        ax.set_xlabel("probability, per env, averaged", fontsize=8)
        ax.tick_params(axis="x", labelsize=7)
        ax.grid(True, axis="x", alpha=0.3)
    caption = (
        f"Final scores: {board.source}. Bars: {CONFIDENCE:.0%} stratified-bootstrap CIs (rliable, "
        f"{board.reps:,} resamples); ticks: point estimates; dots: estimates of fewer than {MIN_RUNS_FOR_INTERVAL} "
        f"runs, which get no interval; n: runs per env."
    )
    references = sorted({f"{c.normalizer.source} {c.algo}" for c in board.cells if c.normalizer})
    if unit == NORMALIZED or board.profiles:
        caption += (
            " Normalized score: 0 = uniformly random actions (measured by canter), 1 = the published 1M-step figure "
            f"of the same algorithm ({', '.join(references)}), measured under its source's own protocol."
        )
    fig.suptitle(textwrap.fill(caption, width=int(fig.get_figure(root=True).get_figwidth() * 14)), fontsize=9)
