"""Whether a run's envs fit in the machine's memory, checked before they are created.

Host-stepped backends give every env its own simulator (EnvPool and Gymnasium each hold one MuJoCo model and data per
env, about 0.5 MB for Hopper), so `env.num_envs=200000` would take about 100 GB, and the kernel's out-of-memory
killer would end the process with no message. For large env counts, the memory of a few envs is measured (the
process's resident size before and after making them, after a first env has paid the one-time costs of the
library, in a process of its own), scaled to the run's count and compared with what the machine has available.
JAX-native backends are checked on the compiled program instead (`canter.training.device_memory`)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from typing import Any

from canter.errors import CanterError

CHECK_ABOVE = 1024  # envs; smaller runs are not measured (a handful of MB per env at most)
PROBE_ENVS = 8
HEADROOM = 0.9  # of the available memory that the envs may take
GIB = 1024**3


def available_bytes() -> int | None:
    """MemAvailable of /proc/meminfo, or None where there is none."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def resident_bytes() -> int | None:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


def bytes_per_env(make: Callable[[int], Any]) -> float | None:
    """The resident memory one more env takes: `make(n)` builds n envs (closed again here)."""
    first = make(1)  # pays the library's one-time costs (loading, assets)
    before = resident_bytes()
    probe = make(PROBE_ENVS)
    after = resident_bytes()
    probe.close()
    first.close()
    if before is None or after is None:
        return None
    return max(after - before, 0) / PROBE_ENVS


def refusal(num_envs: int, per_env: float, available: int) -> CanterError | None:
    """The one-line error when `num_envs` envs of `per_env` bytes do not fit in `available` bytes, else None."""
    need = per_env * num_envs
    if need <= HEADROOM * available:
        return None
    fits = max(int(HEADROOM * available / per_env), 1) if per_env > 0 else num_envs
    return CanterError(
        f"env.num_envs={num_envs} needs about {need / GIB:.1f} GiB of memory for its envs ({per_env / 2**20:.2f} "
        f"MiB each, measured), but {available / GIB:.1f} GiB are available; lower it, e.g. "
        f"--set env.num_envs={fits}"
    )


_PROBE = """
import json, sys
from canter.envs.registry import make_vec_env
from canter.training.host_memory import bytes_per_env
env_id, backend, options = json.loads(sys.argv[1])
print(json.dumps(bytes_per_env(lambda n: make_vec_env(env_id, backend, n, list(range(n)), **options))))
"""
PROBE_TIMEOUT_SECONDS = 300


def bytes_per_env_apart(env_id: str, backend: str, options: dict[str, Any]) -> float | None:
    """`bytes_per_env` of the env in a fresh process, or None where it cannot be measured. A process that has made
    and closed envs before reuses their freed memory for new ones, so its resident size hardly grows and the measure
    comes out near zero: enough envs to exhaust the machine would then pass the check."""
    try:
        argument = json.dumps([env_id, backend, options])
    except TypeError:
        return None
    try:
        done = subprocess.run(
            [sys.executable, "-c", _PROBE, argument], capture_output=True, text=True, timeout=PROBE_TIMEOUT_SECONDS
        )
    except subprocess.TimeoutExpired:
        return None
    lines = done.stdout.strip().splitlines()
    if done.returncode != 0 or not lines:
        return None  # a bad env id or option fails again, with its own error, where the run makes its envs
    measured = json.loads(lines[-1])
    return float(measured) if measured is not None else None


def check_envs_fit(env_id: str, backend: str, options: dict[str, Any], num_envs: int) -> None:
    """Refuse, before creating them, `num_envs` envs that the machine's memory cannot hold."""
    if num_envs <= CHECK_ABOVE:
        return
    available = available_bytes()
    if available is None:
        return
    per_env = bytes_per_env_apart(env_id, backend, options)
    if per_env is None:
        return
    error = refusal(num_envs, per_env, available)
    if error is not None:
        raise error
