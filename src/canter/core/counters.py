"""The integer type of step counters in train states."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def count_dtype() -> np.dtype:
    """int64 where JAX has 64-bit types on (the host-stepped backends), int32 in a float32 program (JAX-native
    backends: 2**31 steps are far beyond any run). Read when a state is built or traced, so it follows the mode."""
    return jax.dtypes.canonicalize_dtype(jnp.int64)
