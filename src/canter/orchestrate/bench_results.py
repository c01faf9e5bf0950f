"""The results of a bench: each finished seed's record, each cell's row, and what the bench writes of them
(results.md, results.csv, statistics.json and a plot per env)."""

from __future__ import annotations

import csv
import io
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from canter.errors import CanterError
from canter.files import check_writable
from canter.orchestrate.bench_grid import BenchSettings, Cell, safe_name, varying_keys
from canter.orchestrate.run_status import is_number, read_usable_summary
from canter.run_layout import CONFIG_FILE, EVAL_FILE, read_object
from canter.use.reference_scores import REFERENCE_STEPS, env_base, published_scores

if TYPE_CHECKING:
    from canter.use.scoreboard import Scoreboard


@dataclass(frozen=True)
class SeedRecord:
    """What the table needs of one finished run: its final eval mean, wall seconds and SPS (None where missing)."""

    seed: int
    eval_mean: float | None
    wall_seconds: float | None
    sps: float | None
    # The seeds its last session trained beside; None for a summary written before that was kept.
    trained_with: tuple[int, ...] | None

    def to_json(self) -> dict[str, Any]:
        """The form a grid's trial stores (`canter.orchestrate.bench_distributed`) and the benchmark scripts extend."""
        return {
            "seed": self.seed,
            "eval_mean": self.eval_mean,
            "wall_seconds": self.wall_seconds,
            "sps": self.sps,
            "trained_with": None if self.trained_with is None else list(self.trained_with),
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> SeedRecord:
        """A stored record, or one that a benchmark script extended with keys of its own; a trial stored before
        `trained_with` was kept has none."""
        trained_with = data.get("trained_with")
        return cls(
            data["seed"],
            data["eval_mean"],
            data["wall_seconds"],
            data["sps"],
            None if trained_with is None else tuple(trained_with),
        )


def read_seed(run_dir: Path, seed: int) -> SeedRecord:
    """One finished run's record.

    Wall time and SPS cover every session of a resumed run. They are rebuilt from metrics.csv, because the
    summaries of runs trained before resumes carried totals over hold only the last session."""
    from canter.training.logger import totals_until
    from canter.training.run_folder import metrics_file

    evaluation = read_object(run_dir / EVAL_FILE) or {}
    summary = read_usable_summary(run_dir) or {}
    wall = float(summary["wall_seconds"]) if "wall_seconds" in summary else None
    sps = float(summary["sps"]) if "sps" in summary else None
    metrics = metrics_file(run_dir)
    if "global_step" in summary and metrics.is_file():
        totals = totals_until(metrics, int(summary["global_step"]))
        if totals.train_seconds > 0:
            wall, sps = totals.wall_seconds, int(summary["global_step"]) / totals.train_seconds
    trained_with = summary.get("trained_with")
    return SeedRecord(
        seed,
        float(evaluation["mean"]) if is_number(evaluation.get("mean")) else None,
        wall,
        sps,
        tuple(int(s) for s in trained_with) if isinstance(trained_with, list) else None,
    )


def seed_record(run_dir: Path, seed: int) -> dict[str, Any]:
    """`read_seed` as JSON, for the benchmark scripts, which add the run's own files to it."""
    return read_seed(run_dir, seed).to_json()


@dataclass(frozen=True)
class CellResult:
    """A cell's row of the table, and its seeds' final evaluations for the statistics."""

    cell: str
    env: str
    algo: str
    values: tuple[tuple[str, str], ...]  # the cell's grid values
    seeds: int  # how many seeds have an evaluation
    return_mean: float
    return_std: float
    return_median: float
    seed_returns: tuple[float, ...]
    wall_minutes: float
    sps: float
    per_seed: bool  # wall minutes and SPS are means per seed, not of one process that trained them all

    def to_json(self) -> dict[str, Any]:
        """The form the benchmark scripts read and extend."""
        return {
            "cell": self.cell,
            "env": self.env,
            "algo": self.algo,
            "values": dict(self.values),
            "seeds": self.seeds,
            "return_mean": self.return_mean,
            "return_std": self.return_std,
            "return_median": self.return_median,
            "seed_returns": list(self.seed_returns),
            "wall_minutes": self.wall_minutes,
            "sps": self.sps,
            "per_seed": self.per_seed,
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> CellResult:
        return cls(
            data["cell"],
            data["env"],
            data["algo"],
            tuple(data["values"].items()),
            data["seeds"],
            data["return_mean"],
            data["return_std"],
            data["return_median"],
            tuple(data["seed_returns"]),
            data["wall_minutes"],
            data["sps"],
            data["per_seed"],
        )


def cell_result(cell: Cell, settings: BenchSettings, bench_dir: Path) -> CellResult:
    return combine_seeds(cell, [read_seed(cell.run_dir(bench_dir, s), s) for s in settings.seeds])


def combine_seeds(cell: Cell, records: Sequence[SeedRecord]) -> CellResult:
    """Final deterministic eval (mean over seeds of each seed's mean, std over seeds), wall time and SPS. A group
    of seeds trained together has one wall time (its slowest seed's) and their steps per second add up. Seeds
    trained as separate jobs (td3, ddpg, sac) may have run at different times, so a sum of their rates would
    describe no real run: for them it is the mean per seed, of wall time and of SPS; and so for a cell whose seeds
    did not all train in one group (a seed added by a later bench, `per_seed`)."""
    from canter.algos import seeds_train_apart

    evals = [r.eval_mean for r in records if r.eval_mean is not None]
    walls = [r.wall_seconds for r in records if r.wall_seconds is not None]
    sps = [r.sps for r in records if r.sps is not None]
    seeds = {r.seed for r in records}
    split = any(r.trained_with is not None and not seeds <= set(r.trained_with) for r in records)
    apart = seeds_train_apart(cell.algo) or split
    return CellResult(
        cell=cell.name,
        env=cell.env_id,
        algo=cell.algo,
        values=tuple(cell.values),
        seeds=len(evals),
        return_mean=float(np.mean(evals)) if evals else math.nan,
        return_std=float(np.std(evals)) if evals else math.nan,
        return_median=float(np.median(evals)) if evals else math.nan,
        seed_returns=tuple(evals),
        wall_minutes=float(np.mean(walls) if apart else np.max(walls)) / 60 if walls else math.nan,
        sps=float(np.mean(sps) if apart else np.sum(sps)) if sps else math.nan,
        per_seed=apart,
    )


def combine_records(cell: Cell, records: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """`combine_seeds` of records in their JSON form, as JSON: the benchmark scripts' records carry keys of their
    own, and their cell results get more."""
    return combine_seeds(cell, [SeedRecord.from_json(r) for r in records]).to_json()


def _cell_results(results: Sequence[CellResult | Mapping[str, Any]]) -> list[CellResult]:
    """The benchmark scripts give `combine_records`' JSON form."""
    return [r if isinstance(r, CellResult) else CellResult.from_json(r) for r in results]


def published_for(algo: str, env_id: str, total_steps: int, data: dict[str, Any] | None = None) -> str:
    """'CR 2383±272, TS 2609±701' for this algo and env at the bench's budget (else at REFERENCE_STEPS, marked:
    ' @1M')."""
    data = data or published_scores()
    rows = [s for s in data["score"] if s["algo"] == algo and s["env"] == env_base(env_id)]
    at_budget = [s for s in rows if s["steps"] == total_steps]
    at_reference = [s for s in rows if s["steps"] == REFERENCE_STEPS]
    chosen, mark = (at_budget, "") if at_budget else (at_reference, f" @{REFERENCE_STEPS / 1e6:g}M")
    parts = [f"{s['source']} {s['mean']:.0f}" + (f"±{s['std']:.0f}" if "std" in s else "") for s in chosen]
    return ", ".join(parts) + mark if parts else ""


def results_table(
    results: Sequence[CellResult | Mapping[str, Any]], keys: list[str], total_steps: int
) -> tuple[str, str]:
    """(markdown, csv) of the results."""
    from canter.algos import seeds_train_apart

    rows = _cell_results(results)
    data = published_scores()
    short = [k.split(".", 1)[1] for k in keys]
    header = (
        ["env", "algo"]
        + short
        + ["return (mean ± std over seeds)", "median", "seeds", "cell wall min", "cell SPS", "published"]
    )
    md = ["| " + " | ".join(header) + " |", "|" + "---|" * 2 + "---|" * len(short) + "---:|---:|---:|---:|---:|---|"]
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(
        ["env", "algo"]
        + keys
        + ["return_mean", "return_std", "return_median", "seeds", "wall_minutes", "sps", "published"]
    )
    for r in rows:
        reference = published_for(r.algo, r.env, total_steps, data)
        grid_values = [dict(r.values).get(k, "") for k in keys]
        md.append(
            "| "
            + " | ".join(
                [r.env, r.algo]
                + grid_values
                + [
                    f"{r.return_mean:.1f} ± {r.return_std:.1f}",
                    f"{r.return_median:.1f}",
                    str(r.seeds),
                    f"{r.wall_minutes:.1f}",
                    f"{r.sps:,.0f}",
                    reference,
                ]
            )
            + " |"
        )
        writer.writerow(
            [r.env, r.algo]
            + grid_values
            + [
                f"{r.return_mean:.3f}",
                f"{r.return_std:.3f}",
                f"{r.return_median:.3f}",
                r.seeds,
                f"{r.wall_minutes:.3f}",
                f"{r.sps:.1f}",
                reference,
            ]
        )
    sources = data["sources"]
    apart = sorted({r.algo for r in rows if seeds_train_apart(r.algo)})
    if apart:
        md += [
            "",
            f"Cell wall min and cell SPS of {', '.join(apart)}: the mean per seed, since each of their seeds "
            "trains as a job of its own (for the other algorithms, a cell's seeds train together: its wall "
            "time, and the steps per second of all its seeds).",
        ]
    split = [r.cell for r in rows if r.per_seed and not seeds_train_apart(r.algo)]
    if split:
        md += [
            "",
            f"Cell wall min and cell SPS of {', '.join(split)}: the mean per seed, since their seeds did not all "
            "train in one process (a seed added by a later bench trains in a group of its own).",
        ]
    md += [
        "",
        "Published: "
        + "; ".join(f"{k} = {v['name']} ({v['where']}; {v['measure']})" for k, v in sources.items())
        + ".",
    ]
    return "\n".join(md) + "\n", buffer.getvalue()


def plot_env(run_dirs: list[Path], path: Path) -> None:
    """One figure per env through `canter plot`: one curve (mean over seeds, with a band) per algorithm and grid
    values, training return against env steps."""
    from canter.files import write_output
    from canter.use.curves import load_run
    from canter.use.plot import render_runs

    runs = []
    for run_dir in run_dirs:
        # A folder whose job was killed before it logged (its cell trained on another machine since) has no curve.
        try:
            runs.append(load_run(run_dir))
        except CanterError as exc:
            print(f"canter: note: {path.name} leaves out {run_dir.name}: {exc}", file=sys.stderr)
    if not runs:
        return
    returns = [run.columns.get("episodic_return") for run in runs]
    if not any(r is not None and np.isfinite(r).any() for r in returns):
        print(
            f"canter: note: no plot {path.name}: no training episode ended within the budget; a larger "
            "--total-steps gives one",
            file=sys.stderr,
        )
        return
    write_output(path, render_runs(runs, "png", ["episodic_return"], smooth=5)[0])


def method_label(result: CellResult, keys: list[str]) -> str:
    """A cell's algorithm and grid values without its env: the cells of one method on several envs."""
    values = dict(result.values)
    return ", ".join([result.algo] + [f"{k.split('.', 1)[1]}={values[k]}" for k in keys])


def results_scoreboard(results: Sequence[CellResult], keys: list[str], reps: int | None = None) -> Scoreboard | None:
    """IQM, mean, median and optimality gap with their intervals, per cell and per method across envs, the
    performance profiles and the probabilities of improvement (`canter.use.scoreboard`) of the seeds' final
    evaluations. None when no cell has an evaluated seed."""
    from canter.use.scoreboard import EVAL_SOURCE, RunScore, build_scoreboard
    from canter.use.statistics import REPS

    left_out = {r.cell for r in diverged_cells(results)}
    scores = [
        RunScore(method_label(r, keys), r.env, r.algo, value, f"{r.cell}#{i}")
        for r in results
        if r.cell not in left_out
        for i, value in enumerate(r.seed_returns)
    ]
    return build_scoreboard(scores, EVAL_SOURCE, reps=reps or REPS) if scores else None


def diverged_cells(results: Sequence[CellResult]) -> list[CellResult]:
    """The cells with a seed whose final evaluation is not finite. They stay out of the statistics whole: leaving
    out only the failed seed would score the cell as if it had not failed."""
    return [r for r in results if not all(math.isfinite(v) for v in r.seed_returns)]


def results_markdown(
    results: Sequence[CellResult | Mapping[str, Any]], keys: list[str], total_steps: int
) -> tuple[str, str, str]:
    """(results.md: the table, then the statistics; results.csv; statistics.json, empty without scores)."""
    from canter.use.scoreboard import DIVERGED

    rows = _cell_results(results)
    markdown, table_csv = results_table(rows, keys, total_steps)
    diverged = diverged_cells(rows)
    if diverged:
        markdown += (
            f"\nLeft out of the statistics: {', '.join(r.cell for r in diverged)}, each with {DIVERGED} in a "
            "seed's eval.json.\n"
        )
    board = results_scoreboard(rows, keys)
    if board is None:
        return markdown, table_csv, ""
    return markdown + "\n## Statistics\n\n" + board.markdown(), table_csv, board.json()


RESULTS_TABLE = "results.md"  # the table, then the statistics
RESULTS_CSV = "results.csv"
STATISTICS_FILE = "statistics.json"  # absent without scores
RESULT_FILES = (RESULTS_TABLE, RESULTS_CSV, STATISTICS_FILE)


def write_results(cells: list[Cell], results: list[CellResult], settings: BenchSettings, bench_dir: Path) -> str:
    from canter.files import write_output
    from canter.training.run_folder import metrics_file

    keys = varying_keys(cells)
    markdown, table_csv, statistics_json = results_markdown(results, keys, settings.total_steps)
    write_output(bench_dir / RESULTS_TABLE, markdown.encode())
    write_output(bench_dir / RESULTS_CSV, table_csv.encode())
    if statistics_json:
        write_output(bench_dir / STATISTICS_FILE, statistics_json.encode())
    for env_id in dict.fromkeys(c.env_id for c in cells):
        run_dirs = [cell.run_dir(bench_dir, seed) for cell in cells if cell.env_id == env_id for seed in settings.seeds]
        run_dirs = [d for d in run_dirs if metrics_file(d).is_file() and (d / CONFIG_FILE).is_file()]
        if run_dirs:
            plot_env(run_dirs, plot_path(bench_dir, env_id))
    return markdown


def plot_path(bench_dir: Path, env_id: str) -> Path:
    return bench_dir / f"plot_{safe_name(env_id.split(':')[-1])}.png"


def check_results_writable(cells: list[Cell], bench_dir: Path) -> None:
    """Before any job starts, as eval and report check their outputs: each file the bench writes once the jobs have
    ended is a plain file or absent (the atomic rename would replace a link or fail on a folder), in a folder that
    takes new files."""
    paths = [bench_dir / name for name in RESULT_FILES]
    paths += [plot_path(bench_dir, env_id) for env_id in dict.fromkeys(c.env_id for c in cells)]
    for path in paths:
        if path.is_symlink() or (path.exists() and not path.is_file()):
            raise CanterError(
                f"cannot write {path}: it is not a plain file (a folder or a link), and the bench writes its results "
                f"there; move it away, then run the command again"
            )
    check_writable(paths[0])
