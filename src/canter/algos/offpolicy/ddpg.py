"""ddpg (Lillicrap et al. 2016): a deterministic tanh actor trained through one critic, with target networks and
exploration noise (gaussian, Ornstein-Uhlenbeck or none). td3 (canter.algos.offpolicy.td3) is this learner with
twin critics and target policy smoothing.

The delayed actor step and the target update that goes with it sit under `lax.cond`, so a skipped step costs
nothing rather than being computed and thrown away.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

from canter.algos.offpolicy.learner import UPDATE_METRICS
from canter.algos.offpolicy.record import offpolicy_algorithm
from canter.algos.offpolicy.sections import OffPolicyConfig
from canter.config.schema import Config


class DDPGLearner(NamedTuple):
    """The learner state of ddpg, and of td3."""

    actor: Any
    critics: Any  # stacked: leading axis = number of critics
    target_actor: Any
    target_critics: Any
    actor_opt: Any
    critic_opt: Any
    updates: Any  # int32 gradient steps taken, for policy_delay


@dataclass(frozen=True)
class DDPG:
    """The ddpg learner of the shared off-policy loop (`OffPolicyLearner`)."""

    cfg: OffPolicyConfig
    num_critics: ClassVar[int] = 1
    update_metrics: ClassVar[tuple[str, ...]] = UPDATE_METRICS

    def init(self, key: Any, obs_dim: int, act_dim: int) -> DDPGLearner:
        import jax
        import jax.numpy as jnp

        from canter.algos.offpolicy.networks import init_actor, init_adam, init_critics

        cfg = self.cfg
        actor_key, critic_key = jax.random.split(key)
        actor = init_actor(actor_key, obs_dim, act_dim, cfg.hidden)
        critics = init_critics(critic_key, obs_dim, act_dim, cfg.hidden, self.num_critics)
        # Targets start as copies: distinct buffers, since the train state is donated to jit leaf by leaf.
        copy = lambda tree: jax.tree_util.tree_map(jnp.array, tree)  # noqa: E731
        return DDPGLearner(
            actor=actor,
            critics=critics,
            target_actor=copy(actor),
            target_critics=copy(critics),
            actor_opt=init_adam(actor, cfg.actor_lr),
            critic_opt=init_adam(critics, cfg.critic_lr),
            updates=jnp.zeros((), jnp.int32),
        )

    def target_action(self, next_action: Any, key: Any) -> Any:
        """The action the critic target bootstraps with, given the target actor's."""
        return next_action

    def update(self, learner: DDPGLearner, batch: Any, key: Any) -> tuple[DDPGLearner, dict]:
        """A critic step, then every `policy_delay` steps an actor step on the first critic and a Polyak update of
        all targets."""
        import jax
        import jax.numpy as jnp

        from canter.algos.offpolicy import losses
        from canter.algos.offpolicy.networks import (
            adam_step,
            deterministic_action,
            first_critic,
            q_values,
        )

        cfg = self.cfg
        act = cfg.activation
        next_action = self.target_action(deterministic_action(learner.target_actor, batch.next_obs, act), key)
        next_q = q_values(learner.target_critics, batch.next_obs, next_action, act)
        target = jax.lax.stop_gradient(losses.td_target(batch.reward, batch.terminated, next_q, cfg.gamma))

        critics, critic_opt, critic_loss, q = losses.critic_step(
            learner.critics, learner.critic_opt, batch, target, act, cfg.critic_lr
        )

        def actor_objective(actor):
            return losses.deterministic_actor_loss(
                q_values(first_critic(critics), batch.obs, deterministic_action(actor, batch.obs, act), act)
            )

        def update_actor(operand):
            actor, actor_opt, target_actor, target_critics = operand
            actor_loss, grads = jax.value_and_grad(actor_objective)(actor)
            actor, actor_opt = adam_step(actor, actor_opt, grads, cfg.actor_lr)
            return (
                actor,
                actor_opt,
                losses.polyak(target_actor, actor, cfg.tau),
                losses.polyak(target_critics, critics, cfg.tau),
                actor_loss,
            )

        def skip(operand):
            return (*operand, jnp.float32(jnp.nan))

        operand = (learner.actor, learner.actor_opt, learner.target_actor, learner.target_critics)
        actor, actor_opt, target_actor, target_critics, actor_loss = jax.lax.cond(
            learner.updates % cfg.policy_delay == 0, update_actor, skip, operand
        )
        new = DDPGLearner(
            actor=actor,
            critics=critics,
            target_actor=target_actor,
            target_critics=target_critics,
            actor_opt=actor_opt,
            critic_opt=critic_opt,
            updates=learner.updates + 1,
        )
        return new, {"critic_loss": critic_loss, "actor_loss": actor_loss, "q_mean": jnp.mean(q)}

    def explore(self, learner: DDPGLearner, obs: Any, ou_state: Any, key: Any) -> tuple[Any, Any]:
        from canter.algos.offpolicy import noise
        from canter.algos.offpolicy.networks import deterministic_action

        cfg = self.cfg
        action = deterministic_action(learner.actor, obs, cfg.activation)
        return noise.explore(cfg.noise, action, ou_state, key, cfg.noise_std, cfg.ou_theta, cfg.ou_dt)

    def act(self, actor: Any, obs: Any, key: Any, deterministic: bool) -> Any:
        """The actor's output, plus Gaussian noise of `noise_std` when not deterministic."""
        import jax
        import jax.numpy as jnp

        from canter.algos.offpolicy.networks import deterministic_action

        action = deterministic_action(actor, obs, self.cfg.activation)
        if deterministic:
            return action
        return jnp.clip(action + self.cfg.noise_std * jax.random.normal(key, action.shape, jnp.float32), -1.0, 1.0)


def _learner(config: Config, spec: Any) -> DDPG:
    return DDPG(config.ddpg)


ALGORITHM = offpolicy_algorithm("ddpg", _learner, DDPG.update_metrics)
