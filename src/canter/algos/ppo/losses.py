"""The PPO loss as a pure function of parameters and one minibatch, with its variants: RPO's shifted mean, the
adaptive-KL objective, and the symmetric action term."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from canter.algos.ppo.sections import PPOConfig
from canter.algos.ppo.symmetry import MirrorPair, parse_groups, symmetric_loss
from canter.config.schema import Config
from canter.core.netconfig import NetConfig
from canter.core.networks import (
    Params,
    gaussian_entropy,
    gaussian_log_prob,
    gaussian_log_prob_per_dim,
    policy_dist,
    value,
)


class Minibatch(NamedTuple):
    obs: jnp.ndarray  # [B, obs_dim], normalized as the policy saw it
    actions: jnp.ndarray  # [B, act_dim], unclipped samples
    log_probs: jnp.ndarray  # [B], under the policy that collected them
    values: jnp.ndarray  # [B], critic estimates at collection time
    advantages: jnp.ndarray  # [B]
    returns: jnp.ndarray  # [B]
    mask: jnp.ndarray  # [B], 0 for EnvPool autoreset steps
    old_mean: Any = None  # [B, act_dim], the collecting policy's mean; only the kl_penalty objective needs it
    old_log_std: Any = None  # [B, act_dim]


@dataclass(frozen=True)
class LossVariant:
    """The static choices that turn the PPO loss into one of its relatives."""

    rpo_alpha: float = 0.0  # > 0: RPO, the mean is shifted by U(-alpha, alpha) per dimension
    kl_penalty: bool = False  # surrogate - beta * KL instead of the clipped surrogate
    sym_coef: float = 0.0
    sym_pairs: tuple[MirrorPair, ...] = ()
    sym_compare: str = "mean"  # or "log_prob"

    @property
    def symmetric(self) -> bool:
        return self.sym_coef > 0 and bool(self.sym_pairs)


def loss_variant(config: Config, rpo: bool) -> LossVariant:
    return LossVariant(
        rpo_alpha=config.rpo.alpha if rpo else 0.0,
        kl_penalty=config.ppo.objective == "kl_penalty",
        sym_coef=config.sym.coef,
        sym_pairs=parse_groups(config.sym.groups, config.sym.negate),
        sym_compare=config.sym.compare,
    )


def gaussian_kl(
    mean_p: jnp.ndarray, log_std_p: jnp.ndarray, mean_q: jnp.ndarray, log_std_q: jnp.ndarray
) -> jnp.ndarray:
    """KL(p || q) of diagonal Gaussians, summed over the last axis."""
    var_p, var_q = jnp.exp(2.0 * log_std_p), jnp.exp(2.0 * log_std_q)
    return jnp.sum(log_std_q - log_std_p + (var_p + jnp.square(mean_p - mean_q)) / (2.0 * var_q) - 0.5, axis=-1)


def rpo_shift(key: jax.Array, mean: jnp.ndarray, alpha: float) -> jnp.ndarray:
    """RPO: the mean plus z ~ U(-alpha, alpha), drawn independently per sample and dimension."""
    return mean + jax.random.uniform(key, mean.shape, mean.dtype, -alpha, alpha)


def masked_mean(x: jnp.ndarray, mask: jnp.ndarray) -> jnp.ndarray:
    return jnp.sum(x * mask) / jnp.maximum(jnp.sum(mask), 1.0)


def normalize_advantages(advantages: jnp.ndarray, mask: jnp.ndarray) -> jnp.ndarray:
    """Zero mean, unit (unbiased) std over the valid entries, as CleanRL does per minibatch."""
    count = jnp.maximum(jnp.sum(mask), 2.0)
    mean = jnp.sum(advantages * mask) / jnp.maximum(jnp.sum(mask), 1.0)
    std = jnp.sqrt(jnp.sum(jnp.square(advantages - mean) * mask) / (count - 1.0))
    return (advantages - mean) / (std + 1e-8)


def ppo_loss(
    params: Params,
    batch: Minibatch,
    net: NetConfig,
    ppo: PPOConfig,
    variant: LossVariant = LossVariant(),
    key: jax.Array | None = None,
    kl_beta: Any = 0.0,
) -> tuple[jnp.ndarray, dict]:
    """Clipped surrogate (or surrogate - kl_beta * KL) + (optionally clipped) value loss - entropy bonus
    [+ sym_coef * symmetric action loss]. `key` draws RPO's shift. Returns (loss, diagnostics)."""
    mask = batch.mask
    mean, log_std = policy_dist(params, batch.obs, net)
    # RPO re-evaluates the stored actions under a shifted mean; everything downstream sees the shifted policy.
    eval_mean = mean
    if variant.rpo_alpha > 0:
        assert key is not None, "RPO draws its mean shift from `key`"
        eval_mean = rpo_shift(key, mean, variant.rpo_alpha)
    new_log_probs = gaussian_log_prob(eval_mean, log_std, batch.actions)
    log_ratio = new_log_probs - batch.log_probs
    ratio = jnp.exp(log_ratio)

    advantages = normalize_advantages(batch.advantages, mask) if ppo.norm_adv else batch.advantages
    surrogate = -advantages * ratio
    if variant.kl_penalty:
        kl = gaussian_kl(batch.old_mean, batch.old_log_std, mean, log_std)
        policy_loss = masked_mean(surrogate + kl_beta * kl, mask)
    else:
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
    diagnostics = {}
    if variant.symmetric:
        if variant.sym_compare == "mean":
            sym_loss = symmetric_loss(mean, variant.sym_pairs, mask, use_signs=True)
        else:
            per_dim = gaussian_log_prob_per_dim(eval_mean, log_std, batch.actions)
            sym_loss = symmetric_loss(per_dim, variant.sym_pairs, mask, use_signs=False)
        loss = loss + variant.sym_coef * sym_loss
        diagnostics["sym_loss"] = sym_loss
    diagnostics.update(
        {
            "policy_loss": policy_loss,
            "value_loss": value_loss,
            "entropy": entropy,
            # The low-variance k3 estimator of KL(old || new) (Schulman's note), as CleanRL logs it.
            "approx_kl": masked_mean((ratio - 1.0) - log_ratio, mask),
            "clip_frac": masked_mean((jnp.abs(ratio - 1.0) > ppo.clip).astype(jnp.float32), mask),
        }
    )
    return loss, diagnostics
