"""The PPO loss as a pure function of parameters and one minibatch."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from canter.config import NetConfig, PPOConfig
from canter.networks import Params, gaussian_entropy, gaussian_log_prob, policy_dist, value


class Minibatch(NamedTuple):
    obs: jnp.ndarray          # [B, obs_dim], normalized as the policy saw it
    actions: jnp.ndarray      # [B, act_dim], unclipped samples
    log_probs: jnp.ndarray    # [B], under the policy that collected them
    values: jnp.ndarray       # [B], critic estimates at collection time
    advantages: jnp.ndarray   # [B]
    returns: jnp.ndarray      # [B]
    mask: jnp.ndarray         # [B], 0 for EnvPool autoreset steps


def masked_mean(x: jnp.ndarray, mask: jnp.ndarray) -> jnp.ndarray:
    return jnp.sum(x * mask) / jnp.maximum(jnp.sum(mask), 1.0)


def normalize_advantages(advantages: jnp.ndarray, mask: jnp.ndarray) -> jnp.ndarray:
    """Zero mean, unit (unbiased) std over the valid entries, as CleanRL does per minibatch."""
    count = jnp.maximum(jnp.sum(mask), 2.0)
    mean = jnp.sum(advantages * mask) / jnp.maximum(jnp.sum(mask), 1.0)
    std = jnp.sqrt(jnp.sum(jnp.square(advantages - mean) * mask) / (count - 1.0))
    return (advantages - mean) / (std + 1e-8)


def ppo_loss(params: Params, batch: Minibatch, net: NetConfig, ppo: PPOConfig) -> tuple[jnp.ndarray, dict]:
    """Clipped surrogate + (optionally clipped) value loss - entropy bonus. Returns (loss, diagnostics)."""
    mask = batch.mask
    mean, log_std = policy_dist(params, batch.obs, net)
    new_log_probs = gaussian_log_prob(mean, log_std, batch.actions)
    log_ratio = new_log_probs - batch.log_probs
    ratio = jnp.exp(log_ratio)

    advantages = normalize_advantages(batch.advantages, mask) if ppo.norm_adv else batch.advantages
    surrogate = -advantages * ratio
    surrogate_clipped = -advantages * jnp.clip(ratio, 1.0 - ppo.clip, 1.0 + ppo.clip)
    policy_loss = masked_mean(jnp.maximum(surrogate, surrogate_clipped), mask)

    new_values = value(params, batch.obs, net)
    value_error = jnp.square(new_values - batch.returns)
    if ppo.clip_vloss:
        clipped_values = batch.values + jnp.clip(new_values - batch.values, -ppo.clip, ppo.clip)
        value_error = jnp.maximum(value_error, jnp.square(clipped_values - batch.returns))
    value_loss = 0.5 * masked_mean(value_error, mask)

    entropy = masked_mean(gaussian_entropy(log_std), mask)
    loss = policy_loss - ppo.ent_coef * entropy + ppo.vf_coef * value_loss
    diagnostics = {
        "policy_loss": policy_loss,
        "value_loss": value_loss,
        "entropy": entropy,
        # The low-variance k3 estimator of KL(old || new) (Schulman's note), as CleanRL logs it.
        "approx_kl": masked_mean((ratio - 1.0) - log_ratio, mask),
        "clip_frac": masked_mean((jnp.abs(ratio - 1.0) > ppo.clip).astype(jnp.float32), mask),
    }
    return loss, diagnostics
