"""The jitted unit of TRPO training: rollout, GAE, one natural-gradient policy step with a backtracking line
search, then Adam regression of the critic on the GAE returns.

The rollout, reward scaling and GAE are PPO's (`canter.algos.onpolicy_rollout.collect`, `canter.core.gae`), so they read
ppo.n_steps, ppo.gamma, ppo.gae_lambda and ppo.norm_adv.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from jax.flatten_util import ravel_pytree

from canter.algos.onpolicy_rollout import (
    Collected,
    chain,
    estimate_advantages,
    explained_variance,
    make_rollout,
    rollout_report,
)
from canter.algos.ppo.losses import gaussian_kl, masked_mean, normalize_advantages
from canter.algos.trpo.natural import (
    backtracking_line_search,
    conjugate_gradient,
    fisher_vector_product,
)
from canter.config.schema import Config
from canter.core.counters import count_dtype
from canter.core.networks import (
    Params,
    gaussian_entropy,
    gaussian_log_prob,
    init_params,
    policy_dist,
    value,
)
from canter.core.normalize import RunningStats, init_stats
from canter.envs.base import EnvSpec
from canter.envs.episodes import EnvCarry


class TrainState(NamedTuple):
    """Everything a checkpoint must hold to continue learning exactly."""

    params: Params  # {"actor", "log_std" (unless state-dependent), "critic"}
    critic_opt_state: Any
    obs_stats: RunningStats
    return_stats: RunningStats
    key: jax.Array
    iteration: jnp.ndarray
    global_step: jnp.ndarray


def critic_optimizer(config: Config) -> optax.GradientTransformation:
    return optax.adam(config.trpo.critic_lr)


def init_train_state(config: Config, obs_dim: int, act_dim: int, seed: Any) -> TrainState:
    """The state of run seed `seed` (a Python int or a uint32 scalar, traced or not: the same state either way)."""
    key, init_key = jax.random.split(jax.random.key(seed))
    params = init_params(init_key, config.net, obs_dim, act_dim)
    return TrainState(
        params=params,
        critic_opt_state=critic_optimizer(config).init(params["critic"]),
        obs_stats=init_stats((obs_dim,)),
        return_stats=init_stats(()),
        key=jax.random.key_data(key),
        iteration=jnp.zeros((), jnp.int32),
        global_step=jnp.zeros((), count_dtype()),
    )


def split_policy(params: Params) -> tuple[Params, Params]:
    """(policy part, critic part); policy_dist reads only the policy part."""
    return {k: v for k, v in params.items() if k != "critic"}, params["critic"]


class PolicyBatch(NamedTuple):
    obs: jnp.ndarray
    actions: jnp.ndarray
    advantages: jnp.ndarray
    mask: jnp.ndarray


class PolicyObjectives(NamedTuple):
    theta: jnp.ndarray  # the current policy parameters, flattened
    unravel: Any  # flat vector -> policy params
    surrogate: Any  # flat -> E[pi(a|s) / pi_old(a|s) * A], to maximize
    mean_kl: Any  # flat -> E[KL(pi_old(.|s) || pi(.|s))]; its Hessian at theta is the Fisher matrix


def policy_objectives(policy: Params, batch: PolicyBatch, config: Config) -> PolicyObjectives:
    """The surrogate and the mean KL as functions of the flattened policy parameters, with the old policy (and
    its log-probabilities) fixed at `policy`."""
    net = config.net
    theta, unravel = ravel_pytree(policy)
    old_mean, old_log_std = jax.lax.stop_gradient(policy_dist(policy, batch.obs, net))
    old_log_prob = gaussian_log_prob(old_mean, old_log_std, batch.actions)

    def surrogate(flat):
        mean, log_std = policy_dist(unravel(flat), batch.obs, net)
        ratio = jnp.exp(gaussian_log_prob(mean, log_std, batch.actions) - old_log_prob)
        return masked_mean(ratio * batch.advantages, batch.mask)

    def mean_kl(flat):
        mean, log_std = policy_dist(unravel(flat), batch.obs, net)
        return masked_mean(gaussian_kl(old_mean, old_log_std, mean, log_std), batch.mask)

    return PolicyObjectives(theta, unravel, surrogate, mean_kl)


def policy_step(policy: Params, batch: PolicyBatch, config: Config) -> tuple[Params, dict]:
    """One TRPO step: natural gradient of the importance-sampled surrogate by conjugate gradient, scaled to the
    trust region's edge, then a backtracking line search on the true surrogate and KL."""
    trpo = config.trpo
    theta, unravel, surrogate, mean_kl = policy_objectives(policy, batch, config)
    gradient = jax.grad(surrogate)(theta)
    fvp = fisher_vector_product(mean_kl, theta, trpo.cg_damping)
    cg = conjugate_gradient(fvp, gradient, trpo.cg_iters)
    curvature = jnp.vdot(cg.x, fvp(cg.x))
    # Step to where the quadratic model of the KL reaches max_kl: 0.5 s^T F s = max_kl.
    scale = jnp.sqrt(2.0 * trpo.max_kl / jnp.maximum(curvature, 1e-12))
    full_step = jnp.where((curvature > 0) & jnp.isfinite(curvature), scale, 0.0) * cg.x
    search = backtracking_line_search(
        surrogate, mean_kl, theta, full_step, trpo.max_kl, trpo.line_search_shrink, trpo.line_search_iters
    )
    diagnostics = {
        "surrogate_gain": search.improvement,
        "policy_kl": search.kl,
        "step_accepted": search.accepted.astype(jnp.float32),
        "step_fraction": search.fraction,
        "line_search_steps": search.steps.astype(jnp.float32),
        "cg_iterations": cg.iterations.astype(jnp.float32),
        "cg_residual": cg.residual_norm,
        "entropy": masked_mean(gaussian_entropy(policy_dist(policy, batch.obs, config.net)[1]), batch.mask),
    }
    return unravel(search.theta), diagnostics


