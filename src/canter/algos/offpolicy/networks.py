"""Actors and critics of the off-policy algorithms, as pure functions over plain parameter dicts.

Actions inside the learner live in [-1, 1]: actors end in tanh, the replay buffer stores these coordinates, and only
the env sees `center + half_range * a`. The critics of one algorithm (two for td3 and sac, one for ddpg) are one
parameter tree whose leaves carry a leading critic axis, evaluated with `vmap`: one batched matmul per layer instead
of one per critic. Every network learns by Adam at a constant learning rate.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import optax

from canter.core.networks import init_mlp, mlp

# SAC's log std is squashed into this range with tanh (smooth, unlike a clip, so its gradient never vanishes).
LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0


def init_actor(key: jax.Array, obs_dim: int, out_dim: int, hidden: tuple[int, ...]) -> list:
    # PyTorch's default Linear weight init, as the reference TD3/SAC implementations use (biases start at 0 here).
    return init_mlp(key, [obs_dim, *hidden, out_dim], 1.0, ortho=False)


def init_critics(key: jax.Array, obs_dim: int, act_dim: int, hidden: tuple[int, ...], count: int) -> list:
    """`count` independent Q networks stacked along a leading axis of every leaf."""
    keys = jax.random.split(key, count)
    # Jitted: an eager vmap dispatches (and compiles) every initializer op separately, which takes seconds.
    return jax.jit(jax.vmap(lambda k: init_mlp(k, [obs_dim + act_dim, *hidden, 1], 1.0, ortho=False)))(keys)


def deterministic_action(actor: list, obs: jnp.ndarray, activation: str) -> jnp.ndarray:
    """The td3/ddpg actor: an action in [-1, 1]."""
    return jnp.tanh(mlp(actor, obs, activation))


def q_values(critics: list, obs: jnp.ndarray, action: jnp.ndarray, activation: str) -> jnp.ndarray:
    """Q of every critic: [num_critics, batch]."""
    x = jnp.concatenate([obs, action], axis=-1)
    return jax.vmap(lambda layers: mlp(layers, x, activation)[..., 0])(critics)


def first_critic(critics: list) -> list:
    return jax.tree_util.tree_map(lambda leaf: leaf[:1], critics)


def squashed_gaussian(actor: list, obs: jnp.ndarray, activation: str) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Mean and log std of the pre-tanh Gaussian of the sac actor."""
    out = mlp(actor, obs, activation)
    act_dim = out.shape[-1] // 2
    mean, raw = out[..., :act_dim], out[..., act_dim:]
    log_std = LOG_STD_MIN + 0.5 * (LOG_STD_MAX - LOG_STD_MIN) * (jnp.tanh(raw) + 1.0)
    return mean, log_std


def init_adam(params: Any, lr: float) -> Any:
    return optax.adam(lr).init(params)


def adam_step(params: Any, opt_state: Any, grads: Any, lr: float) -> tuple[Any, Any]:
    """(params, opt_state) after one Adam step along `grads`."""
    updates, opt_state = optax.adam(lr).update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state
