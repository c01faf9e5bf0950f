"""Exploration noise for deterministic actors, in [-1, 1] action coordinates.

Gaussian noise is independent per step. Ornstein-Uhlenbeck noise is a mean-reverting AR(1) process per env and
action dimension, `x <- x - theta * x * dt + sigma * sqrt(dt) * N(0, 1)`, whose state lives in the train state and
restarts at 0 when that env's episode ends.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import jax.numpy as jnp


def ou_step(state: jnp.ndarray, key: jax.Array, theta: float, sigma: float, dt: float) -> jnp.ndarray:
    return state - theta * state * dt + sigma * math.sqrt(dt) * jax.random.normal(key, state.shape, jnp.float32)


Noise = Callable[[jnp.ndarray, jnp.ndarray, jax.Array, float, float, float], tuple[jnp.ndarray, jnp.ndarray]]


def _gaussian(
    action: jnp.ndarray, ou_state: jnp.ndarray, key: jax.Array, std: float, theta: float, dt: float
) -> tuple[jnp.ndarray, jnp.ndarray]:
    return action + std * jax.random.normal(key, action.shape, jnp.float32), ou_state


def _ornstein_uhlenbeck(
    action: jnp.ndarray, ou_state: jnp.ndarray, key: jax.Array, std: float, theta: float, dt: float
) -> tuple[jnp.ndarray, jnp.ndarray]:
    ou_state = ou_step(ou_state, key, theta, std, dt)
    return action + ou_state, ou_state


def _none(
    action: jnp.ndarray, ou_state: jnp.ndarray, key: jax.Array, std: float, theta: float, dt: float
) -> tuple[jnp.ndarray, jnp.ndarray]:
    return action, ou_state


# (action, OU state, key, std, theta, dt) -> (noisy action, next OU state), for each of the `noise` key's values
# (canter.algos.offpolicy.sections.NOISE_KINDS, which the config checks without importing JAX).
NOISES: dict[str, Noise] = {"gaussian": _gaussian, "ou": _ornstein_uhlenbeck, "none": _none}


def explore(
    kind: str, action: jnp.ndarray, ou_state: jnp.ndarray, key: jax.Array, std: float, theta: float, dt: float
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(noisy action clipped to [-1, 1], next OU state) for `kind`, one of NOISES."""
    noisy, ou_state = NOISES[kind](action, ou_state, key, std, theta, dt)
    return jnp.clip(noisy, -1.0, 1.0), ou_state
