"""Collect a rollout inside `lax.scan` over the `VecEnv` protocol, with normalizers and episode statistics as
pure state.

A step whose env was done on the previous step is an autoreset step (invalid): its action was ignored, and it is
excluded from the observation and reward normalizers, the episode statistics, the step count and the loss.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from canter.config.schema import Config
from canter.core.counters import count_dtype
from canter.core.gae import compute_gae
from canter.core.networks import (
    Params,
    all_finite,
    gaussian_log_prob,
    policy_dist,
    sample_action,
    value,
)
from canter.core.normalize import RunningStats, learning_reward, normalize_obs, update_stats
from canter.envs.base import StepOutput
from canter.envs.episodes import EnvCarry, track_episodes


class Transition(NamedTuple):
    obs: jnp.ndarray
    action: jnp.ndarray
    log_prob: jnp.ndarray
    reward: jnp.ndarray  # scaled, for learning
    terminated: jnp.ndarray
    done: jnp.ndarray  # an episode ended at this step (terminated or truncated; never on reset steps)
    valid: jnp.ndarray
    episode_return: jnp.ndarray
    episode_length: jnp.ndarray
    episode_info: dict


def collect(
    params: Params,
    obs_stats: RunningStats,
    return_stats: RunningStats,
    carry: EnvCarry,
    key: jax.Array,
    env_step: Callable[[Any, jnp.ndarray], tuple[Any, StepOutput]],
    action_low: jnp.ndarray,
    action_high: jnp.ndarray,
    config: Config,
) -> tuple[RunningStats, RunningStats, EnvCarry, Transition, jnp.ndarray]:
    """Run `ppo.n_steps` steps. Returns (obs_stats, return_stats, carry, transitions [T, N], next_obs [N, D]),
    where next_obs is the normalized observation after the last step, for the bootstrap value. Values are computed
    afterwards in one batch: the critic is not needed to act, and every op inside the env loop costs time."""
    env_cfg = config.env

    def step(state, step_key):
        obs_stats, return_stats, carry = state
        valid = ~carry.prev_done
        if env_cfg.normalize_obs:
            obs_stats = update_stats(obs_stats, carry.obs, valid)
        obs = normalize_obs(config, obs_stats, carry.obs)
        mean, log_std = policy_dist(params, obs, config.net)
        action = sample_action(step_key, mean, log_std)
        log_prob = gaussian_log_prob(mean, log_std, action)

        env_state, out = env_step(carry.env_state, jnp.clip(action, action_low, action_high))
        carry, episodes = track_episodes(carry, env_state, out, config.ppo.gamma)
        if env_cfg.normalize_reward:
            return_stats = update_stats(return_stats, episodes.discounted_return, valid)
        learn_reward = learning_reward(out.reward, return_stats, env_cfg)
        transition = Transition(
            obs,
            action,
            log_prob,
            learn_reward,
            out.terminated & valid,
            episodes.done,
            valid,
            episodes.episode_return,
            episodes.episode_length,
            episodes.episode_info,
        )
        return (obs_stats, return_stats, carry), transition

    keys = jax.random.split(key, config.ppo.n_steps)
    (obs_stats, return_stats, carry), transitions = jax.lax.scan(step, (obs_stats, return_stats, carry), keys)
    next_obs = normalize_obs(config, obs_stats, carry.obs)
    return obs_stats, return_stats, carry, transitions, next_obs


class Collected(NamedTuple):
    """What one rollout hands to the update: the transitions [T, N], the normalized observation after the last step
    (for the bootstrap value), and the update's random key (key data)."""

    transitions: Transition
    next_obs: jnp.ndarray
    learn_key: jnp.ndarray


def make_rollout(
    config: Config, action_low: Any, action_high: Any, env_step: Callable[[Any, jnp.ndarray], tuple[Any, StepOutput]]
) -> Callable[[Any, EnvCarry], tuple[Any, EnvCarry, Collected]]:
    """`rollout(state, carry) -> (state, carry, collected)`, the first part of an on-policy iteration: the train
    state's normalizers and key move on, its parameters do not. `state` is any train state with `params`,
    `obs_stats`, `return_stats` and `key` (key data); the update's key is split off here, as the rollout's is."""
    low = jnp.asarray(action_low, jnp.float32)
    high = jnp.asarray(action_high, jnp.float32)

    def rollout(state: Any, carry: EnvCarry) -> tuple[Any, EnvCarry, Collected]:
        key, rollout_key, learn_key = jax.random.split(jax.random.wrap_key_data(state.key), 3)
        obs_stats, return_stats, carry, tr, next_obs = collect(
            state.params, state.obs_stats, state.return_stats, carry, rollout_key, env_step, low, high, config
        )
        state = state._replace(obs_stats=obs_stats, return_stats=return_stats, key=jax.random.key_data(key))
        return state, carry, Collected(tr, next_obs, jax.random.key_data(learn_key))

    return rollout


def chain(
    rollout: Callable[[Any, EnvCarry], tuple[Any, EnvCarry, Collected]],
    learn: Callable[[Any, Collected, jnp.ndarray], tuple[Any, dict[str, Any]]],
) -> Callable[[Any, EnvCarry, jnp.ndarray], tuple[Any, EnvCarry, dict[str, Any]]]:
    """The whole iteration, `iteration(state, carry, lr_fraction) -> (state, carry, metrics)`, from its two parts."""

    def iteration(state: Any, carry: EnvCarry, lr_fraction: jnp.ndarray) -> tuple[Any, EnvCarry, dict[str, Any]]:
        state, carry, collected = rollout(state, carry)
        state, metrics = learn(state, collected, lr_fraction)
        return state, carry, metrics

    return iteration


def estimate_advantages(
    params: Params, transitions: Any, next_obs: jnp.ndarray, config: Config
) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """The critic's values of a collected rollout, next_obs included ([T + 1, N]), and its GAE advantages and
    returns ([T, N])."""
    values = value(params, jnp.concatenate([transitions.obs, next_obs[None]], axis=0), config.net)
    advantages, returns = compute_gae(
        transitions.reward,
        values,
        transitions.terminated,
        transitions.done,
        transitions.valid,
        config.ppo.gamma,
        config.ppo.gae_lambda,
    )
    return values, advantages, returns


def rollout_report(tr: Transition, params: Params) -> dict[str, Any]:
    """What every on-policy iteration reports of its rollout: the env steps it took (autoreset steps excluded),
    whether the rollout and the updated parameters are all finite, and the episodes that finished in it."""
    return dict(
        steps=tr.valid.sum().astype(count_dtype()),
        finite=all_finite((tr.obs, tr.reward, params)),
        finished=tr.done,
        episode_return=tr.episode_return,
        episode_length=tr.episode_length,
        episode_info=tr.episode_info,
    )


def explained_variance(predicted: jnp.ndarray, target: jnp.ndarray, mask: jnp.ndarray) -> jnp.ndarray:
    """1 - Var(target - predicted) / Var(target) over the entries where `mask` is 1 (the valid steps); NaN when the
    target does not vary."""
    count = jnp.maximum(mask.sum(), 1.0)

    def var(x):
        mean = (x * mask).sum() / count
        return (jnp.square(x - mean) * mask).sum() / count

    target_var = var(target)
    return jnp.where(target_var > 0, 1.0 - var(target - predicted) / target_var, jnp.nan)
