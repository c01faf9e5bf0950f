"""One gradient step of td3/ddpg and of sac on a sampled batch, as pure functions of the learner state.

The delayed actor step (and, for td3/ddpg, the target update that goes with it) sits under `lax.cond`, so a
skipped step costs nothing rather than being computed and thrown away.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from canter.algos.offpolicy import losses
from canter.algos.offpolicy.networks import (deterministic_action, first_critic, init_actor, init_critics,
                                             q_values, squashed_gaussian)
from canter.config.schema import OffPolicyConfig, SACConfig, TD3Config
from canter.core.replay import Transitions


class Learner(NamedTuple):
    actor: Any
    critics: Any                 # stacked: leading axis = number of critics
    target_actor: Any            # None for sac, which has no target actor
    target_critics: Any
    actor_opt: Any
    critic_opt: Any
    log_alpha: Any               # sac only (None otherwise)
    alpha_opt: Any
    updates: jnp.ndarray         # gradient steps taken, for policy_delay


def _adam(lr: float) -> optax.GradientTransformation:
    return optax.adam(lr)


def init_learner(key: jax.Array, algo: str, cfg: OffPolicyConfig, obs_dim: int, act_dim: int) -> Learner:
    actor_key, critic_key = jax.random.split(key)
    sac = algo == "sac"
    actor = init_actor(actor_key, obs_dim, 2 * act_dim if sac else act_dim, cfg.hidden)
    critics = init_critics(critic_key, obs_dim, act_dim, cfg.hidden, 1 if algo == "ddpg" else 2)
    log_alpha = alpha_opt = None
    if sac:
        log_alpha = jnp.log(jnp.asarray(cfg.alpha, jnp.float32))
        alpha_opt = _adam(cfg.alpha_lr).init(log_alpha)
    # Targets start as copies: distinct buffers, since the train state is donated to jit leaf by leaf.
    copy = lambda tree: jax.tree_util.tree_map(jnp.array, tree)  # noqa: E731
    return Learner(actor=actor, critics=critics, target_actor=None if sac else copy(actor),
                   target_critics=copy(critics),
                   actor_opt=_adam(cfg.actor_lr).init(actor), critic_opt=_adam(cfg.critic_lr).init(critics),
                   log_alpha=log_alpha, alpha_opt=alpha_opt, updates=jnp.zeros((), jnp.int32))


def _step(params: Any, opt_state: Any, grads: Any, lr: float) -> tuple[Any, Any]:
    updates, opt_state = _adam(lr).update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state


def deterministic_update(learner: Learner, batch: Transitions, key: jax.Array, cfg: OffPolicyConfig,
                         smoothing: bool) -> tuple[Learner, dict]:
    """td3 (`smoothing`, twin critics) or ddpg (one critic): a critic step, then every `policy_delay` steps an
    actor step on the first critic and a Polyak update of all targets."""
    act = cfg.activation
    next_action = deterministic_action(learner.target_actor, batch.next_obs, act)
    if smoothing:
        assert isinstance(cfg, TD3Config)
        noise = jax.random.normal(key, next_action.shape, jnp.float32)
        next_action = losses.smoothed_target_action(next_action, noise, cfg.target_noise, cfg.noise_clip)
    next_q = q_values(learner.target_critics, batch.next_obs, next_action, act)
    target = jax.lax.stop_gradient(losses.td_target(batch.reward, batch.terminated, next_q, cfg.gamma))

    def critic_objective(critics):
        q = q_values(critics, batch.obs, batch.action, act)
        return losses.critic_loss(q, target), q

    (critic_loss, q), grads = jax.value_and_grad(critic_objective, has_aux=True)(learner.critics)
    critics, critic_opt = _step(learner.critics, learner.critic_opt, grads, cfg.critic_lr)

    def actor_objective(actor):
        return losses.deterministic_actor_loss(
            q_values(first_critic(critics), batch.obs, deterministic_action(actor, batch.obs, act), act))

    def update_actor(operand):
        actor, actor_opt, target_actor, target_critics = operand
        actor_loss, grads = jax.value_and_grad(actor_objective)(actor)
        actor, actor_opt = _step(actor, actor_opt, grads, cfg.actor_lr)
        return (actor, actor_opt, losses.polyak(target_actor, actor, cfg.tau),
                losses.polyak(target_critics, critics, cfg.tau), actor_loss)

    def skip(operand):
        return (*operand, jnp.float32(jnp.nan))

    operand = (learner.actor, learner.actor_opt, learner.target_actor, learner.target_critics)
    actor, actor_opt, target_actor, target_critics, actor_loss = jax.lax.cond(
        learner.updates % cfg.policy_delay == 0, update_actor, skip, operand)
    new = learner._replace(actor=actor, critics=critics, target_actor=target_actor, target_critics=target_critics,
                           actor_opt=actor_opt, critic_opt=critic_opt, updates=learner.updates + 1)
    return new, {"critic_loss": critic_loss, "actor_loss": actor_loss, "q_mean": jnp.mean(q)}


def sac_update(learner: Learner, batch: Transitions, key: jax.Array, cfg: SACConfig,
               target_entropy: float) -> tuple[Learner, dict]:
    """A critic step against the soft target, a Polyak update of the target critics, and every `policy_delay`
    steps an actor step and (with autotune) a temperature step."""
    act = cfg.activation
    next_key, actor_key = jax.random.split(key)
    alpha = jnp.exp(learner.log_alpha)
    mean, log_std = squashed_gaussian(learner.actor, batch.next_obs, act)
    next_action, next_log_prob = losses.squashed_sample(
        mean, log_std, jax.random.normal(next_key, mean.shape, jnp.float32))
    next_q = q_values(learner.target_critics, batch.next_obs, next_action, act)
    target = jax.lax.stop_gradient(
        losses.td_target(batch.reward, batch.terminated, next_q, cfg.gamma, -alpha * next_log_prob))

    def critic_objective(critics):
        q = q_values(critics, batch.obs, batch.action, act)
        return losses.critic_loss(q, target), q

    (critic_loss, q), grads = jax.value_and_grad(critic_objective, has_aux=True)(learner.critics)
    critics, critic_opt = _step(learner.critics, learner.critic_opt, grads, cfg.critic_lr)
    target_critics = losses.polyak(learner.target_critics, critics, cfg.tau)

    def actor_objective(actor):
        mean, log_std = squashed_gaussian(actor, batch.obs, act)
        action, log_prob = losses.squashed_sample(mean, log_std,
                                                  jax.random.normal(actor_key, mean.shape, jnp.float32))
        q_pi = q_values(critics, batch.obs, action, act)
        return losses.sac_actor_loss(q_pi, log_prob, alpha), log_prob

    def update_actor(operand):
        actor, actor_opt, log_alpha, alpha_opt = operand
        (actor_loss, log_prob), grads = jax.value_and_grad(actor_objective, has_aux=True)(actor)
        actor, actor_opt = _step(actor, actor_opt, grads, cfg.actor_lr)
        if cfg.autotune:
            alpha_grad = jax.grad(losses.temperature_loss)(log_alpha, log_prob, target_entropy)
            log_alpha, alpha_opt = _step(log_alpha, alpha_opt, alpha_grad, cfg.alpha_lr)
        return actor, actor_opt, log_alpha, alpha_opt, actor_loss, -jnp.mean(log_prob)

    def skip(operand):
        return (*operand, jnp.float32(jnp.nan), jnp.float32(jnp.nan))

    operand = (learner.actor, learner.actor_opt, learner.log_alpha, learner.alpha_opt)
    actor, actor_opt, log_alpha, alpha_opt, actor_loss, entropy = jax.lax.cond(
        learner.updates % cfg.policy_delay == 0, update_actor, skip, operand)
    new = learner._replace(actor=actor, critics=critics, target_critics=target_critics, actor_opt=actor_opt,
                           critic_opt=critic_opt, log_alpha=log_alpha, alpha_opt=alpha_opt,
                           updates=learner.updates + 1)
    return new, {"critic_loss": critic_loss, "actor_loss": actor_loss, "q_mean": jnp.mean(q),
                 "alpha": jnp.exp(log_alpha), "entropy": entropy}
