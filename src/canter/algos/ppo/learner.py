"""One PPO update over a collected batch: epochs of shuffled minibatches, all under jit.

Gradients of actor and critic are clipped together by global norm, then Adam moments are computed once and the
step is scaled by a learning rate per part, so a separate critic learning rate costs nothing extra.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from canter.algos.ppo.losses import (
    LossVariant,
    Minibatch,
    gaussian_kl,
    masked_mean,
    ppo_loss,
)
from canter.config.schema import Config
from canter.core.networks import Params, policy_dist

KL_BETA_MIN, KL_BETA_MAX = 1e-5, 1e5


def make_optimizer(config: Config) -> optax.GradientTransformation:
    return optax.chain(
        optax.clip_by_global_norm(config.ppo.max_grad_norm), optax.scale_by_adam(eps=config.ppo.adam_eps)
    )


def _apply_lrs(updates: Params, actor_lr: Any, critic_lr: Any) -> Params:
    def descend(tree: Any, lr: Any) -> Any:
        return jax.tree_util.tree_map(lambda u: (-lr * u).astype(u.dtype), tree)

    return {k: descend(v, critic_lr if k == "critic" else actor_lr) for k, v in updates.items()}


class UpdateResult(NamedTuple):
    params: Params
    opt_state: Any
    diagnostics: dict


def ppo_update(
    params: Params,
    opt_state: Any,
    batch: Minibatch,
    key: jax.Array,
    actor_lr: Any,
    critic_lr: Any,
    config: Config,
    variant: LossVariant = LossVariant(),
    kl_beta: Any = 0.0,
) -> UpdateResult:
    """Run `epochs` passes of `num_minibatches` gradient steps; stop early on target KL if configured.

    `variant` selects the loss (ppo, rpo, kl_penalty, symmetric term); `kl_beta` is the current penalty weight.
    The diagnostics include `policy_kl`, the exact mean KL(old || new) over the batch after the update, and the
    global norm of each step's gradient before `ppo.max_grad_norm` clips it: `grad_norm` (mean over the steps) and
    `grad_norm_max` (the largest), which say how often and how hard the clip acts."""
    optimizer = make_optimizer(config)
    batch_size = batch.mask.shape[0]
    num_minibatches = batch_size // config.ppo.minibatch_size
    target_kl = config.ppo.target_kl
    grad_fn = jax.value_and_grad(ppo_loss, has_aux=True)
    diag_names: tuple[str, ...] = ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_frac", "grad_norm")
    diag_names += ("sym_loss",) if variant.symmetric else ()
    zero_diag = {k: jnp.float32(0.0) for k in diag_names}
    old_mean, old_log_std = policy_dist(params, batch.obs, config.net)
    if variant.kl_penalty:
        batch = batch._replace(old_mean=old_mean, old_log_std=old_log_std)

    def minibatch_step(carry, step):
        params, opt_state = carry
        indices, loss_key = step
        minibatch = jax.tree_util.tree_map(lambda x: x[indices], batch)
        (_, diag), grads = grad_fn(params, minibatch, config.net, config.ppo, variant, loss_key, kl_beta)
        diag = diag | {"grad_norm": optax.tree.norm(grads)}
        updates, opt_state = optimizer.update(grads, opt_state, params)
        params = optax.apply_updates(params, _apply_lrs(updates, actor_lr, critic_lr))
        return (params, opt_state), diag

    def epoch(carry, epoch_key):
        params, opt_state, stopped, sums, count, peak = carry

        def run(operand):
            params, opt_state = operand
            permutation = jax.random.permutation(epoch_key, batch_size)
            # A derived key for RPO's shifts, so that ppo's minibatch order does not depend on whether RPO shifts
            # are drawn.
            loss_keys = jax.random.split(jax.random.fold_in(epoch_key, 1), num_minibatches)
            steps = (permutation.reshape(num_minibatches, -1), loss_keys)
            (params, opt_state), diags = jax.lax.scan(minibatch_step, (params, opt_state), steps)
            return params, opt_state, diags

        def skip(operand):
            params, opt_state = operand
            return params, opt_state, {k: jnp.zeros((num_minibatches,), jnp.float32) for k in zero_diag}

        params, opt_state, diags = jax.lax.cond(stopped, skip, run, (params, opt_state))
        ran = 1.0 - stopped.astype(jnp.float32)
        sums = {k: sums[k] + ran * diags[k].mean() for k in sums}
        peak = jnp.maximum(peak, ran * diags["grad_norm"].max())
        if target_kl is not None:
            stopped = stopped | (diags["approx_kl"][-1] > target_kl)
        return (params, opt_state, stopped, sums, count + ran, peak), None

    keys = jax.random.split(key, config.ppo.epochs)
    init = (params, opt_state, jnp.asarray(False), zero_diag, jnp.float32(0.0), jnp.float32(0.0))
    (params, opt_state, _, sums, count, peak), _ = jax.lax.scan(epoch, init, keys)
    diagnostics = {k: v / jnp.maximum(count, 1.0) for k, v in sums.items()}
    diagnostics["grad_norm_max"] = peak
    diagnostics["epochs_run"] = count
    new_mean, new_log_std = policy_dist(params, batch.obs, config.net)
    diagnostics["policy_kl"] = masked_mean(gaussian_kl(old_mean, old_log_std, new_mean, new_log_std), batch.mask)
    return UpdateResult(params, opt_state, diagnostics)


def adapt_kl_beta(beta: Any, kl: Any, target: float) -> Any:
    """The PPO paper's rule (sec. 4): halve beta when KL < target / 1.5, double it when KL > 1.5 target. Beta is
    kept in [1e-5, 1e5] so a long run of tiny (or huge) KLs cannot strand it at 0 (or inf)."""
    beta = jnp.where(kl < target / 1.5, beta / 2.0, jnp.where(kl > target * 1.5, beta * 2.0, beta))
    return jnp.clip(beta, KL_BETA_MIN, KL_BETA_MAX)
