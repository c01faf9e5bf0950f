"""sac (Haarnoja et al. 2018): a tanh-squashed Gaussian actor, twin critics against a soft target with no target
actor, and an entropy temperature alpha tuned towards a target entropy.

The delayed actor and temperature step sits under `lax.cond`, so a skipped step costs nothing rather than being
computed and thrown away.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import numpy as np

from canter.algos.offpolicy.learner import UPDATE_METRICS
from canter.algos.offpolicy.record import offpolicy_algorithm
from canter.algos.offpolicy.sections import SACConfig
from canter.config.schema import Config


class SACLearner(NamedTuple):
    actor: Any  # outputs the mean and the raw log std of the pre-tanh Gaussian
    critics: Any  # stacked: leading axis = number of critics
    target_critics: Any
    actor_opt: Any
    critic_opt: Any
    log_alpha: Any  # float32 log of the entropy temperature
    alpha_opt: Any
    updates: Any  # int32 gradient steps taken, for policy_delay


def entropy_target(cfg: SACConfig, act_dim: int) -> float:
    """`sac.target_entropy`, or -act_dim where it is none."""
    return float(-act_dim) if cfg.target_entropy is None else float(cfg.target_entropy)


def log_scale(cfg: SACConfig, action_low: Sequence[float], action_high: Sequence[float]) -> float:
    """What turns a log-probability of the [-1, 1] box into one of `sac.entropy_box`: sum(log half-range) for the
    env's own bounds (log pi_env = log pi_unit - sum(log half)), 0 for the unit box."""
    if cfg.entropy_box == "unit":
        return 0.0
    half = (np.asarray(action_high, np.float64) - np.asarray(action_low, np.float64)) / 2
    return float(np.sum(np.log(half)))


