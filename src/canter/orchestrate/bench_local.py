"""A bench run on this machine alone: up to `--jobs` child processes at once, each training one job."""

from __future__ import annotations

import itertools
import time
from pathlib import Path
from typing import Any

from canter.orchestrate.bench_grid import BenchSettings, Cell, Job, make_jobs
from canter.orchestrate.bench_runs import STOPPED_EARLY, job_spec, seed_progress, seeds_finished, start_text
from canter.orchestrate.job_resources import job_layout, warn_if_more_jobs_than_cores, worker_count
from canter.orchestrate.jobs import failure_reason, start_job, stop_jobs


def run_local(cells: list[Cell], settings: BenchSettings, bench_dir: Path) -> dict[str, str]:
    """Run the unfinished jobs, up to `jobs` child processes at once (no more than there are jobs left); returns
    {cell name: failure reason}."""
    jobs = make_jobs(cells, settings.seeds)
    finished = [seeds_finished(job.cell, job.seeds, settings, bench_dir) for job in jobs]
    if any(finished):
        print(f"{sum(finished)} of {len(jobs)} jobs already done", flush=True)
    for job in itertools.compress(jobs, finished):
        print(f"skip {job.name} (finished)")
    pending = [job for job, done in zip(jobs, finished) if not done]
    # Slots for the jobs left only: each slot's share of the cores and of a GPU's memory is cut for the slots there are.
    workers = worker_count(settings.jobs, len(pending))
    warn_if_more_jobs_than_cores(settings.jobs, workers)
    slots = job_layout(workers) if workers > 1 else [{}]
    running: dict[int, tuple[Job, Any, float]] = {}
    failures: dict[str, str] = {}
    try:
        while pending or running:
            for slot, caps in enumerate(slots):
                if slot not in running and pending:
                    job = pending.pop(0)
                    progress = seed_progress(job, settings, bench_dir)  # before the job saves any
                    line = start_text(job, progress, settings.total_steps)
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
