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
name, seeds, step budget, evaluation episodes and a digest of its experiment (`bench_distributed.job_key`), so
workers on several machines share the grid the way `canter tune` workers share a study, and a re-run with more seeds
or steps queues what it adds. Any number of such workers work on one --out folder, or one local bench alone
(`bench_folder`).

With `--track`, each seed is a tracker run, the seeds of a cell in one group (`canter.training.trackers`); a job
that resumes a seed continues its tracker runs.

This module runs a bench; `bench_grid` makes its cells and jobs, `bench_runs` reads their run folders, `bench_local`
and `bench_distributed` train them, and `bench_results` writes the tables.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from canter.errors import CanterError
from canter.files import make_folder, refuse_out_dir_in_a_run
from canter.orchestrate.bench_distributed import open_grid_study, run_distributed
from canter.orchestrate.bench_folder import holding_bench_folder, refuse_run_or_study_folder, sharing_bench_folder
from canter.orchestrate.bench_grid import BenchSettings, Cell, make_cells
from canter.orchestrate.bench_local import run_local
from canter.orchestrate.bench_results import cell_result, check_results_writable, write_results
from canter.orchestrate.bench_runs import check_existing_runs, seeds_finished
from canter.orchestrate.job_resources import check_jobs
from canter.orchestrate.jobs import needs_a_fix
from canter.orchestrate.study import describe_url, normalize_url
from canter.training.trackers import check_trackers, group_name, open_groups


def bench(settings: BenchSettings) -> str:
    """Check the grid, run it (locally or through the storage), and write the results; returns the markdown."""
    cells = make_cells(settings)
    check_trackers(settings.track)  # a missing library or a bad --mlflow-uri, before any cell
    check_jobs(settings.jobs)  # before the bench folder is made
    bench_dir = Path(settings.out_dir)
    if settings.storage_url:
        describe_url(normalize_url(settings.storage_url))  # a URL that is not one, before the folder is made
    refuse_run_or_study_folder(bench_dir)
    refuse_out_dir_in_a_run(bench_dir, "--out")
    existed = bench_dir.exists()
    make_folder(bench_dir)  # first: a SQLite storage may live in it
    try:
        opened = open_grid_study(settings, bench_dir) if settings.storage_url else None
    except CanterError:
        if not existed and not any(bench_dir.iterdir()):  # a refused command leaves nothing behind
            bench_dir.rmdir()
        raise
    if settings.storage_url:
        folder = sharing_bench_folder(bench_dir, settings.storage_url)
    else:
        folder = holding_bench_folder(bench_dir)
    with folder:
        return _run_grid(cells, settings, bench_dir, opened)


def _run_grid(cells: list[Cell], settings: BenchSettings, bench_dir: Path, opened: tuple[Any, Any] | None) -> str:
    check_results_writable(cells, bench_dir)
    check_existing_runs(cells, settings, bench_dir)
    # Each unfinished cell's tracker group (MLflow's parent run) is made here, once, not by jobs that start together.
    unfinished = [c for c in cells if not seeds_finished(c, settings.seeds, settings, bench_dir)]
    settings = replace(settings, track=open_groups(settings.track, [group_name(c.config) for c in unfinished]))
    if opened is not None:
        results, failures = run_distributed(cells, settings, bench_dir, *opened)
    else:
        failures = run_local(cells, settings, bench_dir)
        results = [cell_result(c, settings, bench_dir) for c in cells if c.name not in failures]
    finished = [c for c in cells if any(r.cell == c.name for r in results)]
    markdown = write_results(finished, results, settings, bench_dir) if results else ""
    print(markdown, end="")
    if failures:
        raise CanterError(failures_text(failures, len(cells)))
    return markdown


def failures_text(failures: dict[str, str], cells: int) -> str:
    """The bench's error for its failed cells: the reason of the first, and a retry only where one can help; a job
    that refused its input (`needs_a_fix`) fails the same way until that is fixed, so its reason comes first."""
    fixes = [reason for reason in failures.values() if needs_a_fix(reason)]
    if fixes:
        return (
            f"{len(failures)} of {cells} cells failed ({fixes[0]}); do what it says, then re-run: a retry alone fails "
            f"the same way"
        )
    first = next(iter(failures.values()))
    return f"{len(failures)} of {cells} cells failed ({first}); re-run the same command to retry them"
