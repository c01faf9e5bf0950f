"""A bench shared through an Optuna storage (`--storage`): each job is a queued trial, which any worker of the grid,
on this machine or another, takes and trains."""

from __future__ import annotations

import functools
import hashlib
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from canter.orchestrate.bench_grid import BenchSettings, Cell, Job, make_jobs
from canter.orchestrate.bench_results import CellResult, SeedRecord, combine_seeds, read_seed
from canter.orchestrate.bench_runs import STOPPED_EARLY, job_spec, seed_progress, seeds_finished, start_text
from canter.orchestrate.job_resources import warn_if_more_jobs_than_cores, worker_count
from canter.orchestrate.jobs import exit_text, failure_reason, run_workers, start_job, stop_jobs
from canter.orchestrate.study import claim_study, retrying, say, study_storage

if TYPE_CHECKING:
    from canter.orchestrate.study import Outcome


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
    progress = seed_progress(job, settings, bench_dir)
    print(f"{start_text(job, progress, settings.total_steps)}; trial {trial.number}", flush=True)
    started = time.monotonic()
    proc = start_job(job_spec(job, settings, bench_dir), folder)
    try:
        code = proc.wait()
    finally:
        stop_jobs([proc])
    if code != 0:
        reason = failure_reason(folder, code)
        say(f"FAIL  {job.name}: {reason}")
        return Outcome("fail", reason=reason)
    if not seeds_finished(job.cell, job.seeds, settings, bench_dir):
        # The child exits cleanly when a signal or run.max_minutes stops it early, checkpointed.
        say(f"STOP  {job.name}: {STOPPED_EARLY}")
        return Outcome("fail", reason=STOPPED_EARLY)
    say(f"done  {job.name} in {(time.monotonic() - started) / 60:.1f} min")
    # The records travel with the trial, so any machine can build the table from the storage alone.
    records = [read_seed(job.cell.run_dir(bench_dir, s), s) for s in job.seeds]
    # Waits out an outage of the storage, as every other storage call of a worker does: the cell is trained.
    retrying(
        functools.partial(trial.set_user_attr, "records", [r.to_json() for r in records]),
        str(settings.storage_url),
        "recording a cell's results",
    )
    evals = [r.eval_mean for r in records if r.eval_mean is not None and math.isfinite(r.eval_mean)]
    if len(evals) < len(records):  # Optuna would store a NaN value as a failure, with no reason
        return Outcome(
            "fail", reason="a seed's eval.json has no finite mean return; delete it and re-run to evaluate again"
        )
    return Outcome("complete", value=float(np.mean(evals)))


def open_grid_study(settings: BenchSettings, bench_dir: Path) -> tuple[Any, Any]:
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
    storage, study = open_grid_study(settings, bench_dir)
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
) -> tuple[list[CellResult], dict[str, str]]:
    """Share the jobs with other workers through the Optuna study (`open_grid_study`); returns the results of every
    cell whose jobs all finished (by any worker) and the failure reasons of the other cells."""
    from optuna.trial import TrialState

    from canter.orchestrate.study import FAIL_REASON, retrying

    by_key = _jobs_by_key(cells, settings)
    # Queue the jobs that no trial holds yet (a first run, a job whose trial failed, or one with new settings).
    trials = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.RUNNING, TrialState.WAITING))
    held = {trial_job(t) for t in trials}
    for key in by_key:
        if key not in held:
            study.enqueue_trial({}, user_attrs={JOB_ATTR: key})
    # A worker beyond the grid's unfinished jobs would find no trial to take.
    complete = {trial_job(t) for t in trials if t.state == TrialState.COMPLETE}
    workers = worker_count(settings.jobs, sum(1 for key in by_key if key not in complete))
    warn_if_more_jobs_than_cores(settings.jobs, workers)
    if workers == 1:
        _grid_worker(cells, settings, bench_dir)
    elif ended := run_workers(_grid_worker, [(cells, settings, bench_dir)] * workers, "canter-bench"):
        # The others retried what it held (a trial whose heartbeat stops is failed and queued again); the table
        # below holds every cell they finished, and names the rest.
        print(
            f"canter: note: {len(ended)} of {workers} bench workers ended early ({exit_text(ended[0])}; a "
            f"worker's own error, if it had one, is printed above)",
            file=sys.stderr,
        )
    done, failed = {}, {}
    for t in retrying(lambda: study.get_trials(deepcopy=False), storage.url, "reading the results"):
        held_by = trial_job(t)
        if held_by not in by_key:
            continue
        if t.state == TrialState.COMPLETE and "records" in t.user_attrs:
            done[held_by] = [SeedRecord.from_json(r) for r in t.user_attrs["records"]]
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
            results.append(combine_seeds(cell, [r for k in keys for r in done[k]]))
        else:  # never silently missing from the table, whatever became of its trials
            failures.setdefault(cell.name, "no worker finished it")
    return results, failures
