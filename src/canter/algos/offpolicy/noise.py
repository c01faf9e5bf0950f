"""Exploration noise for deterministic actors, in [-1, 1] action coordinates.

Gaussian noise is independent per step. Ornstein-Uhlenbeck noise is a mean-reverting AR(1) process per env and
action dimension, `x <- x - theta * x * dt + sigma * sqrt(dt) * N(0, 1)`, whose state lives in the train state and
restarts at 0 when that env's episode ends.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp


def ou_step(state: jnp.ndarray, key: jax.Array, theta: float, sigma: float, dt: float) -> jnp.ndarray:
    return state - theta * state * dt + sigma * math.sqrt(dt) * jax.random.normal(key, state.shape, jnp.float32)


def explore(
    kind: str, action: jnp.ndarray, ou_state: jnp.ndarray, key: jax.Array, std: float, theta: float, dt: float
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(noisy action clipped to [-1, 1], next OU state) for `kind` gaussian, ou or none."""
    if kind == "gaussian":
        noisy = action + std * jax.random.normal(key, action.shape, jnp.float32)
    elif kind == "ou":
        ou_state = ou_step(ou_state, key, theta, std, dt)
        noisy = action + ou_state
    else:
        noisy = action
    return jnp.clip(noisy, -1.0, 1.0), ou_state
