"""A fixed-capacity replay buffer on the JAX device, as a pure pytree: arrays, an insert pointer and a size.

Inserting writes a batch of transitions at the pointer (wrapping around, oldest first overwritten); rows whose mask
is false (EnvPool's autoreset steps) are skipped and take no slot. Sampling draws indices uniformly from the filled
part. Both are plain functions, so the buffer lives in the train state that the trainer donates to jit: the
arrays are updated in place and never copied between calls.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp


class Transitions(NamedTuple):
    obs: jnp.ndarray  # [..., obs_dim] raw observation acted on
    action: jnp.ndarray  # [..., act_dim] the action taken, in the policy's [-1, 1] coordinates
    reward: jnp.ndarray  # [...] raw env reward
    next_obs: jnp.ndarray  # [..., obs_dim] the true next observation (the final one when an episode ended)
    terminated: jnp.ndarray  # [...] float32 1.0 only for a true terminal state (time limits bootstrap)


class ReplayBuffer(NamedTuple):
    data: Transitions  # arrays of leading size `capacity`
    ptr: jnp.ndarray  # int32, the next slot to write
    size: jnp.ndarray  # int32, filled slots


def init_buffer(capacity: int, obs_dim: int, act_dim: int) -> ReplayBuffer:
    f32 = jnp.float32
    data = Transitions(
        jnp.zeros((capacity, obs_dim), f32),
        jnp.zeros((capacity, act_dim), f32),
        jnp.zeros((capacity,), f32),
        jnp.zeros((capacity, obs_dim), f32),
        jnp.zeros((capacity,), f32),
    )
    return ReplayBuffer(data, jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))


def capacity_of(buffer: ReplayBuffer) -> int:
    return buffer.data.reward.shape[0]


def insert(buffer: ReplayBuffer, batch: Transitions, mask: jnp.ndarray) -> ReplayBuffer:
    """Write the rows of `batch` (leading axis N) whose `mask` is true, in order, at consecutive slots."""
    capacity = capacity_of(buffer)
    keep = mask.astype(jnp.int32)
    offsets = jnp.cumsum(keep, dtype=jnp.int32) - keep
    # Skipped rows get an out-of-range index, which mode="drop" ignores.
    slots = jnp.where(mask, (buffer.ptr + offsets) % capacity, capacity)
    data = jax.tree_util.tree_map(
        lambda store, rows: store.at[slots].set(rows.astype(store.dtype), mode="drop"), buffer.data, batch
    )
    count = keep.sum().astype(jnp.int32)
    return ReplayBuffer(data, (buffer.ptr + count) % capacity, jnp.minimum(buffer.size + count, capacity))


def sample(buffer: ReplayBuffer, key: jax.Array, batch_size: int) -> Transitions:
    """`batch_size` transitions drawn uniformly, with replacement, from the filled slots (size must be > 0)."""
    indices = jax.random.randint(key, (batch_size,), 0, jnp.maximum(buffer.size, 1), dtype=jnp.int32)
    return jax.tree_util.tree_map(lambda store: store[indices], buffer.data)
