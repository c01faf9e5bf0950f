"""The statistics that bench, plot and report give about final scores, built from one score per run with
`canter.use.statistics` (rliable) and the normalizers of `canter.use.reference_scores`:

- per env and method (a method: an algorithm with its settings; runs of one method on one env are its seeds):
  IQM, mean, median and optimality gap of the runs' returns, each with a 95% stratified-bootstrap interval. The
  optimality gap is the mean shortfall below the published reference (threshold: the reference return), in return units;
- per method across envs: the same four on normalized scores (threshold 1), over the envs that have a normalizer;
- performance profiles of the normalized scores, and the probability of improvement P(X > Y) between every two
  methods over the envs both ran (it compares returns within each env, so it needs no normalizer).

Every table is also a list of rows (`tables()`), so that markdown, HTML and JSON say the same thing.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from canter.run_layout import EVAL_FILE, SUMMARY_FILE, evaluates_newest_checkpoint, read_object
from canter.use import statistics
from canter.use.reference_scores import Normalizer, normalizer_for, random_command, reference_score
from canter.use.statistics import Aggregates, Interval, Profile

# Thresholds of the performance profile, in normalized score.
PROFILE_TAUS = tuple(round(0.05 * i, 2) for i in range(41))  # 0 to 2
SHOWN_TAUS = (0.25, 0.5, 0.75, 1.0, 1.25, 1.5)
EVAL_SOURCE = "final deterministic evaluation (eval.json: mean return over its episodes)"
LAST_EVAL_SOURCE = "last evaluation during training (metrics.csv: eval/return_mean)"
TRAINING_SOURCE = "training return (summary.json: mean of the last 20 training episodes)"
DIVERGED = "a final evaluation that is not finite (a diverged policy)"


@dataclass(frozen=True)
class RunScore:
    method: str  # label of the algorithm and settings
    env_id: str
    algo: str
    score: float
    run: str  # the run's name, for the JSON


@dataclass(frozen=True)
class CellStats:
    """One method on one env: the returns of its runs."""

    method: str
    env_id: str
    algo: str
    scores: tuple[float, ...]
    returns: Aggregates  # optimality gap below the reference return, when there is one
    normalizer: Normalizer | None
    # The published return of the algorithm on the env and its source, also where no random score normalizes it.
    reference: tuple[float, str, str] | None = None  # (return, source, the env id it measured)


@dataclass(frozen=True)
class MethodStats:
    """One method across the envs with a normalizer: normalized scores [runs, envs]."""

    method: str
    envs: tuple[str, ...]
    normalized: Aggregates
    without_normalizer: tuple[str, ...]
    dropped_runs: int  # runs beyond the fewest any env has, left out to make a matrix


@dataclass(frozen=True)
class Comparison:
    x: str
    y: str
    envs: tuple[str, ...]
    probability: Interval
    runs: tuple[int, int]  # runs per env of X and of Y that the probability compares


@dataclass(frozen=True)
class Table:
    title: str
    note: str
    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]


@dataclass(frozen=True)
class Scoreboard:
    source: str  # what a run's score is
    cells: tuple[CellStats, ...]
    methods: tuple[MethodStats, ...]
    profiles: dict[str, Profile] = field(default_factory=dict)
    comparisons: tuple[Comparison, ...] = ()
    reps: int = statistics.REPS
    seed: int = 0

    @property
    def envs(self) -> list[str]:
        return list(dict.fromkeys(c.env_id for c in self.cells))

    def interval_note(self) -> str:
        return (
            f"Intervals: {statistics.CONFIDENCE:.0%} stratified-bootstrap confidence intervals (rliable "
            f"get_interval_estimates, percentile method, {self.reps:,} resamples of the runs within each env, "
            f"seed {self.seed}), shown from {statistics.MIN_RUNS_FOR_INTERVAL} runs on: with fewer, a bootstrap "
            f"only restates the runs' spread. n: runs per cell."
        )

    def tables(self) -> list[Table]:
        tables = [
            Table(
                "Final return per env",
                f"Score of a run: {self.source}. IQM: mean of the runs left once the lowest and the highest quarter "
                "(rounded down) are cut, as rliable computes it. Optimality gap: mean shortfall of the runs below "
                "the reference (the published 1M-step figure of the same algorithm), in return units. "
                + self.interval_note(),
                ("env", "method", "n", "IQM", "mean", "median", "optimality gap", "reference"),
                tuple(
                    (
                        c.env_id,
                        c.method,
                        str(c.returns.runs),
                        c.returns.iqm.show(runs=c.returns.runs),
                        c.returns.mean.show(runs=c.returns.runs),
                        c.returns.median.show(runs=c.returns.runs),
                        c.returns.optimality_gap.show(runs=c.returns.runs) if c.returns.optimality_gap else "–",
                        _reference_cell(c),
                    )
                    for c in self.cells
                ),
            )
        ]
        if self.methods:
            tables.append(
                Table(
                    "Across envs, normalized",
                    "Normalized score = (return − random) / (reference − random): 0 is uniformly random actions "
                    "(measured by canter), 1 the published 1M-step figure of the same algorithm: Tianshou's best "
                    "10-seed average during training (MuJoCo v3; v2 for Reacher and the pendulums) where it has "
                    "one, else CleanRL's training return (v4), another protocol and env version than these runs', so "
                    "a yardstick rather than a ranking. Mean and median are of the per-env means (for one env, of its "
                    "runs); IQM and optimality gap (γ = 1) pool every run.",
                    ("method", "envs", "n per env", "IQM", "mean", "median", "optimality gap"),
                    tuple(
                        (
                            m.method,
                            ", ".join(m.envs)
                            + (f" (no normalizer: {', '.join(m.without_normalizer)})" if m.without_normalizer else ""),
                            str(m.normalized.runs) + (f" ({m.dropped_runs} more left out)" if m.dropped_runs else ""),
                            m.normalized.iqm.show(2, runs=m.normalized.runs),
                            m.normalized.mean.show(2, runs=m.normalized.runs),
                            m.normalized.median.show(2, runs=m.normalized.runs),
                            m.normalized.optimality_gap.show(2, runs=m.normalized.runs)
                            if m.normalized.optimality_gap
                            else "–",
                        )
                        for m in self.methods
                    ),
                )
            )
        if self.profiles:
            shown = [t for t in SHOWN_TAUS if t in PROFILE_TAUS]
            tables.append(
                Table(
                    "Performance profile",
                    "Fraction of runs (over the envs of the row above) whose normalized score exceeds τ, with its "
                    f"interval from {statistics.MIN_RUNS_FOR_INTERVAL} runs per env on (rliable "
                    "create_performance_profile).",
                    ("method",) + tuple(f"τ = {t:g}" for t in shown),
                    tuple(
                        (name,)
                        + tuple(
                            Interval(p.fraction[i], p.low[i], p.high[i]).show(2, runs=self.runs_per_env(name))
                            for i in (PROFILE_TAUS.index(t) for t in shown)
                        )
                        for name, p in self.profiles.items()
                    ),
                )
            )
        if self.comparisons:
            tables.append(
                Table(
                    "Probability of improvement",
                    "P(X > Y): the probability that a run of X returns more than a run of Y on the same env (ties "
                    "count half), averaged over the envs both ran; its interval resamples the runs of X and Y "
                    f"independently (rliable probability_of_improvement), shown when both have "
                    f"{statistics.MIN_RUNS_FOR_INTERVAL} runs per env or more. A method with unequal numbers of runs "
                    "per env takes as many runs per env as its smallest env has.",
                    ("X", "Y", "envs", "P(X > Y)"),
                    tuple(
                        (c.x, c.y, ", ".join(c.envs), c.probability.show(2, runs=min(c.runs))) for c in self.comparisons
                    ),
                )
            )
        return tables

    def runs_per_env(self, method: str) -> int:
        return next(m.normalized.runs for m in self.methods if m.method == method)

    def normalizer_note(self) -> str:
        used = {(c.env_id, c.algo): c.normalizer for c in self.cells if c.normalizer}
        if not used:
            return ""
        return (
            "Normalizers: "
            + "; ".join(n.describe() for n in used.values())
            + f". Random returns measured with `{random_command()}`."
        )

    def markdown(self) -> str:
        parts = []
        for table in self.tables():
            lines = [f"### {table.title}", "", table.note, "", "| " + " | ".join(table.header) + " |"]
            lines.append("|" + "---|" * len(table.header))
            lines += ["| " + " | ".join(row) + " |" for row in table.rows]
            parts.append("\n".join(lines))
        note = self.normalizer_note()
        return "\n\n".join(parts + ([note] if note else [])) + "\n"

    def as_dict(self) -> dict[str, Any]:
        return {
            "score": self.source,
            "confidence": statistics.CONFIDENCE,
            "bootstrap": {"method": "stratified, percentile", "reps": self.reps, "seed": self.seed},
            "cells": [
                {
                    "env": c.env_id,
                    "method": c.method,
                    "algo": c.algo,
                    "scores": list(c.scores),
                    "return": c.returns.as_dict(),
                    "normalizer": c.normalizer.as_dict() if c.normalizer else None,
                }
                for c in self.cells
            ],
            "across_envs": [
                {
                    "method": m.method,
                    "envs": list(m.envs),
                    "without_normalizer": list(m.without_normalizer),
                    "dropped_runs": m.dropped_runs,
                    "normalized": m.normalized.as_dict(),
                }
                for m in self.methods
            ],
            "performance_profiles": {name: p.as_dict() for name, p in self.profiles.items()},
            "probability_of_improvement": [
                {
                    "x": c.x,
                    "y": c.y,
                    "envs": list(c.envs),
                    "runs": list(c.runs),
                    "probability": c.probability.as_dict(),
                }
                for c in self.comparisons
            ],
            "random_command": random_command(),
        }

    def json(self) -> str:
        return json.dumps(self.as_dict(), indent=2) + "\n"


def _normalized_matrix(cells: Sequence[CellStats]) -> tuple[np.ndarray, int]:
    """[runs, envs] of normalized scores, runs matched by position; the runs beyond the fewest are left out."""
    runs = min(len(c.scores) for c in cells)
    columns = []
    for c in cells:
        assert c.normalizer is not None
        columns.append(statistics.normalized(c.scores[:runs], c.normalizer.random, c.normalizer.reference))
    return np.stack(columns, axis=1), sum(len(c.scores) - runs for c in cells)


def _reference_cell(cell: CellStats) -> str:
    """The reference column: the published return and its source; where canter has no random score for the env, it
    still gives the optimality gap, but normalizes nothing."""
    if cell.reference is None:
        return "none published"
    value, source, measured = cell.reference
    return f"{value:,.1f} ({source}, {measured})" + ("" if cell.normalizer else "; no random score, not normalized")


def build_scoreboard(scores: Sequence[RunScore], source: str, reps: int | None = None, seed: int = 0) -> Scoreboard:
    """All the statistics of the runs' scores, from `reps` bootstrap resamples (default `statistics.REPS`, read at
    each call). Cells and methods keep the order in which they first appear."""
    reps = reps or statistics.REPS
    grouped: dict[tuple[str, str], list[RunScore]] = {}
    for s in scores:
        grouped.setdefault((s.method, s.env_id), []).append(s)
    cells = []
    for (method, env_id), members in grouped.items():
        algo = members[0].algo
        normalizer = normalizer_for(algo, env_id)
        reference = reference_score(algo, env_id)
        values = np.array([[m.score] for m in members])
        gamma = reference[0] if reference else None
        cells.append(
            CellStats(
                method,
                env_id,
                algo,
                tuple(float(v) for v in values[:, 0]),
                statistics.aggregates(values, gamma, reps, seed),
                normalizer,
                reference,
            )
        )
    method_names = list(dict.fromkeys(c.method for c in cells))
    methods, matrices = [], {}
    for name in method_names:
        own = [c for c in cells if c.method == name]
        normalizable = [c for c in own if c.normalizer]
        if not normalizable:
            continue
        matrix, dropped = _normalized_matrix(normalizable)
        matrices[name] = matrix
        methods.append(
            MethodStats(
                name,
                tuple(c.env_id for c in normalizable),
                statistics.aggregates(matrix, 1.0, reps, seed),
                tuple(c.env_id for c in own if not c.normalizer),
                dropped,
            )
        )
    profiles = statistics.performance_profiles(matrices, PROFILE_TAUS, reps, seed) if matrices else {}
    pairs, matched = [], []
    for x, y in itertools.combinations(method_names, 2):
        by_env_x = {c.env_id: c for c in cells if c.method == x}
        by_env_y = {c.env_id: c for c in cells if c.method == y}
        common = [e for e in by_env_x if e in by_env_y]
        if not common:
            continue
        # P(X > Y) takes a matrix per method: X and Y may differ in runs, but each needs as many runs per env.
        px = _runs_by_env([by_env_x[e].scores for e in common])
        py = _runs_by_env([by_env_y[e].scores for e in common])
        pairs.append((x, y, tuple(common), (px.shape[0], py.shape[0])))
        matched.append((px, py))
    probabilities = statistics.probabilities_of_improvement(matched, reps, seed)
    comparisons = [Comparison(x, y, envs, p, runs) for (x, y, envs, runs), p in zip(pairs, probabilities)]
    return Scoreboard(source, tuple(cells), tuple(methods), profiles, tuple(comparisons), reps, seed)


def _runs_by_env(columns: Sequence[tuple[float, ...]]) -> np.ndarray:
    """[runs, envs] from each env's runs; with unequal counts, the first runs up to the fewest."""
    runs = min(len(c) for c in columns)
    return np.array([list(c[:runs]) for c in columns]).T


SCORE_FILES = {EVAL_SOURCE: (EVAL_FILE, "mean"), TRAINING_SOURCE: (SUMMARY_FILE, "recent_return")}


def run_score(run_dir: Path, sources: Sequence[str] = (EVAL_SOURCE, TRAINING_SOURCE)) -> tuple[float, str] | None:
    """(a finished run's score, what it is), from the first of `sources` the run has: its final deterministic
    evaluation where `canter bench` wrote one for its newest checkpoint (one from before a resume is stale), the mean
    training return of its last episodes; None for a run without either. A final evaluation that is not finite (a
    diverged policy) is still the run's score: falling back to its training return would score a failed run as if
    it had not failed."""
    for source in sources:
        name, key = SCORE_FILES[source]
        data = read_object(run_dir / name)
        if data is None:
            continue
        value = data.get(key)
        if source == EVAL_SOURCE and not evaluates_newest_checkpoint(run_dir, data):
            continue
        if isinstance(value, int | float) and (np.isfinite(value) or source == EVAL_SOURCE):
            return float(value), source
    return None
