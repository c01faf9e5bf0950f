"""Proximal Policy Optimization: pure loss, pure update, and the jitted iteration."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

from canter.algos import Algorithm, ExportedActor
from canter.algos.protocol import export_mlp_actor
from canter.config.schema import Config
from canter.envs.base import EnvSpec

PPO_METRICS = (
    "policy_loss",
    "value_loss",
    "entropy",
    "approx_kl",
    "clip_frac",
    "grad_norm",
    "grad_norm_max",
    "explained_variance",
    "learning_rate",
    "epochs_run",
    "policy_kl",
    "kl_beta",
    "sym_loss",
)


# The actor's and the critic's layers, and Adam's two moments of each.
GAUSSIAN_SIZE_KEYS = (("params", "net.hidden"), ("opt_state", "net.hidden"))


def _init_state(config: Config, spec: Any, seed: Any) -> Any:
    from canter.algos.ppo.iteration import init_train_state

    return init_train_state(config, spec.obs_dim, spec.act_dim, seed)


def _make_iteration(config: Config, spec: Any, env_step: Any) -> Callable[..., Any]:
    from canter.algos.ppo.iteration import make_iteration

    return make_iteration(config, spec, env_step)


def _make_rpo_iteration(config: Config, spec: Any, env_step: Any) -> Callable[..., Any]:
    from canter.algos.ppo.iteration import make_iteration

    return make_iteration(config, spec, env_step, rpo=True)


def _make_parts(config: Config, spec: Any, env_step: Any) -> tuple[Callable[..., Any], Callable[..., Any]]:
    from canter.algos.ppo.iteration import make_parts

    return make_parts(config, spec, env_step)


def _make_rpo_parts(config: Config, spec: Any, env_step: Any) -> tuple[Callable[..., Any], Callable[..., Any]]:
    from canter.algos.ppo.iteration import make_parts

    return make_parts(config, spec, env_step, rpo=True)


def make_gaussian_act(config: Config, spec: Any) -> Callable[..., Any]:
    """`act(params, obs_stats, raw_obs, key, deterministic)` for the diagonal Gaussian actor of ppo and its kin."""
    import jax.numpy as jnp

    from canter.core.networks import policy_dist, sample_action
    from canter.core.normalize import normalize_obs

    low = jnp.asarray(spec.action_low, jnp.float32)
    high = jnp.asarray(spec.action_high, jnp.float32)

    def act(params: Any, obs_stats: Any, obs: Any, key: Any, deterministic: bool) -> Any:
        mean, log_std = policy_dist(params, normalize_obs(config, obs_stats, obs), config.net)
        action = mean if deterministic else sample_action(key, mean, log_std)
        return jnp.clip(action, low, high)

    return act


def gaussian_policy_params(state: Any) -> Any:
    return state.params


def export_gaussian_actor(config: Config, state: Any, spec: Any) -> ExportedActor:
    import jax

    actor, stats = jax.device_get((state.params["actor"], state.obs_stats))
    return export_mlp_actor(config, actor, stats, spec, config.net.activation, squash=False)


def validate_continuous(config: Config, spec: EnvSpec) -> None:
    """Checks against the env: symmetric-loss groups inside the action range. (Box actions are checked when the
    env is built; the trainer names the algorithm in that error.)"""
    from canter.algos.ppo.symmetry import check_action_range, parse_groups

    if config.sym.coef > 0:
        check_action_range(parse_groups(config.sym.groups, config.sym.negate), spec.act_dim, config.run.algo)


_PPO = Algorithm(
    name="ppo",
    init_state=_init_state,
    make_iteration=_make_iteration,
    make_parts=_make_parts,
    metric_names=PPO_METRICS,
    make_act=make_gaussian_act,
    policy_params=gaussian_policy_params,
    export_actor=export_gaussian_actor,
    validate=validate_continuous,
    size_keys=GAUSSIAN_SIZE_KEYS,
)
# rpo is ppo whose loss shifts the policy mean by U(-rpo.alpha, rpo.alpha): only its iteration differs.
ALGORITHMS = {
    "ppo": _PPO,
    "rpo": replace(_PPO, name="rpo", make_iteration=_make_rpo_iteration, make_parts=_make_rpo_parts),
}
