"""`canter bench`: a grid of algorithms x envs x hyperparameter values x seeds, each run an ordinary run folder.

A cell is one (algo, env, grid values) combination. A job is what one child process trains
(`canter.orchestrate.jobs`): all of a cell's seeds together as one vmapped group, or, for the off-policy algorithms
(`canter.algos.seeds_train_apart`), one seed; up to `--jobs` jobs run at once. Run folders have deterministic
names built from the env, the algorithm, every grid value and the seed, so re-running the same command finds them:
finished runs are skipped, runs stopped after a checkpoint resume, and only what is missing trains. Each finished
run's final policy is evaluated deterministically (`eval.json`), and the bench writes `results.md` (the table, then
the statistics of `canter.use.scoreboard`: aggregates with 95% bootstrap intervals, profiles, probabilities of
improvement), `results.csv`, `statistics.json` and a plot per env.

With `--storage`, the jobs are the trials of an Optuna study: each job is enqueued once, under a key that holds its
name, seeds, step budget, evaluation episodes and a digest of its experiment (`job_key`), so workers on several
machines share the grid the way `canter tune` workers share a study, and a re-run with more seeds or steps queues
what it adds.

With `--track`, each seed is a tracker run, the seeds of a cell in one group (`canter.training.trackers`); a job
that resumes a seed continues its tracker runs.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import itertools
import math
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from canter.config.algorithms import reads_key, unread_key_error
from canter.config.build import build_config
from canter.config.overrides import all_keys
from canter.config.schema import Config
from canter.config.serialize import to_toml
from canter.config.values import coerce, field_types
from canter.errors import CanterError
from canter.files import WriteError, check_writable, make_folder
from canter.orchestrate.jobs import (
    EVAL_FILE,
    JobSpec,
    exit_text,
    failure_reason,
    is_number,
    job_layout,
    read_object,
    read_summary,
    run_status,
    run_workers,
    start_job,
    stop_jobs,
    warn_if_more_jobs_than_cores,
)
from canter.orchestrate.study import check_at_least, claim_study, describe_url, normalize_url, study_storage
from canter.training.run_folder import CONFIG_FILE, METRICS_FILE
from canter.training.trackers import TrackSpec, check_trackers, group_name, open_groups
from canter.use.reference_scores import published_scores

if TYPE_CHECKING:
    from canter.orchestrate.study import Outcome
    from canter.use.scoreboard import Scoreboard

# Keys the bench sets itself, each from its own flag (run.algo and env.id as grid axes stand in for --algos and
# --envs).
_FORBIDDEN = {"run.seed": "--seeds", "run.total_steps": "--total-steps", "run.out_dir": "--out"}


@dataclass(frozen=True)
class BenchSettings:
    algos: tuple[str, ...]
    envs: tuple[str, ...]
    seeds: tuple[int, ...]
    total_steps: int
    grid: tuple[tuple[str, tuple[str, ...]], ...] = ()  # (key, raw values) in the order given
    jobs: int = 1
    out_dir: str = "bench"
    preset: str = "fast"
    config_file: str | None = None
    sets: tuple[str, ...] = ()
    eval_episodes: int = 10
    storage_url: str | None = None
    study_name: str | None = None
    heartbeat_seconds: int = 60
    poll_seconds: float = 0.5
    track: TrackSpec = field(default_factory=TrackSpec)  # `--track`: a tracker run per seed, a group per cell

    def __post_init__(self) -> None:
        check_at_least(
            [
                ("--jobs", self.jobs, 1),
                ("--episodes (eval_episodes)", self.eval_episodes, 1),
                ("--heartbeat (heartbeat_seconds)", self.heartbeat_seconds, 1),
            ]
        )


@dataclass(frozen=True)
class Cell:
    algo: str
    env_id: str
    values: tuple[tuple[str, str], ...]  # every grid axis: (key, canonical value)
    config: Config

    @property
    def name(self) -> str:
        parts = [self.env_id.split(":")[-1], self.algo] + [f"{key}={value}" for key, value in self.values]
        return "__".join(_safe(p) for p in parts)

    def run_dir(self, bench_dir: Path, seed: int) -> Path:
        return bench_dir / f"{self.name}__s{seed}"


@dataclass(frozen=True)
class Job:
    """The seeds of one cell that one child process trains together."""

    cell: Cell
    seeds: tuple[int, ...]
    apart: bool  # one seed of a cell whose seeds train apart: the seed is part of the name

    @property
    def name(self) -> str:
        return f"{self.cell.name}__s{self.seeds[0]}" if self.apart else self.cell.name


def make_jobs(cells: list[Cell], seeds: tuple[int, ...]) -> list[Job]:
    from canter.algos import seeds_train_apart

    jobs = []
    for cell in cells:
        if seeds_train_apart(cell.algo):
            jobs += [Job(cell, (seed,), True) for seed in seeds]
        else:
            jobs.append(Job(cell, tuple(seeds), False))
    return jobs


def _safe(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_.=," else "-" for c in text)


def canonical(value: Any) -> str:
    if isinstance(value, tuple):
        return "-".join(map(str, value))
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "none"
    return repr(value) if isinstance(value, float) else str(value)


def parse_grid_arg(text: str) -> tuple[str, tuple[str, ...]]:
    key, sep, values = text.partition("=")
    key = key.strip()
    items = tuple(v.strip() for v in values.split(",") if v.strip())
    if not sep or not key or not items:
        raise CanterError(f"--grid expects KEY=V1,V2,... such as ppo.ent_coef=0.01,1e-4,0; got {text!r}")
    return key, items


def make_cells(settings: BenchSettings) -> list[Cell]:
    """Every cell, each with its validated config; refuses an unknown algo, env, key or value before any work."""
    from canter.algos import check_algorithm_name
    from canter.envs import resolve_backend

    algos, envs = list(settings.algos), list(settings.envs)
    axes: list[tuple[str, list[str]]] = []
    seen: set[str] = set()
    known = set(all_keys())
    for key, raw in settings.grid:
        if key in seen:
            raise CanterError(f"--grid {key} is given twice; list all its values in one --grid")
        seen.add(key)
        if key in _FORBIDDEN:
            raise CanterError(f"--grid {key} is not a grid axis; use {_FORBIDDEN[key]}")
        if key == "run.algo":
            algos = list(raw)
            continue
        if key == "env.id":
            envs = list(raw)
            continue
        if key not in known:
            import difflib

            close = difflib.get_close_matches(key, sorted(known), n=3, cutoff=0.5)
            raise CanterError(
                f"--grid: unknown config key '{key}'" + (f"; did you mean {', '.join(close)}?" if close else "")
            )
        section, _, name = key.partition(".")
        values = [canonical(coerce(key, field_types(section)[name], v)) for v in raw]
        if len(set(values)) != len(values):
            raise CanterError(f"--grid {key} repeats a value")
        axes.append((key, values))
    if not algos or not envs or not settings.seeds:
        raise CanterError("the bench needs at least one algorithm, one env and one seed")
    for algo in algos:
        check_algorithm_name(algo)
    for key, _ in axes:
        for algo in algos:
            if not reads_key(algo, key):
                raise CanterError(f"--grid {key}: {unread_key_error(algo, key)}, or bench {algo} in a bench of its own")
    # A --set applies to the cells whose algorithm reads it, so one bench can carry td3.* and sac.* settings.
    set_keys = {item.partition("=")[0].strip(): item for item in settings.sets}
    for key in set_keys:
        if key in _FORBIDDEN:  # the bench's own value would replace it
            raise CanterError(
                f"{key} is set by the bench's {_FORBIDDEN[key]}; give {_FORBIDDEN[key]} rather than --set {key}"
            )
        if key in known and algos and not any(reads_key(algo, key) for algo in algos):
            raise CanterError(f"--set {unread_key_error(algos[0], key)}")
    for env_id in envs:
        resolve_backend(env_id, "auto")
    cells = []
    for algo, env_id in itertools.product(algos, envs):
        for combo in itertools.product(*(values for _, values in axes)):
            pairs = tuple(zip((key for key, _ in axes), combo))
            sets = [item for key, item in set_keys.items() if key not in known or reads_key(algo, key)]
            sets += [f"{key}={value}" for key, value in pairs]
            try:
                config = build_config(
                    env_id,
                    preset=settings.preset,
                    config_file=settings.config_file,
                    sets=sets,
                    seed=settings.seeds[0],
                    total_steps=settings.total_steps,
                    algo=algo,
                )
            except CanterError as exc:
                where = ", ".join([algo, env_id] + [f"{k}={v}" for k, v in pairs])
                raise CanterError(f"cell ({where}): {exc}") from None
            cells.append(Cell(algo, env_id, pairs, config))
    return cells


def varying_keys(cells: list[Cell]) -> list[str]:
    """The grid keys whose value differs between cells: they label the table rows."""
    keys = [key for key, _ in cells[0].values] if cells else []
    return [k for i, k in enumerate(keys) if len({c.values[i][1] for c in cells}) > 1]


def job_spec(job: Job, settings: BenchSettings, bench_dir: Path) -> JobSpec:
    cell = job.cell
    config = replace(cell.config, run=replace(cell.config.run, out_dir=str(bench_dir)))
    return JobSpec(
        to_toml(config),
        {s: str(cell.run_dir(bench_dir, s).resolve()) for s in job.seeds},
        settings.eval_episodes,
        settings.track,
    )


def seeds_finished(cell: Cell, seeds: tuple[int, ...], settings: BenchSettings, bench_dir: Path) -> bool:
    """Each seed trained to the budget, with its final evaluation of its newest checkpoint (one left from a smaller
    budget, whose extension stopped before the evaluations, does not count; a run restored from a results archive
    keeps its evaluation and no checkpoint)."""
    from canter.training import checkpoint

    for seed in seeds:
        run_dir = cell.run_dir(bench_dir, seed)
        if run_status(run_dir, settings.total_steps, cell.config.run.stop_at_return) != "done":
            return False
        evaluation = read_object(run_dir / EVAL_FILE) or {}  # a damaged one is evaluated again
        newest = checkpoint.list_checkpoints(run_dir)  # none in a run restored from a results archive
        if (
            evaluation.get("episodes") != settings.eval_episodes
            or (newest and evaluation.get("checkpoint") != newest[-1].name)
            or not is_number(evaluation.get("mean"))
        ):
            return False
    return True


def check_existing_runs(cells: list[Cell], settings: BenchSettings, bench_dir: Path) -> None:
    """Refuse a bench folder whose run folders were trained with other settings than this command gives their
    cells (a changed --set, --config or preset): reusing them would put old results under the new settings. A run
    folder belongs to its cell when it is a seed of the same experiment (`canter.config.experiment`), so a larger
    --total-steps extends finished runs."""
    from canter.config.experiment import experiment_key
    from canter.training.run_folder import read_config

    for cell in cells:
        expected = dict(experiment_key(cell.config))
        for seed in settings.seeds:
            saved = cell.run_dir(bench_dir, seed) / CONFIG_FILE
            if not saved.is_file():
                continue
            try:
                found = dict(experiment_key(read_config(saved.parent)))
            except (CanterError, OSError):
                continue  # unreadable: the run is not usable anyway, and training it anew rewrites the file
            differing = [k for k in expected if found.get(k) != expected[k]]
            if differing:
                key = differing[0]
                more = f" and {len(differing) - 1} more keys" if len(differing) > 1 else ""
                raise CanterError(
                    f"{saved.parent} was trained with {key}={found.get(key)!r}{more}, but this bench "
                    f"gives {key}={expected[key]!r}; use a new --out, or delete that folder to retrain it"
                )


# ---------------------------------------------------------------------------------------------------- results


def seed_record(run_dir: Path, seed: int) -> dict[str, Any]:
    """What the table needs of one finished run: its final eval mean, wall seconds and SPS (None where missing).

    Wall time and SPS cover every session of a resumed run. They are rebuilt from metrics.csv, because the
    summaries of runs trained before resumes carried totals over hold only the last session."""
    from canter.training.logger import totals_until
    from canter.training.run_folder import metrics_file

    evaluation = read_object(run_dir / EVAL_FILE) or {}
    summary = read_summary(run_dir) or {}
    wall = float(summary["wall_seconds"]) if "wall_seconds" in summary else None
    sps = float(summary["sps"]) if "sps" in summary else None
    metrics = metrics_file(run_dir)
    if "global_step" in summary and metrics.is_file():
        totals = totals_until(metrics, int(summary["global_step"]))
        if totals["train_seconds"] > 0:
            wall, sps = totals["wall_seconds"], int(summary["global_step"]) / totals["train_seconds"]
    trained_with = summary.get("trained_with")
    return {
        "seed": seed,
        "eval_mean": float(evaluation["mean"]) if is_number(evaluation.get("mean")) else None,
        "wall_seconds": wall,
        "sps": sps,
        # The seeds its last session trained beside; None for a summary written before that was kept.
        "trained_with": [int(s) for s in trained_with] if isinstance(trained_with, list) else None,
    }


def cell_result(cell: Cell, settings: BenchSettings, bench_dir: Path) -> dict[str, Any]:
    return combine_records(cell, [seed_record(cell.run_dir(bench_dir, s), s) for s in settings.seeds])


def combine_records(cell: Cell, records: list[dict[str, Any]]) -> dict[str, Any]:
    """Final deterministic eval (mean over seeds of each seed's mean, std over seeds), wall time and SPS. A group
    of seeds trained together has one wall time (its slowest seed's) and their steps per second add up. Seeds
    trained as separate jobs (td3, ddpg, sac) may have run at different times, so a sum of their rates would
    describe no real run: for them it is the mean per seed, of wall time and of SPS; and so for a cell whose seeds
    did not all train in one group (a seed added by a later bench, `per_seed`)."""
    from canter.algos import seeds_train_apart

    evals = [r["eval_mean"] for r in records if r["eval_mean"] is not None]
    walls = [r["wall_seconds"] for r in records if r["wall_seconds"] is not None]
    sps = [r["sps"] for r in records if r["sps"] is not None]
    seeds = {r["seed"] for r in records}
    split = any(r.get("trained_with") is not None and not seeds <= set(r["trained_with"]) for r in records)
    apart = seeds_train_apart(cell.algo) or split
    return {
        "cell": cell.name,
        "env": cell.env_id,
        "algo": cell.algo,
        "values": dict(cell.values),
        "seeds": len(evals),
        "return_mean": float(np.mean(evals)) if evals else math.nan,
        "return_std": float(np.std(evals)) if evals else math.nan,
        "return_median": float(np.median(evals)) if evals else math.nan,
        "seed_returns": evals,
        "wall_minutes": float(np.mean(walls) if apart else np.max(walls)) / 60 if walls else math.nan,
        "sps": float(np.mean(sps) if apart else np.sum(sps)) if sps else math.nan,
        "per_seed": apart,
    }


def published_for(algo: str, env_id: str, total_steps: int, data: dict[str, Any] | None = None) -> str:
    """'CR 2383±272, TS 2609±701' for this algo and env at the bench's budget (else at 1M steps, marked)."""
    data = data or published_scores()
    base = env_id.split(":")[-1].rsplit("-v", 1)[0]
    rows = [s for s in data["score"] if s["algo"] == algo and s["env"] == base]
    at_budget = [s for s in rows if s["steps"] == total_steps]
    chosen, mark = (at_budget, "") if at_budget else ([s for s in rows if s["steps"] == 1_000_000], " @1M")
    parts = [f"{s['source']} {s['mean']:.0f}" + (f"±{s['std']:.0f}" if "std" in s else "") for s in chosen]
    return ", ".join(parts) + mark if parts else ""


def results_table(results: list[dict[str, Any]], keys: list[str], total_steps: int) -> tuple[str, str]:
    """(markdown, csv) of the results."""
    from canter.algos import seeds_train_apart

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
    for r in results:
        reference = published_for(r["algo"], r["env"], total_steps, data)
        grid_values = [r["values"].get(k, "") for k in keys]
        md.append(
            "| "
            + " | ".join(
                [r["env"], r["algo"]]
                + grid_values
                + [
                    f"{r['return_mean']:.1f} ± {r['return_std']:.1f}",
                    f"{r['return_median']:.1f}",
                    str(r["seeds"]),
                    f"{r['wall_minutes']:.1f}",
                    f"{r['sps']:,.0f}",
                    reference,
                ]
            )
            + " |"
        )
        writer.writerow(
            [r["env"], r["algo"]]
            + grid_values
            + [
                f"{r['return_mean']:.3f}",
                f"{r['return_std']:.3f}",
                f"{r['return_median']:.3f}",
                r["seeds"],
                f"{r['wall_minutes']:.3f}",
                f"{r['sps']:.1f}",
                reference,
            ]
        )
    sources = data["sources"]
    apart = sorted({r["algo"] for r in results if seeds_train_apart(r["algo"])})
    if apart:
        md += [
            "",
            f"Cell wall min and cell SPS of {', '.join(apart)}: the mean per seed, since each of their seeds "
            "trains as a job of its own (for the other algorithms, a cell's seeds train together: its wall "
            "time, and the steps per second of all its seeds).",
        ]
    split = [r["cell"] for r in results if r.get("per_seed") and not seeds_train_apart(r["algo"])]
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
    from canter.use.plot import load_run, render_runs

    runs = [load_run(d) for d in run_dirs]
    returns = [run.columns.get("episodic_return") for run in runs]
    if not any(r is not None and np.isfinite(r).any() for r in returns):
        print(
            f"canter: note: no plot {path.name}: no training episode ended within the budget; a larger "
            "--total-steps gives one",
            file=sys.stderr,
        )
        return
    write_output(path, render_runs(runs, "png", ["episodic_return"], smooth=5)[0])


def method_label(result: dict[str, Any], keys: list[str]) -> str:
    """A cell's algorithm and grid values without its env: the cells of one method on several envs."""
    return ", ".join([result["algo"]] + [f"{k.split('.', 1)[1]}={result['values'][k]}" for k in keys])


def results_scoreboard(results: list[dict[str, Any]], keys: list[str], reps: int | None = None) -> Scoreboard | None:
    """IQM, mean, median and optimality gap with their intervals, per cell and per method across envs, the
    performance profiles and the probabilities of improvement (`canter.use.scoreboard`) of the seeds' final
    evaluations. None when no cell has an evaluated seed."""
    from canter.use.scoreboard import EVAL_SOURCE, RunScore, build_scoreboard
    from canter.use.statistics import REPS

    left_out = {r["cell"] for r in diverged_cells(results)}
    scores = [
        RunScore(method_label(r, keys), r["env"], r["algo"], value, f"{r['cell']}#{i}")
        for r in results
        if r["cell"] not in left_out
        for i, value in enumerate(r["seed_returns"])
    ]
    return build_scoreboard(scores, EVAL_SOURCE, reps=reps or REPS) if scores else None


def diverged_cells(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The cells with a seed whose final evaluation is not finite. They stay out of the statistics whole: leaving
    out only the failed seed would score the cell as if it had not failed."""
    return [r for r in results if not all(math.isfinite(v) for v in r["seed_returns"])]


def results_markdown(results: list[dict[str, Any]], keys: list[str], total_steps: int) -> tuple[str, str, str]:
    """(results.md: the table, then the statistics; results.csv; statistics.json, empty without scores)."""
    from canter.use.scoreboard import DIVERGED

    markdown, table_csv = results_table(results, keys, total_steps)
    diverged = diverged_cells(results)
    if diverged:
        markdown += (
            f"\nLeft out of the statistics: {', '.join(r['cell'] for r in diverged)}, each with {DIVERGED} in a "
            "seed's eval.json.\n"
        )
    board = results_scoreboard(results, keys)
    if board is None:
        return markdown, table_csv, ""
    return markdown + "\n## Statistics\n\n" + board.markdown(), table_csv, board.json()


def write_results(cells: list[Cell], results: list[dict[str, Any]], settings: BenchSettings, bench_dir: Path) -> str:
    from canter.files import write_output

    keys = varying_keys(cells)
    markdown, table_csv, statistics_json = results_markdown(results, keys, settings.total_steps)
    write_output(bench_dir / "results.md", markdown.encode())
    write_output(bench_dir / "results.csv", table_csv.encode())
    if statistics_json:
        write_output(bench_dir / "statistics.json", statistics_json.encode())
    for env_id in dict.fromkeys(c.env_id for c in cells):
        run_dirs = [cell.run_dir(bench_dir, seed) for cell in cells if cell.env_id == env_id for seed in settings.seeds]
        run_dirs = [d for d in run_dirs if (d / METRICS_FILE).is_file() and (d / CONFIG_FILE).is_file()]
        if run_dirs:
            plot_env(run_dirs, plot_path(bench_dir, env_id))
    return markdown


def plot_path(bench_dir: Path, env_id: str) -> Path:
    return bench_dir / f"plot_{_safe(env_id.split(':')[-1])}.png"


RESULT_FILES = ("results.md", "results.csv", "statistics.json")


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


# ------------------------------------------------------------------------------------------------------- running


STOPPED_EARLY = "stopped before its budget (a signal or run.max_minutes); it is checkpointed and a re-run resumes it"


def seed_steps(job: Job, bench_dir: Path) -> list[int | None]:
    """Each seed's newest checkpoint step, which its job goes on from; None for a seed that trains anew."""
    from canter.training import checkpoint

    found = [checkpoint.list_checkpoints(job.cell.run_dir(bench_dir, seed)) for seed in job.seeds]
    return [checkpoint.step_of(f[-1]) if f else None for f in found]


def start_text(job: Job, steps: list[int | None], total_steps: int) -> str:
    """The line a job's start prints: whether it trains anew, resumes checkpointed runs (from which step), or only
    evaluates runs trained to the budget."""
    seeds = f"seeds {','.join(map(str, job.seeds))}"
    if all(step is None for step in steps):
        return f"start {job.name} ({seeds})"
    if all(step is not None and step >= total_steps for step in steps):
        return f"evaluate {job.name} ({seeds}; trained to the budget)"
    if len(set(steps)) == 1:
        return f"resume {job.name} ({seeds}) from step {steps[0]:,}"
    each = [
        f"seed {seed} " + ("anew" if step is None else f"from step {step:,}") for seed, step in zip(job.seeds, steps)
    ]
    return f"resume {job.name} ({seeds}): {', '.join(each)}"


def run_local(cells: list[Cell], settings: BenchSettings, bench_dir: Path) -> dict[str, str]:
    """Run the unfinished jobs, up to `jobs` child processes at once; returns {cell name: failure reason}."""
    jobs = make_jobs(cells, settings.seeds)
    finished = [seeds_finished(job.cell, job.seeds, settings, bench_dir) for job in jobs]
    if any(finished):
        print(f"{sum(finished)} of {len(jobs)} jobs already done", flush=True)
    for job in itertools.compress(jobs, finished):
        print(f"skip {job.name} (finished)")
    pending = [job for job, done in zip(jobs, finished) if not done]
    slots = job_layout(settings.jobs) if settings.jobs > 1 else [{}]
    running: dict[int, tuple[Job, Any, float]] = {}
    failures: dict[str, str] = {}
    try:
        while pending or running:
            for slot, caps in enumerate(slots):
                if slot not in running and pending:
                    job = pending.pop(0)
                    line = start_text(job, seed_steps(job, bench_dir), settings.total_steps)  # before the job saves any
                    proc = start_job(job_spec(job, settings, bench_dir), bench_dir / ".cells" / job.name, caps)
                    running[slot] = (job, proc, time.monotonic())
                    print(line, flush=True)
            for slot, (job, proc, started) in list(running.items()):
                code = proc.poll()
                if code is None:
                    continue
                del running[slot]
                if code == 0 and not seeds_finished(job.cell, job.seeds, settings, bench_dir):
                    # The child exits cleanly when a signal or run.max_minutes stops it early, checkpointed.
                    failures.setdefault(job.cell.name, STOPPED_EARLY)
                    print(f"STOP  {job.name}: {STOPPED_EARLY}", flush=True)
                elif code == 0:
                    print(f"done  {job.name} in {(time.monotonic() - started) / 60:.1f} min", flush=True)
                else:
                    reason = failure_reason(bench_dir / ".cells" / job.name, code)
                    failures.setdefault(job.cell.name, reason)
                    print(f"FAIL  {job.name}: {reason}", flush=True)
            time.sleep(settings.poll_seconds)
    finally:
        stop_jobs(proc for _, proc, _ in running.values())
    return failures


JOB_ATTR = "job"


def job_key(job: Job, settings: BenchSettings) -> str:
    """What a stored trial of the grid stands for: the job and the settings its records answer to, so that a re-run
    with more seeds, another budget, another episode count or another experiment under the same cell name (a bench
    with other --set, --preset or --config values sharing the storage) queues the job again rather than reuse
    another's records."""
    from canter.config.experiment import experiment_key

    seeds = ",".join(map(str, job.seeds))
    experiment = hashlib.sha1(repr(experiment_key(job.cell.config)).encode()).hexdigest()[:12]
    return (
        f"{job.name}|seeds={seeds}|steps={settings.total_steps}|episodes={settings.eval_episodes}"
        f"|experiment={experiment}"
    )


def trial_job(trial: Any) -> str | None:
    return trial.user_attrs.get(JOB_ATTR)


def _job_trial(study: Any, trial: Any, jobs: dict[str, Job], settings: BenchSettings, bench_dir: Path) -> Outcome:
    from optuna.trial import TrialState

    from canter.orchestrate.study import Outcome

    key = trial_job(trial)
    if key is None:  # asked for when another worker had just taken the last queued job
        return Outcome("fail", reason="surplus: no queued job was left for this trial")
    if key not in jobs:
        return Outcome("fail", reason=f"{key} is not in this worker's grid; run the same command on every worker")
    for other in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.RUNNING)):
        if (
            trial_job(other) == key
            and other.number != trial.number
            and (other.state == TrialState.COMPLETE or other.number < trial.number)
        ):
            return Outcome("fail", reason=f"duplicate: trial {other.number} has this job")
    job = jobs[key]
    folder = bench_dir / ".cells" / job.name
    print(f"{start_text(job, seed_steps(job, bench_dir), settings.total_steps)}; trial {trial.number}", flush=True)
    started = time.monotonic()
    proc = start_job(job_spec(job, settings, bench_dir), folder)
    try:
        code = proc.wait()
    finally:
        stop_jobs([proc])
    if code != 0:
        reason = failure_reason(folder, code)
        print(f"FAIL  {job.name}: {reason}", flush=True)
        return Outcome("fail", reason=reason)
    if not seeds_finished(job.cell, job.seeds, settings, bench_dir):
        # The child exits cleanly when a signal or run.max_minutes stops it early, checkpointed.
        print(f"STOP  {job.name}: {STOPPED_EARLY}", flush=True)
        return Outcome("fail", reason=STOPPED_EARLY)
    print(f"done  {job.name} in {(time.monotonic() - started) / 60:.1f} min", flush=True)
    # The records travel with the trial, so any machine can build the table from the storage alone.
    records = [seed_record(job.cell.run_dir(bench_dir, s), s) for s in job.seeds]
    trial.set_user_attr("records", records)
    evals = [r["eval_mean"] for r in records if r["eval_mean"] is not None and math.isfinite(r["eval_mean"])]
    if len(evals) < len(records):  # Optuna would store a NaN value as a failure, with no reason
        return Outcome(
            "fail", reason="a seed's eval.json has no finite mean return; delete it and re-run to evaluate again"
        )
    return Outcome("complete", value=float(np.mean(evals)))


def _open_grid_study(settings: BenchSettings, bench_dir: Path) -> tuple[Any, Any]:
    import optuna

    from canter.orchestrate.study import open_storage, retrying

    assert settings.storage_url is not None, "only a bench with --storage runs through a study"
    storage = open_storage(study_storage(settings.storage_url, settings.heartbeat_seconds))
    study = retrying(
        lambda: optuna.create_study(
            storage=storage,
            study_name=settings.study_name or bench_dir.name,
            direction="maximize",
            sampler=optuna.samplers.RandomSampler(),  # nothing is sampled: every trial is a queued job
            load_if_exists=True,
        ),
        settings.storage_url,
        "opening the study",
    )
    retrying(
        lambda: claim_study(study, "bench"),
        settings.storage_url,
        "opening the study",
    )
    return storage, study


def _jobs_by_key(cells: list[Cell], settings: BenchSettings) -> dict[str, Job]:
    return {job_key(j, settings): j for j in make_jobs(cells, settings.seeds)}


def _grid_worker(cells: list[Cell], settings: BenchSettings, bench_dir: Path) -> None:
    from canter.orchestrate.study import run_worker

    by_key = _jobs_by_key(cells, settings)
    storage, study = _open_grid_study(settings, bench_dir)
    run_worker(
        study,
        storage,
        len(by_key),
        lambda trial: _job_trial(study, trial, by_key, settings, bench_dir),
        heartbeat_seconds=settings.heartbeat_seconds,
        poll_seconds=settings.poll_seconds,
        ask_new=False,
    )


def run_distributed(
    cells: list[Cell], settings: BenchSettings, bench_dir: Path, storage: Any, study: Any
) -> tuple[list[dict[str, Any]], dict[str, str]]:
    """Share the jobs with other workers through the Optuna study (`_open_grid_study`); returns the results of every
    cell whose jobs all finished (by any worker) and the failure reasons of the other cells."""
    from optuna.trial import TrialState

    from canter.orchestrate.study import FAIL_REASON, retrying

    by_key = _jobs_by_key(cells, settings)
    # Queue the jobs that no trial holds yet (a first run, a job whose trial failed, or one with new settings).
    held = {
        trial_job(t)
        for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.RUNNING, TrialState.WAITING))
    }
    for key in by_key:
        if key not in held:
            study.enqueue_trial({}, user_attrs={JOB_ATTR: key})
    if settings.jobs == 1:
        _grid_worker(cells, settings, bench_dir)
    elif ended := run_workers(_grid_worker, [(cells, settings, bench_dir)] * settings.jobs, "canter-bench"):
        # The others retried what it held (a trial whose heartbeat stops is failed and queued again); the table
        # below holds every cell they finished, and names the rest.
        print(
            f"canter: note: {len(ended)} of {settings.jobs} bench workers ended early ({exit_text(ended[0])}; a "
            f"worker's own error, if it had one, is printed above)",
            file=sys.stderr,
        )
    done, failed = {}, {}
    for t in retrying(lambda: study.get_trials(deepcopy=False), storage.url, "reading the results"):
        held_by = trial_job(t)
        if held_by not in by_key:
            continue
        if t.state == TrialState.COMPLETE and "records" in t.user_attrs:
            done[held_by] = t.user_attrs["records"]
        elif t.state == TrialState.FAIL:
            failed[held_by] = t.user_attrs.get(FAIL_REASON, "worker died")
    failures: dict[str, str] = {}
    for key, reason in failed.items():
        if key not in done:
            failures.setdefault(by_key[key].cell.name, reason)
    results = []
    for cell in cells:
        keys = [k for k, j in by_key.items() if j.cell is cell]
        if all(k in done for k in keys):
            results.append(combine_records(cell, [r for k in keys for r in done[k]]))
        else:  # never silently missing from the table, whatever became of its trials
            failures.setdefault(cell.name, "no worker finished it")
    return results, failures