@dataclass(frozen=True)
class SAC:
    """The sac learner of the shared off-policy loop (`OffPolicyLearner`)."""

    cfg: SACConfig
    target_entropy: float
    # sum(log half-range) of the env's bounds with sac.entropy_box env, else 0: log-probabilities, and so the soft
    # target, the temperature loss and the logged entropy, are then of the env's action coordinates, as CleanRL's.
    log_scale: float = 0.0
    update_metrics: ClassVar[tuple[str, ...]] = UPDATE_METRICS + ("alpha", "entropy")

    def init(self, key: Any, obs_dim: int, act_dim: int) -> SACLearner:
        import jax
        import jax.numpy as jnp

        from canter.algos.offpolicy.networks import init_actor, init_adam, init_critics

        cfg = self.cfg
        actor_key, critic_key = jax.random.split(key)
        actor = init_actor(actor_key, obs_dim, 2 * act_dim, cfg.hidden)
        critics = init_critics(critic_key, obs_dim, act_dim, cfg.hidden, 2)
        log_alpha = jnp.log(jnp.asarray(cfg.alpha, jnp.float32))
        # The target starts as a copy: distinct buffers, since the train state is donated to jit leaf by leaf.
        target_critics = jax.tree_util.tree_map(jnp.array, critics)
        return SACLearner(
            actor=actor,
            critics=critics,
            target_critics=target_critics,
            actor_opt=init_adam(actor, cfg.actor_lr),
            critic_opt=init_adam(critics, cfg.critic_lr),
            log_alpha=log_alpha,
            alpha_opt=init_adam(log_alpha, cfg.alpha_lr),
            updates=jnp.zeros((), jnp.int32),
        )

    def update(self, learner: SACLearner, batch: Any, key: Any) -> tuple[SACLearner, dict]:
        """A critic step against the soft target, a Polyak update of the target critics, and every `policy_delay`
        steps an actor step and (with autotune) a temperature step."""
        import jax
        import jax.numpy as jnp

        from canter.algos.offpolicy import losses
        from canter.algos.offpolicy.networks import (
            adam_step,
            q_values,
            squashed_gaussian,
        )

        cfg = self.cfg
        act = cfg.activation
        next_key, actor_key = jax.random.split(key)
        alpha = jnp.exp(learner.log_alpha)
        mean, log_std = squashed_gaussian(learner.actor, batch.next_obs, act)
        next_action, next_log_prob = losses.squashed_sample(
            mean, log_std, jax.random.normal(next_key, mean.shape, jnp.float32)
        )
        next_log_prob = next_log_prob - self.log_scale
        next_q = q_values(learner.target_critics, batch.next_obs, next_action, act)
        target = jax.lax.stop_gradient(
            losses.td_target(batch.reward, batch.terminated, next_q, cfg.gamma, -alpha * next_log_prob)
        )

        critics, critic_opt, critic_loss, q = losses.critic_step(
            learner.critics, learner.critic_opt, batch, target, act, cfg.critic_lr
        )
        target_critics = losses.polyak(learner.target_critics, critics, cfg.tau)

        def actor_objective(actor):
            mean, log_std = squashed_gaussian(actor, batch.obs, act)
            action, log_prob = losses.squashed_sample(
                mean, log_std, jax.random.normal(actor_key, mean.shape, jnp.float32)
            )
            q_pi = q_values(critics, batch.obs, action, act)
            log_prob = log_prob - self.log_scale
            return losses.sac_actor_loss(q_pi, log_prob, alpha), log_prob

        def update_actor(operand):
            actor, actor_opt, log_alpha, alpha_opt = operand
            (actor_loss, log_prob), grads = jax.value_and_grad(actor_objective, has_aux=True)(actor)
            actor, actor_opt = adam_step(actor, actor_opt, grads, cfg.actor_lr)
            if cfg.autotune:
                alpha_grad = jax.grad(losses.temperature_loss)(log_alpha, log_prob, self.target_entropy)
                log_alpha, alpha_opt = adam_step(log_alpha, alpha_opt, alpha_grad, cfg.alpha_lr)
            return actor, actor_opt, log_alpha, alpha_opt, actor_loss, -jnp.mean(log_prob)

        def skip(operand):
            return (*operand, jnp.float32(jnp.nan), jnp.float32(jnp.nan))

        operand = (learner.actor, learner.actor_opt, learner.log_alpha, learner.alpha_opt)
        actor, actor_opt, log_alpha, alpha_opt, actor_loss, entropy = jax.lax.cond(
            learner.updates % cfg.policy_delay == 0, update_actor, skip, operand
        )
        new = SACLearner(
            actor=actor,
            critics=critics,
            target_critics=target_critics,
            actor_opt=actor_opt,
            critic_opt=critic_opt,
            log_alpha=log_alpha,
            alpha_opt=alpha_opt,
            updates=learner.updates + 1,
        )
        return new, {
            "critic_loss": critic_loss,
            "actor_loss": actor_loss,
            "q_mean": jnp.mean(q),
            "alpha": jnp.exp(log_alpha),
            "entropy": entropy,
        }

    def explore(self, learner: SACLearner, obs: Any, ou_state: Any, key: Any) -> tuple[Any, Any]:
        """sac explores by sampling its policy; it has no OU noise, whose state passes through unchanged."""
        return self.act(learner.actor, obs, key, deterministic=False), ou_state

    def act(self, actor: Any, obs: Any, key: Any, deterministic: bool) -> Any:
        """tanh of the Gaussian's mean, or of a sample from it when not deterministic."""
        import jax
        import jax.numpy as jnp

        from canter.algos.offpolicy import losses
        from canter.algos.offpolicy.networks import squashed_gaussian

        mean, log_std = squashed_gaussian(actor, obs, self.cfg.activation)
        if deterministic:
            return jnp.tanh(mean)
        action, _ = losses.squashed_sample(mean, log_std, jax.random.normal(key, mean.shape, jnp.float32))
        return action


def _learner(config: Config, spec: Any) -> SAC:
    return SAC(
        config.sac,
        entropy_target(config.sac, spec.act_dim),
        log_scale(config.sac, spec.action_low, spec.action_high),
    )


ALGORITHM = offpolicy_algorithm("sac", _learner, SAC.update_metrics)
