"""Generalized advantage estimation over a rollout with EnvPool-style episode boundaries.

Layout (time-major, T steps, N envs):
- `values` has T+1 rows: the value of the observation each step acted on, plus the value of the observation after
  the last step (the bootstrap).
- `valid[t]` is false for an autoreset step (the step after a done: reset observation, reward 0, action ignored).
- `terminated[t]` cuts the bootstrap; `done[t] = terminated or truncated` cuts the advantage chain.

A truncated step therefore bootstraps from `values[t + 1]`, which is the value of the true final observation,
because EnvPool only resets on the following step.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def compute_gae(
    rewards: jnp.ndarray,
    values: jnp.ndarray,
    terminated: jnp.ndarray,
    done: jnp.ndarray,
    valid: jnp.ndarray,
    gamma: float,
    gae_lambda: float,
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Return (advantages, returns), both [T, N]; entries of invalid steps are 0 and must be masked by the caller."""
    not_terminated = 1.0 - terminated.astype(jnp.float32)
    not_done = 1.0 - done.astype(jnp.float32)
    valid_f = valid.astype(jnp.float32)
    deltas = rewards + gamma * not_terminated * values[1:] - values[:-1]

    def backward(next_advantage, step):
        delta, continues, is_valid = step
        advantage = is_valid * (delta + gamma * gae_lambda * continues * next_advantage)
        return advantage, advantage

    _, advantages = jax.lax.scan(backward, jnp.zeros_like(values[0]), (deltas, not_done, valid_f), reverse=True)
    returns = (advantages + values[:-1]) * valid_f
    return advantages, returns