@contextlib.contextmanager
def holding_bench_folder(bench_dir: Path) -> Iterator[None]:
    """A local bench holds its --out folder's writer lock (`canter.training.run_lock`) while it runs: a second one
    on the same folder would fail each cell the first one trains, with the first one's lock error, and write a table
    of the rest. Workers that share a grid through --storage take their jobs from the study instead."""
    from canter.training import run_lock

    try:
        run_lock.acquire(bench_dir)
    except WriteError:  # a full or read-only disk, not another bench
        raise
    except CanterError:
        holder = run_lock.read_holder(bench_dir)
        who = f" (process {holder.get('pid')} on {holder.get('host')}: {holder.get('command')})" if holder else ""
        raise CanterError(
            f"{bench_dir} is in use by another bench{who}; wait for it to finish, or run both with --storage to "
            f"share the grid between them"
        ) from None
    try:
        yield
    finally:
        run_lock.release(bench_dir)


def bench(settings: BenchSettings) -> str:
    """Check the grid, run it (locally or through the storage), and write the results; returns the markdown."""
    cells = make_cells(settings)
    check_trackers(settings.track)  # a missing library or a bad --mlflow-uri, before any cell
    bench_dir = Path(settings.out_dir)
    if settings.storage_url:
        describe_url(normalize_url(settings.storage_url))  # a URL that is not one, before the folder is made
    existed = bench_dir.exists()
    make_folder(bench_dir)  # first: a SQLite storage may live in it
    try:
        opened = _open_grid_study(settings, bench_dir) if settings.storage_url else None
    except CanterError:
        if not existed and not any(bench_dir.iterdir()):  # a refused command leaves nothing behind
            bench_dir.rmdir()
        raise
    with holding_bench_folder(bench_dir) if opened is None else contextlib.nullcontext():
        return _run_grid(cells, settings, bench_dir, opened)


def _run_grid(cells: list[Cell], settings: BenchSettings, bench_dir: Path, opened: tuple[Any, Any] | None) -> str:
    check_results_writable(cells, bench_dir)
    check_existing_runs(cells, settings, bench_dir)
    # Each unfinished cell's tracker group (MLflow's parent run) is made here, once, not by jobs that start together.
    unfinished = [c for c in cells if not seeds_finished(c, settings.seeds, settings, bench_dir)]
    settings = replace(settings, track=open_groups(settings.track, [group_name(c.config) for c in unfinished]))
    warn_if_more_jobs_than_cores(settings.jobs)
    if opened is not None:
        results, failures = run_distributed(cells, settings, bench_dir, *opened)
    else:
        failures = run_local(cells, settings, bench_dir)
        results = [cell_result(c, settings, bench_dir) for c in cells if c.name not in failures]
    finished = [c for c in cells if any(r["cell"] == c.name for r in results)]
    markdown = write_results(finished, results, settings, bench_dir) if results else ""
    print(markdown, end="")
    if failures:
        raise CanterError(
            f"{len(failures)} of {len(cells)} cells failed ({next(iter(failures.values()))}); "
            f"re-run the same command to retry them"
        )
    return markdown
