"""Whether a run's envs fit in the machine's memory, checked before they are created.

Host-stepped backends give every env its own simulator (EnvPool and Gymnasium each hold one MuJoCo model and data per
env, about 0.5 MB for Hopper), so `env.num_envs=200000` would take about 100 GB, and the kernel's out-of-memory
killer would end the process with no message. For large env counts, the memory of a few envs is measured (the
process's resident size before and after making them, after a first env has paid the one-time costs of the
library, in a process of its own), scaled to the run's count and compared with what the machine has available.
JAX-native backends are sized from the shapes of one env's state, against the device's free memory where it reports
it (a GPU), and checked again on the compiled program (`canter.training.device_memory`).

The train state (a replay buffer, the networks and their optimizer's moments) is checked the same way before it is
built, from its shapes (`canter.algos.state_size`), against the device's free memory where the device reports it
(a GPU) and the machine's otherwise: a td3.buffer_size of a billion would take 41 GiB at once."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from canter.config.values import set_text
from canter.errors import DoesNotFitError

if TYPE_CHECKING:
    from canter.algos.protocol import Algorithm
    from canter.algos.state_size import StateSize
    from canter.config.schema import Config

CHECK_ABOVE = 1024  # envs; smaller runs are not measured (a handful of MB per env at most)
PROBE_ENVS = 8
HEADROOM = 0.9  # of the available memory that the envs, a train state or a program may take
GIB = 1024**3
# The least an env takes on any backend, measured or not: its seed in the list the trainer makes of them (a Python
# int and the list's pointer to it, and the uint32 it is drawn as), so that a count no machine holds is refused.
MIN_BYTES_PER_ENV = 48


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


def refusal(
    num_envs: int, per_env: float, available: int, group: int = 1, how: str | None = "measured"
) -> DoesNotFitError | None:
    """The one-line error when `group` seeds of `num_envs` envs each, of `per_env` bytes (found `how`, or None: the
    least an env takes), do not fit in `available` bytes, else None. When one seed's envs fit, the fix is fewer seeds
    at a time, not fewer envs."""
    total = num_envs * group
    need = per_env * total
    room = HEADROOM * available
    if need <= room:
        return None
    fits = max(int(room / per_env), 1) if per_env > 0 else total
    amount = f"about {size_text(need)} of memory"
    if group > 1:
        what = f"{group} seeds of env.num_envs={num_envs} ({total} envs) need {amount} for their"
    else:
        what = f"env.num_envs={num_envs} needs {amount} for its"
    each = f"{size_text(per_env)} each, {how}" if how else f"at least {per_env:.0f} bytes each"
    problem = f"{what} envs ({each}), but {size_text(available)} are available"
    if how is None:  # a count that fits this floor can still be far too many envs
        return DoesNotFitError(problem, "lower it by far (an env takes much more than its seed)")
    if group > 1 and num_envs <= fits:
        return DoesNotFitError(problem, seeds_at_once=fits // num_envs)
    return DoesNotFitError(
        problem, f"lower it, e.g. --set env.num_envs={fits}" + (", with one seed at a time" if group > 1 else "")
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


def check_envs_fit(env_id: str, backend: str, options: dict[str, Any], num_envs: int, group: int = 1) -> None:
    """Refuse, before creating them (and before listing their seeds), `group` seeds' `num_envs` envs each that the
    machine's memory cannot hold. Each env stepped on the host is a simulator of its own, whose memory is measured;
    where it cannot be, any env takes at least MIN_BYTES_PER_ENV."""
    if num_envs * group <= CHECK_ABOVE:
        return
    available = available_bytes()
    if available is None:
        return
    per_env = bytes_per_env_apart(env_id, backend, options)
    if per_env is None:
        error = refusal(num_envs, MIN_BYTES_PER_ENV, available, group, how=None)
    else:
        error = refusal(num_envs, max(per_env, MIN_BYTES_PER_ENV), available, group)
    if error is not None:
        raise error


def check_jax_envs_fit(per_env: Callable[[], int], num_envs: int, group: int, device_free: int | None) -> None:
    """Refuse JAX envs whose state alone, `per_env()` bytes each (read from its shapes), does not fit in the device's
    free memory (the machine's on the CPU): the program that steps them is checked only after its compile, and
    resetting so many envs first can take minutes and then fail with XLA's own error."""
    if num_envs * group <= CHECK_ABOVE:
        return
    available = device_free if device_free is not None else available_bytes()
    if available is None:
        return
    error = refusal(num_envs, max(per_env(), MIN_BYTES_PER_ENV), available, group, how="from its state's shapes")
    if error is not None:
        raise error


def state_copies(group: int) -> int:
    """The train states a group holds at its peak: one per seed and, while they are stacked onto a seed axis
    (`canter.training.seedgroup.stack`), the stacked copy."""
    return 1 if group == 1 else 2 * group


def seeds_that_fit(per_seed: int, room: float) -> int:
    """The largest group whose train states, of `per_seed` bytes each, fit in `room` bytes (0: not even one)."""
    pairs = int(room // (2 * per_seed)) if per_seed > 0 else 2
    return pairs if pairs >= 2 else int(per_seed <= room)


def size_text(size: float) -> str:
    for unit, scale in (("GiB", GIB), ("MiB", 2**20)):
        if size >= scale:
            return f"{size / scale:.1f} {unit}"
    return f"{size / 2**10:.1f} KiB"


def state_refusal(
    size: StateSize, value: Any, group: int, available: int, where: str, smaller: Any | None = None
) -> DoesNotFitError | None:
    """The one-line error when `group` train states of `size` (whose key has `value`) do not fit in `available` bytes
    of `where`, else None; `smaller` is a value of the key that would fit."""
    need = size.total * state_copies(group)
    if need <= HEADROOM * available:
        return None
    amounts = f"about {size_text(need)} of {where}"
    have = f"but {size_text(available)} are available"
    if group > 1 and (fits := seeds_that_fit(size.total, HEADROOM * available)) >= 1:
        return DoesNotFitError(
            f"the train states of {group} seeds need {amounts} ({size_text(size.total)} each, and as much again "
            f"while they are stacked), {have}",
            seeds_at_once=fits,
        )
    whose = f"the train states of {group} seeds need" if group > 1 else "the train state needs"
    if size.key is None:
        return DoesNotFitError(f"{whose} {amounts}, {have}")
    fix = f"lower {size.key}" + (f", e.g. --set {size.key}={set_text(smaller)}" if smaller is not None else "")
    share = size_text(size.share * state_copies(group))
    return DoesNotFitError(f"{whose} {amounts}, {share} of it for {size.key}={set_text(value)}, {have}", fix)


def check_state_fits(algorithm: Algorithm, config: Config, spec: Any, group: int, free: int | None) -> None:
    """Refuse, before it is built, a train state for each of `group` seeds that the memory it goes to cannot hold:
    the device's where it reports its `free` memory (a GPU: `device_memory.free_bytes`), else the machine's."""
    from canter.algos.state_size import smaller_value, state_size
    from canter.config.algorithms import key_value

    available, where = (free, "the device's memory") if free is not None else (available_bytes(), "memory")
    if available is None:
        return
    size = state_size(algorithm, config, spec)
    value = key_value(config, size.key) if size.key is not None else None
    if state_refusal(size, value, group, available, where) is None:
        return
    smaller = None
    if size.key is not None and (group == 1 or seeds_that_fit(size.total, HEADROOM * available) == 0):
        smaller = smaller_value(
            algorithm, config, spec, size.key, lambda total: total * state_copies(group) <= HEADROOM * available
        )
    error = state_refusal(size, value, group, available, where, smaller)
    assert error is not None
    raise error