def critic_regression(
    critic: Params,
    opt_state: Any,
    obs: jnp.ndarray,
    returns: jnp.ndarray,
    mask: jnp.ndarray,
    key: jax.Array,
    config: Config,
) -> tuple[Params, Any, jnp.ndarray]:
    """`trpo.critic_epochs` passes of Adam on the masked MSE to the returns, in shuffled minibatches. Returns the
    new critic, optimizer state and the mean loss of the last epoch."""
    optimizer = critic_optimizer(config)
    batch_size = mask.shape[0]
    num_minibatches = batch_size // config.trpo.critic_minibatch_size

    def loss_fn(critic, indices):
        predicted = value({"critic": critic}, obs[indices], config.net)
        return masked_mean(jnp.square(predicted - returns[indices]), mask[indices])

    grad_fn = jax.value_and_grad(loss_fn)

    def minibatch_step(carry, indices):
        critic, opt_state = carry
        loss, grads = grad_fn(critic, indices)
        updates, opt_state = optimizer.update(grads, opt_state, critic)
        return (optax.apply_updates(critic, updates), opt_state), loss

    def epoch(carry, epoch_key):
        permutation = jax.random.permutation(epoch_key, batch_size).reshape(num_minibatches, -1)
        carry, losses = jax.lax.scan(minibatch_step, carry, permutation)
        return carry, losses.mean()

    (critic, opt_state), losses = jax.lax.scan(
        epoch, (critic, opt_state), jax.random.split(key, config.trpo.critic_epochs)
    )
    return critic, opt_state, losses[-1]


def make_parts(config: Config, spec: EnvSpec, env_step: Any) -> tuple[Callable, Callable]:
    """The iteration's two parts, `rollout(state, carry) -> (state, carry, collected)` (canter.algos.onpolicy_rollout)
    and `learn(state, collected, lr_fraction) -> (state, metrics)`: GAE, the natural-gradient policy step and the
    critic's regression. TRPO has no policy learning rate, and the critic's is constant, so lr_fraction is unused."""

    def learn(state: TrainState, collected: Collected, lr_fraction: jnp.ndarray) -> tuple[TrainState, dict[str, Any]]:
        del lr_fraction
        tr, next_obs = collected.transitions, collected.next_obs
        critic_key = jax.random.wrap_key_data(collected.learn_key)
        values, advantages, returns = estimate_advantages(state.params, tr, next_obs, config)
        flat = lambda x: x.reshape((-1,) + x.shape[2:])  # noqa: E731
        mask = flat(tr.valid.astype(jnp.float32))
        advantages = flat(advantages)
        if config.ppo.norm_adv:
            advantages = normalize_advantages(advantages, mask)
        policy, critic = split_policy(state.params)
        policy, diagnostics = policy_step(policy, PolicyBatch(flat(tr.obs), flat(tr.action), advantages, mask), config)
        critic, critic_opt_state, value_loss = critic_regression(
            critic, state.critic_opt_state, flat(tr.obs), flat(returns), mask, critic_key, config
        )
        params = dict(policy, critic=critic)

        metrics = dict(diagnostics)
        metrics.update(
            value_loss=value_loss,
            explained_variance=explained_variance(flat(values[:-1]), flat(returns), mask),
            **rollout_report(tr, params),
        )
        steps = metrics["steps"]
        new_state = state._replace(
            params=params,
            critic_opt_state=critic_opt_state,
            iteration=state.iteration + 1,
            global_step=state.global_step + steps,
        )
        return new_state, metrics

    return make_rollout(config, spec.action_low, spec.action_high, env_step), learn


def make_iteration(
    config: Config, spec: EnvSpec, env_step: Any
) -> Callable[[TrainState, EnvCarry, jnp.ndarray], tuple[TrainState, EnvCarry, dict[str, Any]]]:
    """Return `iteration(state, carry, lr_fraction) -> (state, carry, metrics)`, ready for jax.jit: one rollout, GAE,
    policy step and critic regression (`make_parts`)."""
    return chain(*make_parts(config, spec, env_step))
