"""Process-wide JAX settings, applied before canter traces anything for an env backend."""

from __future__ import annotations

import os
import sys

_platform_chosen = False
_cpu_notice_given = False


def setup_jax(backend: str | None = None) -> None:
    """Set JAX up for the env backend a program will step (None: a host-stepped one).

    - EnvPool and Gymnasium step C MuJoCo from the host: 64-bit types on (EnvPool's MuJoCo envs take float64
      actions; the learner stays float32 explicitly), and the whole program on the CPU even where a GPU exists,
      since EnvPool's custom call has no GPU version.
    - A JAX-native backend (MJX, Brax) steps its physics inside the program: float32 throughout, on the GPU where
      JAX finds one, else on the CPU with a one-line notice.

    The platform is fixed by the first call in a process (JAX cannot move afterwards); the 64-bit switch follows
    each call's backend, since JAX keys its compiled programs on it."""
    import jax

    from canter.envs.functional import x64_enabled
    from canter.envs.registry import get_backend

    global _platform_chosen, _cpu_notice_given
    native = backend is not None and backend != "auto" and get_backend(backend).jax_native
    if _platform_chosen and x64_enabled() == native:
        # Switching precision in a process that has traced programs: JAX's staging caches can hold a nested
        # program traced in the other precision (MJX's integrators do), so they start over.
        jax.clear_caches()
    jax.config.update("jax_enable_x64", not native)
    if not _platform_chosen:
        if not native and not os.environ.get("JAX_PLATFORMS"):
            jax.config.update("jax_platforms", "cpu")
        _platform_chosen = True
    if native and jax.default_backend() == "cpu" and not _cpu_notice_given:
        print(f"canter: no GPU found, so {backend} steps its physics on the CPU (correct, but slow)", file=sys.stderr)
        _cpu_notice_given = True
