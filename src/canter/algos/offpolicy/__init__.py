"""Off-policy algorithms: td3, ddpg and sac, sharing one replay buffer (canter.core.replay) and one jitted iteration.

Modules: networks.py (actors, stacked critics), losses.py (pure targets and losses), noise.py (exploration),
learners.py (one gradient step per algorithm), iteration.py (the env loop with storage and updates).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from canter.algos import Algorithm, ExportedActor
from canter.config.schema import Config

# Diagnostics of the updates, averaged over the gradient steps of one call (actor terms over the actor steps).
UPDATE_METRICS = ("critic_loss", "actor_loss", "q_mean")
SAC_METRICS = ("alpha", "entropy")


def metric_names(algo: str) -> tuple[str, ...]:
    return UPDATE_METRICS + (SAC_METRICS if algo == "sac" else ()) + ("gradient_steps", "buffer_size",
                                                                       "learning_rate")


def _init_state(config: Config, spec: Any):
    from canter.algos.offpolicy.iteration import init_train_state

    return init_train_state(config, spec.obs_dim, spec.act_dim)


def _make_iteration(config: Config, spec: Any, env_step: Any):
    from canter.algos.offpolicy.iteration import make_iteration

    return make_iteration(config, spec, env_step)


def _make_act(config: Config, spec: Any):
    """`act(actor, obs_stats, raw_obs, key, deterministic)`: td3/ddpg give the actor's output (plus Gaussian noise
    of `noise_std` when not deterministic); sac gives tanh(mean), or a sample when not deterministic."""
    import jax
    import jax.numpy as jnp

    from canter.algos.offpolicy.networks import deterministic_action, squashed_gaussian
    from canter.algos.onpolicy_rollout import normalize_obs

    cfg = getattr(config, config.run.algo)
    low = jnp.asarray(spec.action_low, jnp.float32)
    high = jnp.asarray(spec.action_high, jnp.float32)
    center, half = (high + low) / 2.0, (high - low) / 2.0

    def act(actor, obs_stats, obs, key, deterministic: bool):
        x = normalize_obs(config, obs_stats, obs)
        if config.run.algo == "sac":
            mean, log_std = squashed_gaussian(actor, x, cfg.activation)
            pre_tanh = mean if deterministic else (
                mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape, jnp.float32))
            action = jnp.tanh(pre_tanh)
        else:
            action = deterministic_action(actor, x, cfg.activation)
            if not deterministic:
                action = jnp.clip(action + cfg.noise_std * jax.random.normal(key, action.shape, jnp.float32),
                                  -1.0, 1.0)
        return jnp.clip(center + half * action, low, high)

    return act


def _policy_params(state: Any) -> Any:
    return state.learner.actor


def _export_actor(config: Config, state: Any, spec: Any) -> ExportedActor:
    import jax

    from canter.core.normalize import EPSILON

    actor = jax.device_get(state.learner.actor)
    stats = jax.device_get(state.obs_stats)
    return ExportedActor(
        weights=[np.asarray(layer["w"], np.float32) for layer in actor],
        biases=[np.asarray(layer["b"], np.float32) for layer in actor],
        activation=getattr(config, config.run.algo).activation, squash=True, normalize=config.env.normalize_obs,
        obs_mean=np.asarray(stats.mean, np.float32), obs_var=np.asarray(stats.var, np.float32), obs_eps=EPSILON,
        clip_obs=config.env.clip_obs, action_low=np.asarray(spec.action_low, np.float32),
        action_high=np.asarray(spec.action_high, np.float32), output_slice=spec.act_dim)


def _validate(config: Config, spec: Any) -> None:
    """Bounded actions are required: the actors map tanh outputs onto [low, high]."""
    if spec is None:
        return
    low, high = np.asarray(spec.action_low), np.asarray(spec.action_high)
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(high > low)):
        from canter.errors import CanterError

        raise CanterError(f"{config.run.algo} needs finite action bounds (it squashes actions with tanh); "
                          f"{getattr(spec, 'id', getattr(spec, 'env_id', 'this env'))} has low={low.tolist()} "
                          f"high={high.tolist()}")


def _record(name: str) -> Algorithm:
    return Algorithm(name=name, on_policy=False, init_state=_init_state, make_iteration=_make_iteration,
                     metric_names=metric_names(name), make_act=_make_act, policy_params=_policy_params,
                     export_actor=_export_actor, validate=_validate, donate_state=True)


ALGORITHMS = {name: _record(name) for name in ("td3", "ddpg", "sac")}
