"""Process-wide JAX settings, applied once before canter traces anything."""

from __future__ import annotations

import os

_done = False


def setup_jax() -> None:
    """Enable 64-bit types (EnvPool's MuJoCo envs take float64 actions; the learner stays float32 explicitly) and
    keep the MuJoCo custom call on the CPU even where a GPU exists."""
    global _done
    if _done:
        return
    import jax

    jax.config.update("jax_enable_x64", True)
    if not os.environ.get("JAX_PLATFORMS"):
        jax.config.update("jax_platforms", "cpu")
    _done = True
