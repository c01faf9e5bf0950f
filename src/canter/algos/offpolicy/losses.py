"""The off-policy targets and losses as pure functions of arrays, each small enough to check by hand, and the
critic step that td3, ddpg and sac share."""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp

from canter.algos.offpolicy.networks import adam_step, q_values
from canter.core.networks import gaussian_log_prob

LOG_2 = math.log(2.0)


def min_over_critics(q: jnp.ndarray) -> jnp.ndarray:
    """The smallest Q of each transition, [B] of q [num_critics, B], as a chain of pairwise minimums. `jnp.min`'s
    gradient divides by how many entries equal the minimum it computed; where the compiler evaluates the two with
    different rounding (vmapped sac seeds compiled with XLA's optimizations off did), no entry does and the actor's
    gradient is 0/0 = NaN. A pairwise minimum's gradient selects, and never divides."""
    smallest = q[0]
    for other in q[1:]:
        smallest = jnp.minimum(smallest, other)
    return smallest


def td_target(
    reward: jnp.ndarray,
    terminated: jnp.ndarray,
    next_q: jnp.ndarray,
    gamma: float,
    next_entropy_bonus: jnp.ndarray | float = 0.0,
) -> jnp.ndarray:
    """`r + gamma * (1 - terminated) * (min over critics of next_q + bonus)`; next_q is [num_critics, B].
    Truncated transitions have terminated = 0 and so bootstrap."""
    return reward + gamma * (1.0 - terminated) * (min_over_critics(next_q) + next_entropy_bonus)


def smoothed_target_action(
    target_action: jnp.ndarray, noise: jnp.ndarray, noise_std: float, noise_clip: float
) -> jnp.ndarray:
    """TD3's target policy smoothing: `clip(a' + clip(std * noise, -c, c), -1, 1)` for standard normal `noise`."""
    return jnp.clip(target_action + jnp.clip(noise_std * noise, -noise_clip, noise_clip), -1.0, 1.0)


def critic_loss(q: jnp.ndarray, target: jnp.ndarray) -> jnp.ndarray:
    """Sum over critics of the mean squared TD error; q is [num_critics, B]."""
    return jnp.sum(jnp.mean(jnp.square(q - target[None]), axis=-1))


def critic_step(
    critics: Any, critic_opt: Any, batch: Any, target: jnp.ndarray, activation: str, lr: float
) -> tuple[Any, Any, jnp.ndarray, jnp.ndarray]:
    """One Adam step of the critics on `critic_loss` of their Q at the batch's (obs, action) against `target` [B].
    Returns (critics, critic_opt, the loss, q [num_critics, B]), the loss and q from before the step."""

    def objective(critics):
        q = q_values(critics, batch.obs, batch.action, activation)
        return critic_loss(q, target), q

    (loss, q), grads = jax.value_and_grad(objective, has_aux=True)(critics)
    critics, critic_opt = adam_step(critics, critic_opt, grads, lr)
    return critics, critic_opt, loss, q


def polyak(target: Any, online: Any, tau: float) -> Any:
    """`tau * online + (1 - tau) * target`, leaf by leaf."""
    return jax.tree_util.tree_map(lambda t, o: (tau * o + (1.0 - tau) * t).astype(t.dtype), target, online)


def tanh_log_det_jacobian(pre_tanh: jnp.ndarray) -> jnp.ndarray:
    """`sum log(1 - tanh(u)^2)` over action dims, in the stable form `2 * (log 2 - u - softplus(-2u))`."""
    return jnp.sum(2.0 * (LOG_2 - pre_tanh - jax.nn.softplus(-2.0 * pre_tanh)), axis=-1)


def squashed_sample(mean: jnp.ndarray, log_std: jnp.ndarray, noise: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """`a = tanh(mean + std * noise)` and its log density in [-1, 1] action coordinates (change of variables)."""
    pre_tanh = mean + jnp.exp(log_std) * noise
    log_prob = gaussian_log_prob(mean, log_std, pre_tanh) - tanh_log_det_jacobian(pre_tanh)
    return jnp.tanh(pre_tanh), log_prob


def sac_actor_loss(q: jnp.ndarray, log_prob: jnp.ndarray, alpha: jnp.ndarray) -> jnp.ndarray:
    """`mean(alpha * log pi(a|s) - min over critics of Q(s, a))`, a ~ pi; q is [num_critics, B]."""
    return jnp.mean(alpha * log_prob - min_over_critics(q))


def temperature_loss(log_alpha: jnp.ndarray, log_prob: jnp.ndarray, target_entropy: float) -> jnp.ndarray:
    """`-mean(log_alpha * (log pi + target_entropy))`: its gradient raises alpha while the policy's entropy
    (-log pi) is below the target and lowers it above."""
    return -jnp.mean(log_alpha * jax.lax.stop_gradient(log_prob + target_entropy))


def deterministic_actor_loss(q: jnp.ndarray) -> jnp.ndarray:
    """`-mean Q1(s, mu(s))`; q is [1, B] (the first critic only, as in TD3)."""
    return -jnp.mean(q[0])
