"""A bench run on this machine alone: up to `--jobs` child processes at once, each training one job."""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from canter.orchestrate.bench_grid import BenchSettings, Cell, Job, make_jobs
from canter.orchestrate.bench_runs import STOPPED_EARLY, job_spec, seed_progress, seeds_finished, start_text
from canter.orchestrate.job_resources import job_layout, warn_if_more_jobs_than_cores, worker_count
from canter.orchestrate.jobs import BUSY, STOP_GRACE_SECONDS, failure_reason, start_job, stop_jobs
from canter.training.run_lock import BUSY_FIX

# How long a job whose run folder another process writes is tried again: a killed bench's job that still stops
# (its grace, and the checkpoint it writes), with room for the start of a process.
BUSY_WAIT_SECONDS = STOP_GRACE_SECONDS + 60.0
BUSY_RETRY_SECONDS = 10.0


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
    busy = BusyRetries(BUSY_WAIT_SECONDS, BUSY_RETRY_SECONDS)
    try:
        while pending or running:
            for slot, caps in enumerate(slots):
                starting = busy.next_due(pending) if slot not in running else None
                if starting is not None:
                    progress = seed_progress(starting, settings, bench_dir)  # before the job saves any
                    line = start_text(starting, progress, settings.total_steps)
                    cell_folder = bench_dir / ".cells" / starting.name
                    proc = start_job(job_spec(starting, settings, bench_dir), cell_folder, caps)
                    running[slot] = (starting, proc, time.monotonic())
                    if not busy.waited(starting):  # a retry's start was said with its first
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
                elif code == BUSY and busy.retry(job, pending):
                    print(f"wait  {job.name}: {busy.reason(bench_dir / '.cells' / job.name)}", flush=True)
                else:
                    reason = failure_reason(bench_dir / ".cells" / job.name, code)
                    failures.setdefault(job.cell.name, reason)
                    print(f"FAIL  {job.name}: {reason}", flush=True)
            time.sleep(settings.poll_seconds)
    finally:
        stop_jobs(proc for _, proc, _ in running.values())
    return failures


class BusyRetries:
    """The jobs that exited because another process writes their run folder (`BUSY`), such as a job of a bench that
    was killed and whose jobs still checkpoint: each is tried again every `retry_seconds` for up to
    `wait_seconds` from its first try, then fails as any job does."""

    def __init__(self, wait_seconds: float, retry_seconds: float, clock: Callable[[], float] = time.monotonic):
        self.wait_seconds = wait_seconds
        self.retry_seconds = retry_seconds
        self._clock = clock
        self._first_busy: dict[str, float] = {}
        self._due: dict[str, float] = {}

    def waited(self, job: Job) -> bool:
        """Whether `job` has been busy before."""
        return job.name in self._first_busy

    def next_due(self, pending: list[Job]) -> Job | None:
        """Take the first pending job that is not waiting for its retry."""
        now = self._clock()
        for index, job in enumerate(pending):
            if self._due.get(job.name, now) <= now:
                return pending.pop(index)
        return None

    def retry(self, job: Job, pending: list[Job]) -> bool:
        """Queue a busy job again, unless it has waited its time; False then."""
        now = self._clock()
        first = self._first_busy.setdefault(job.name, now)
        if now - first >= self.wait_seconds:
            return False
        self._due[job.name] = now + self.retry_seconds
        pending.append(job)
        return True

    def reason(self, cell_folder: Path) -> str:
        """The line a waiting job prints: the child's error, which names the process, and the retry."""
        said = failure_reason(cell_folder, BUSY).partition(": canter: error: ")[2].partition(f"; {BUSY_FIX}")[0]
        retry = f"trying again every {self.retry_seconds:.0f} s, for up to {self.wait_seconds / 60:.0f} min"
        return f"{said or 'its run folder is busy'}; {retry}"
