"""Actor and critic MLPs and the diagonal Gaussian policy, as pure functions over plain parameter dicts."""

from __future__ import annotations

import itertools
import math
from typing import Any

import jax
import jax.numpy as jnp

from canter.core.netconfig import NetConfig

Params = dict[str, Any]

# One function per name in netconfig.ACTIVATIONS.
ACTIVATION_FUNCTIONS = {"tanh": jnp.tanh, "relu": jax.nn.relu, "elu": jax.nn.elu}
LOG_2PI = math.log(2.0 * math.pi)


def _dense(key: jax.Array, n_in: int, n_out: int, gain: float, ortho: bool) -> dict[str, jnp.ndarray]:
    if ortho:
        w = jax.nn.initializers.orthogonal(gain)(key, (n_in, n_out), jnp.float32)
    else:
        # PyTorch's default Linear init, the usual alternative (RL Zoo's ortho_init=False).
        bound = 1.0 / math.sqrt(n_in)
        w = jax.random.uniform(key, (n_in, n_out), jnp.float32, -bound, bound)
    return {"w": w, "b": jnp.zeros((n_out,), jnp.float32)}


def init_mlp(key: jax.Array, sizes: list[int], out_gain: float, ortho: bool) -> list[dict[str, jnp.ndarray]]:
    keys = jax.random.split(key, len(sizes) - 1)
    layers = []
    for i, (n_in, n_out) in enumerate(itertools.pairwise(sizes)):
        last = i == len(sizes) - 2
        layers.append(_dense(keys[i], n_in, n_out, out_gain if last else math.sqrt(2.0), ortho))
    return layers


def mlp(layers: list[dict[str, jnp.ndarray]], x: jnp.ndarray, activation: str) -> jnp.ndarray:
    act = ACTIVATION_FUNCTIONS[activation]
    for layer in layers[:-1]:
        x = act(x @ layer["w"] + layer["b"])
    return x @ layers[-1]["w"] + layers[-1]["b"]


def init_params(key: jax.Array, net: NetConfig, obs_dim: int, act_dim: int) -> Params:
    actor_key, critic_key = jax.random.split(key)
    critic_hidden = list(net.critic_hidden or net.hidden)
    actor_out = 2 * act_dim if net.state_dependent_std else act_dim
    actor = init_mlp(actor_key, [obs_dim, *net.hidden, actor_out], 0.01, net.ortho_init)
    if net.state_dependent_std:
        # Start the log-std half of the head at log_std_init regardless of the observation.
        last = actor[-1]
        actor[-1] = {"w": last["w"].at[:, act_dim:].set(0.0), "b": last["b"].at[act_dim:].set(net.log_std_init)}
    params: Params = {
        "actor": actor,
        "critic": init_mlp(critic_key, [obs_dim, *critic_hidden, 1], 1.0, net.ortho_init),
    }
    if not net.state_dependent_std:
        params["log_std"] = jnp.full((act_dim,), net.log_std_init, jnp.float32)
    return params


def policy_dist(params: Params, obs: jnp.ndarray, net: NetConfig) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Mean and log std of the Gaussian policy for a batch of normalized observations."""
    out = mlp(params["actor"], obs, net.activation)
    if net.state_dependent_std:
        act_dim = out.shape[-1] // 2
        return out[..., :act_dim], jnp.clip(out[..., act_dim:], -20.0, 2.0)
    return out, jnp.broadcast_to(params["log_std"], out.shape)


def value(params: Params, obs: jnp.ndarray, net: NetConfig) -> jnp.ndarray:
    return mlp(params["critic"], obs, net.activation)[..., 0]


def gaussian_log_prob_per_dim(mean: jnp.ndarray, log_std: jnp.ndarray, action: jnp.ndarray) -> jnp.ndarray:
    """Log density of each action dimension of the diagonal Gaussian."""
    z = (action - mean) * jnp.exp(-log_std)
    return -0.5 * jnp.square(z) - log_std - 0.5 * LOG_2PI


def gaussian_log_prob(mean: jnp.ndarray, log_std: jnp.ndarray, action: jnp.ndarray) -> jnp.ndarray:
    """Log density summed over action dimensions."""
    return jnp.sum(gaussian_log_prob_per_dim(mean, log_std, action), axis=-1)


def gaussian_entropy(log_std: jnp.ndarray) -> jnp.ndarray:
    return jnp.sum(log_std + 0.5 * (1.0 + LOG_2PI), axis=-1)


def all_finite(tree: Any) -> jnp.ndarray:
    """Whether every floating-point leaf of a pytree (parameters, optimizer moments, a rollout) is finite; integer
    leaves such as step counters cannot be anything else."""
    return jnp.all(
        jnp.stack(
            [jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves(tree) if jnp.issubdtype(x.dtype, jnp.floating)]
        )
    )


def sample_action(key: jax.Array, mean: jnp.ndarray, log_std: jnp.ndarray) -> jnp.ndarray:
    return mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape, mean.dtype)
