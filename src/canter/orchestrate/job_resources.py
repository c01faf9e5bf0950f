"""How parallel jobs share the machine: the threads and cores of each job's process, an equal share of a GPU's
memory, and how many jobs a machine is let run at once."""

from __future__ import annotations

import contextlib
import os
import sys

from canter.errors import CanterError


def thread_env(threads: int, cpus: list[int] | None = None) -> dict[str, str]:
    """Environment variables that cap a JAX process at `threads` threads; they must be set before JAX is imported.
    `CANTER_CPUS` pins the process to those cores (read by `apply_cpu_pinning`)."""
    flags = os.environ.get("XLA_FLAGS", "")
    extra = f"--xla_cpu_multi_thread_eigen={'false' if threads == 1 else 'true'} intra_op_parallelism_threads={threads}"
    env = {
        "XLA_FLAGS": f"{flags} {extra}".strip(),
        "OMP_NUM_THREADS": str(threads),
        "OPENBLAS_NUM_THREADS": str(threads),
        "MKL_NUM_THREADS": str(threads),
    }
    if cpus:
        env["CANTER_CPUS"] = ",".join(map(str, cpus))
    return env


def apply_cpu_pinning() -> None:
    cpus = os.environ.get("CANTER_CPUS")
    if cpus and hasattr(os, "sched_setaffinity"):
        with contextlib.suppress(OSError):
            os.sched_setaffinity(0, {int(c) for c in cpus.split(",")})


def usable_cores() -> list[int]:
    """The cores this process may run on (its affinity, which a scheduler or `taskset` narrows), in order."""
    return sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else list(range(os.cpu_count() or 1))


def job_layout(jobs: int) -> list[dict[str, str]]:
    """Per-job caps: the cores split evenly over the jobs, each job pinned to its share, and on a GPU an equal share
    of its memory (`gpu_memory_env`)."""
    cores = usable_cores()
    if jobs > len(cores):
        return [{**thread_env(1), **gpu_memory_env(jobs)} for _ in range(jobs)]
    per = len(cores) // jobs
    return [{**thread_env(per, cores[i * per : (i + 1) * per]), **gpu_memory_env(jobs)} for i in range(jobs)]


def gpu_memory_env(jobs: int) -> dict[str, str]:
    """JAX takes 75% of a GPU's memory when it starts, so a second job on the same GPU would run out of memory.
    Concurrent jobs each get an equal share of 90% of it instead (the CPU ignores the setting); a user's own
    XLA_PYTHON_CLIENT_MEM_FRACTION wins."""
    if jobs <= 1 or "XLA_PYTHON_CLIENT_MEM_FRACTION" in os.environ:
        return {}
    return {"XLA_PYTHON_CLIENT_MEM_FRACTION": f"{0.9 / jobs:.3f}"}


# Every job is a process of its own that imports JAX and compiles its programs, some hundreds of MB each, and beyond
# one job per core they share the cores one thread each. A few per core can still help (a job waits on its env steps,
# its evaluations, a GPU); at more than 4 per core each gets under a quarter of one, so more jobs add no throughput,
# only memory, until the machine runs out of it. A --jobs that large is taken for a typo and refused.
JOBS_PER_CORE = 4


def check_jobs(jobs: int) -> None:
    """Refuse a `--jobs` above JOBS_PER_CORE per usable core, before the command starts anything."""
    cores = len(usable_cores())
    if jobs > JOBS_PER_CORE * cores:
        raise CanterError(
            f"--jobs {jobs} is more than {JOBS_PER_CORE} per CPU core, and this machine lets canter use {cores}; "
            f"pass --jobs {cores} (one per core), or at most --jobs {JOBS_PER_CORE * cores}"
        )


def worker_count(jobs: int, work: int) -> int:
    """The processes to start for `work` items still to do with up to `jobs` at once: never more than the items,
    since a process with nothing to take only costs memory; at least one, which waits for the items that run
    elsewhere (a shared study) or finds that nothing is left."""
    return max(1, min(jobs, work))


def warn_if_more_jobs_than_cores(jobs: int, started: int) -> None:
    """Warn on stderr when the processes that will run at once, `started` of the `jobs` asked for, exceed the usable
    cores; called once the command has passed its checks, so that a refused command prints only its error."""
    cores = len(usable_cores())
    if started > cores:
        print(
            f"canter: warning: --jobs {jobs} is more than the {cores} CPU cores; the jobs will slow each other down",
            file=sys.stderr,
        )
