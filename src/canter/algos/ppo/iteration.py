"""The jitted unit of PPO training: one iteration = rollout, GAE, update. The host loop calls it repeatedly and
logs, checkpoints and handles signals between calls."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from canter.algos.onpolicy_rollout import (
    Collected,
    chain,
    estimate_advantages,
    explained_variance,
    make_rollout,
    rollout_report,
)
from canter.algos.ppo.learner import adapt_kl_beta, make_optimizer, ppo_update
from canter.algos.ppo.losses import Minibatch, loss_variant
from canter.config.schema import Config
from canter.core.counters import count_dtype
from canter.core.networks import Params, init_params
from canter.core.normalize import RunningStats, init_stats
from canter.envs.base import EnvSpec
from canter.envs.episodes import EnvCarry


class TrainState(NamedTuple):
    """Everything a checkpoint must hold to continue learning exactly."""

    params: Params
    opt_state: Any
    obs_stats: RunningStats
    return_stats: RunningStats
    key: jax.Array
    iteration: jnp.ndarray
    global_step: jnp.ndarray
    kl_beta: Any = None  # the adaptive KL penalty weight; None (no leaf) unless ppo.objective = kl_penalty


def init_train_state(config: Config, obs_dim: int, act_dim: int, seed: Any) -> TrainState:
    """The state of run seed `seed` (a Python int or a uint32 scalar, traced or not: the same state either way)."""
    key, init_key = jax.random.split(jax.random.key(seed))
    params = init_params(init_key, config.net, obs_dim, act_dim)
    return TrainState(
        params=params,
        opt_state=make_optimizer(config).init(params),
        obs_stats=init_stats((obs_dim,)),
        return_stats=init_stats(()),
        key=jax.random.key_data(key),
        iteration=jnp.zeros((), jnp.int32),
        global_step=jnp.zeros((), count_dtype()),
        kl_beta=(
            jnp.asarray(config.ppo.kl_penalty_beta, jnp.float32) if config.ppo.objective == "kl_penalty" else None
        ),
    )


def make_parts(config: Config, spec: EnvSpec, env_step: Any, rpo: bool = False) -> tuple[Callable, Callable]:
    """The iteration's two parts, `rollout(state, carry) -> (state, carry, collected)` (canter.algos.onpolicy_rollout)
    and `learn(state, collected, lr_fraction) -> (state, metrics)`: GAE and the update, which never step the env.
    `rpo` turns the loss into RPO's (the rollout is the same: actions are sampled from the unshifted policy)."""
    variant = loss_variant(config, rpo)

    def learn(state: TrainState, collected: Collected, lr_fraction: jnp.ndarray) -> tuple[TrainState, dict[str, Any]]:
        tr, next_obs = collected.transitions, collected.next_obs
        values, advantages, returns = estimate_advantages(state.params, tr, next_obs, config)
        mask = tr.valid.astype(jnp.float32)
        flat = lambda x: x.reshape((-1,) + x.shape[2:])  # noqa: E731
        batch = Minibatch(
            flat(tr.obs),
            flat(tr.action),
            flat(tr.log_prob),
            flat(values[:-1]),
            flat(advantages),
            flat(returns),
            flat(mask),
        )
        critic_lr = config.ppo.critic_lr if config.ppo.critic_lr is not None else config.ppo.lr
        fraction = lr_fraction if config.ppo.anneal_lr else jnp.float32(1.0)
        actor_lr, critic_lr = config.ppo.lr * fraction, critic_lr * fraction
        kl_beta = state.kl_beta if variant.kl_penalty else jnp.float32(0.0)
        update_key = jax.random.wrap_key_data(collected.learn_key)
        params, opt_state, diagnostics = ppo_update(
            state.params, state.opt_state, batch, update_key, actor_lr, critic_lr, config, variant, kl_beta
        )
        new_beta = (
            adapt_kl_beta(kl_beta, diagnostics["policy_kl"], config.ppo.kl_penalty_target)
            if variant.kl_penalty
            else None
        )
        metrics = dict(diagnostics)
        metrics.setdefault("sym_loss", jnp.float32(0.0))
        metrics.update(
            kl_beta=kl_beta if variant.kl_penalty else jnp.float32(jnp.nan),
            explained_variance=explained_variance(batch.values, batch.returns, batch.mask),
            learning_rate=jnp.asarray(actor_lr, jnp.float32),
            **rollout_report(tr, params),
        )
        steps = metrics["steps"]
        new_state = state._replace(
            params=params,
            opt_state=opt_state,
            iteration=state.iteration + 1,
            global_step=state.global_step + steps,
            kl_beta=new_beta,
        )
        return new_state, metrics

    return make_rollout(config, spec.action_low, spec.action_high, env_step), learn


def make_iteration(
    config: Config, spec: EnvSpec, env_step: Any, rpo: bool = False
) -> Callable[[TrainState, EnvCarry, jnp.ndarray], tuple[TrainState, EnvCarry, dict[str, Any]]]:
    """Return `iteration(state, carry, lr_fraction) -> (state, carry, metrics)`, ready for jax.jit: one rollout, GAE
    and update (`make_parts`)."""
    return chain(*make_parts(config, spec, env_step, rpo))
