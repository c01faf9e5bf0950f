"""Several seeds in one program: `jax.vmap` over an algorithm's unchanged `iteration(state, carry, lr_fraction)`,
with every seed's envs living in ONE vectorized env of group_size * num_envs slots.

EnvPool's XLA step cannot be vmapped, and an `io_callback` should not be. `group_step` wraps the real step in
`jax.custom_batching.custom_vmap`: under the vmap its rule sees the actions of all seeds at once, [S, N, A],
flattens them seed-major to [S * N, A], steps the one env, and splits every output back to [S, N, ...]. Seed s
therefore owns slots s * N ... (s + 1) * N - 1, which is why the group env is built from the seeds' env-seed lists
concatenated in group order.

The env handle in the carry (EnvPool's XLA handle, the Gymnasium step counter) is the same for every seed: it is
stacked S times like everything else, the rule steps with copy 0 and broadcasts the new handle back.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np


def group_step(env_step: Callable[[Any, Any], tuple[Any, Any]], group_size: int) -> Callable[[Any, Any], Any]:
    """An env step for one seed's [N, A] actions that, under `jax.vmap` over group_size seeds, steps the shared
    env of group_size * N slots once."""

    def split(x: jnp.ndarray) -> jnp.ndarray:
        return x.reshape((group_size, -1) + x.shape[1:])

    @jax.custom_batching.custom_vmap
    def step(state: Any, action: jnp.ndarray) -> tuple[Any, Any]:
        # Only traced for shapes: a group always steps under the vmap, where the rule below runs instead.
        batched = jnp.broadcast_to(action, (group_size,) + action.shape)
        new_state, out = env_step(state, batched.reshape((-1,) + action.shape[1:]))
        return new_state, jax.tree.map(lambda x: split(x)[0], out)

    @step.def_vmap
    def rule(axis_size: int, in_batched: list, state: Any, action: jnp.ndarray) -> tuple[Any, Any]:
        if axis_size != group_size:
            raise ValueError(f"group_step built for {group_size} seeds is vmapped over {axis_size}")
        state_batched, action_batched = in_batched
        state = jax.tree.map(lambda x, b: x[0] if b else x, state, state_batched)
        if not action_batched:
            action = jnp.broadcast_to(action, (group_size,) + action.shape)
        flat = action.reshape((-1,) + action.shape[2:])
        # A seed that diverged stays in the group program until the last seed is done; keep its NaN actions out
        # of the shared env (finite actions pass unchanged).
        flat = jnp.where(jnp.isfinite(flat), flat, jnp.zeros_like(flat))
        new_state, out = env_step(state, flat)
        new_state = jax.tree.map(lambda x: jnp.broadcast_to(x, (group_size,) + x.shape), new_state)
        out = jax.tree.map(split, out)
        return (new_state, out), jax.tree.map(lambda _: True, (new_state, out))

    return step


def stack(trees: list[Any]) -> Any:
    """One pytree with a leading seed axis from one pytree per seed."""
    return jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *trees)


def unstack(tree: Any, index: int) -> Any:
    """Seed `index` of a pytree with a leading seed axis (host arrays stay host arrays)."""
    return jax.tree.map(lambda x: x[index], tree)


def split_first_obs(first_obs: np.ndarray, group_size: int) -> list[np.ndarray]:
    """The group env's first observations [S * N, D] as one [N, D] block per seed."""
    return list(np.asarray(first_obs).reshape((group_size, -1) + np.shape(first_obs)[1:]))


def split_env_state(env_state: Any, group_size: int) -> list[Any]:
    """The state of a vmappable group env (every leaf [S * N, ...]) as one [N, ...] state per seed."""
    split = jax.tree.map(lambda x: x.reshape((group_size, x.shape[0] // group_size) + x.shape[1:]), env_state)
    return [unstack(split, i) for i in range(group_size)]
