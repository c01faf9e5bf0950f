"""Process-wide JAX settings, applied before canter traces anything for an env backend."""

from __future__ import annotations

import importlib.util
import os
import sys
from typing import Any

from canter.errors import CanterError, first_line

_platform_chosen = False
_cpu_fixed_for: str | None = None  # the host-stepped backend whose setup put this process's JAX on the CPU
_cpu_notice_given = False

# A folder for compiled programs, or off (0, false, no); default: $XDG_CACHE_HOME/canter/xla (~/.cache/canter/xla).
COMPILE_CACHE_ENV = "CANTER_COMPILE_CACHE"
COMPILE_CACHE_LIMIT = 4 * 1024**3  # bytes; the least recently used programs go beyond it


def setup_jax(backend: str | None = None, announce: bool = True) -> None:
    """Set JAX up for the env backend a program will step (None: a host-stepped one).

    - EnvPool and Gymnasium step C MuJoCo from the host: 64-bit types on (EnvPool's MuJoCo envs take float64
      actions; the learner stays float32 explicitly), and the whole program on the CPU even where a GPU exists,
      since EnvPool's custom call has no GPU version.
    - A JAX-native backend (MJX, Brax) steps its physics inside the program: float32 throughout, on the GPU where
      JAX finds one, else on the CPU with a one-line notice.

    The platform is fixed by the first call in a process (JAX cannot move afterwards); the 64-bit switch follows
    each call's backend, since JAX keys its compiled programs on it. `announce=False` leaves the CPU notice to
    `announce_physics`, for a program that only loads what such a backend trained."""
    import jax

    from canter.envs.functional import x64_enabled
    from canter.envs.registry import AUTO

    global _platform_chosen, _cpu_fixed_for
    native = _steps_in_jax(backend)
    if _platform_chosen and x64_enabled() == native:
        # Switching precision in a process that has traced programs: JAX's staging caches can hold a nested
        # program traced in the other precision (MJX's integrators do), so they start over.
        jax.clear_caches()
    jax.config.update("jax_enable_x64", not native)
    if not _platform_chosen:
        if not native and not os.environ.get("JAX_PLATFORMS"):
            jax.config.update("jax_platforms", "cpu")
            _cpu_fixed_for = backend if backend not in (None, AUTO) else "a host-stepped backend"
        use_compile_cache(jax)
        _platform_chosen = True
    try:
        jax.default_backend()  # starts the platform: a missing one fails here, in one line
    except (RuntimeError, AssertionError, ValueError) as exc:  # JAX_PLATFORMS names a platform this machine lacks
        raise CanterError(
            f"JAX could not start the platform JAX_PLATFORMS={os.environ.get('JAX_PLATFORMS', '')} asks for "
            f"({first_line(exc)}); unset JAX_PLATFORMS, or install JAX for that device"
        ) from None
    if announce:
        announce_physics(backend)


def _steps_in_jax(backend: str | None) -> bool:
    """Whether `backend` steps its physics inside the JAX program (MJX, Brax); None and `auto` are host-stepped."""
    from canter.envs.registry import AUTO, get_backend

    return backend is not None and backend != AUTO and get_backend(backend).jax_native


def announce_physics(backend: str | None) -> None:
    """The one-line notice (once per process) that a JAX-native backend steps its physics on the CPU, given where
    that backend is about to step: a policy trained on mjx and evaluated on EnvPool loads as mjx but steps none.
    Where an earlier setup for a host-stepped backend put JAX on the CPU, it says so, since a GPU may be there: an
    EnvPool run that evaluates on mjx during training steps MJX on the CPU, in the training program's float64."""
    import jax

    from canter.envs.functional import x64_enabled

    global _cpu_notice_given
    if not _steps_in_jax(backend) or _cpu_notice_given or jax.default_backend() != "cpu":
        return
    precision = ", in float64," if x64_enabled() else ""
    if _cpu_fixed_for is None:
        line = f"no GPU found, so {backend} steps its physics on the CPU{precision} (correct, but slow)"
    else:
        line = (
            f"{backend} steps its physics on the CPU{precision} since this process set JAX up for {_cpu_fixed_for} "
            "first, whose step runs only there (correct, but slow)"
        )
    print(f"canter: {line}", file=sys.stderr)
    _cpu_notice_given = True


def compile_cache_dir() -> str | None:
    """Where compiled programs are kept across processes, or None when the cache is off."""
    setting = os.environ.get(COMPILE_CACHE_ENV, "").strip()
    if setting.lower() in ("0", "off", "false", "no"):
        return None
    if setting:
        return setting
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "canter", "xla")


def use_compile_cache(jax: Any) -> None:
    """Keep compiled programs across processes: a resume, a rerun, and bench seeds or trials that share a program
    compile it again otherwise (an MJX iteration: 42 s on this CPU, up to two minutes on a GPU; from the cache, 5 s).
    Programs that compile in under a second are not kept. A program that holds EnvPool's step embeds the pool's
    address, which differs in every process, so it is never found again (about 100 KiB each, until the size bound
    drops it); an on-policy update is compiled apart from that step for this reason (`Algorithm.make_parts`), and
    is found again. JAX's own JAX_COMPILATION_CACHE_DIR, where set, wins; an unusable folder leaves the cache off."""
    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return
    folder = compile_cache_dir()
    if folder is None:
        return
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError:
        return
    if not os.access(folder, os.W_OK):
        return
    jax.config.update("jax_compilation_cache_dir", folder)
    # JAX bounds the cache only with filelock importable; set without it, every read of a kept program fails with a
    # warning and each process compiles again. A `--no-deps` install without filelock keeps an unbounded cache.
    if importlib.util.find_spec("filelock") is not None:
        jax.config.update("jax_compilation_cache_max_size", COMPILE_CACHE_LIMIT)
