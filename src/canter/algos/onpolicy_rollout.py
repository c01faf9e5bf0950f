"""Collect a rollout inside `lax.scan` over the `VecEnv` protocol, with normalizers and episode statistics as
pure state.

A step whose env was done on the previous step is an autoreset step (invalid): its action was ignored, and it is
excluded from the observation and reward normalizers, the episode statistics, the step count and the loss.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from canter.config.schema import Config
from canter.envs.base import StepOutput, is_summed_info
from canter.core.gae import compute_gae
from canter.core.networks import Params, gaussian_log_prob, policy_dist, sample_action, value
from canter.core.normalize import RunningStats, normalize, scale_reward, update_stats


class EnvCarry(NamedTuple):
    """What the env loop carries between steps and iterations. It is not checkpointed: a resumed run restarts
    its episodes."""
    env_state: Any
    obs: jnp.ndarray                 # [N, D] raw float32 observation to act on next
    prev_done: jnp.ndarray           # [N] the previous step ended an episode, so the next step is an autoreset
    discounted_return: jnp.ndarray   # [N] for reward scaling
    episode_return: jnp.ndarray      # [N] raw
    episode_length: jnp.ndarray      # [N] int32
    info_sums: dict                  # key -> [N]


class Transition(NamedTuple):
    obs: jnp.ndarray
    action: jnp.ndarray
    log_prob: jnp.ndarray
    reward: jnp.ndarray        # scaled, for learning
    terminated: jnp.ndarray
    done: jnp.ndarray          # an episode ended at this step (terminated or truncated; never on reset steps)
    valid: jnp.ndarray
    episode_return: jnp.ndarray
    episode_length: jnp.ndarray
    episode_info: dict


def init_env_carry(env_state: Any, first_obs: jnp.ndarray, info_keys: tuple[str, ...]) -> EnvCarry:
    n = first_obs.shape[0]
    zeros = jnp.zeros((n,), jnp.float32)
    return EnvCarry(env_state, jnp.asarray(first_obs, jnp.float32), jnp.zeros((n,), bool), zeros, zeros,
                    jnp.zeros((n,), jnp.int32), {k: zeros for k in info_keys})


def normalize_obs(config: Config, stats: RunningStats, obs: jnp.ndarray) -> jnp.ndarray:
    return normalize(stats, obs, config.env.clip_obs) if config.env.normalize_obs else obs


def collect(params: Params, obs_stats: RunningStats, return_stats: RunningStats, carry: EnvCarry, key: jax.Array,
            env_step: Callable[[Any, jnp.ndarray], tuple[Any, StepOutput]], action_low: jnp.ndarray,
            action_high: jnp.ndarray, config: Config):
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
        valid_f = valid.astype(jnp.float32)
        done = (out.terminated | out.truncated) & valid
        reward = out.reward
        discounted = carry.discounted_return * config.ppo.gamma * valid_f + reward * valid_f
        if env_cfg.normalize_reward:
            return_stats = update_stats(return_stats, discounted, valid)
            learn_reward = scale_reward(return_stats, reward, env_cfg.clip_reward)
        else:
            learn_reward = reward
        episode_return = carry.episode_return + reward * valid_f
        episode_length = carry.episode_length + valid.astype(jnp.int32)
        info_sums = {k: carry.info_sums[k] + out.info[k] * valid_f for k in carry.info_sums}
        length_f = jnp.maximum(episode_length.astype(jnp.float32), 1.0)
        episode_info = {k: v if is_summed_info(k) else v / length_f for k, v in info_sums.items()}

        transition = Transition(obs, action, log_prob, learn_reward, out.terminated & valid, done, valid,
                                episode_return, episode_length, episode_info)
        keep = 1.0 - done.astype(jnp.float32)
        carry = EnvCarry(env_state, out.obs, done, discounted * keep, episode_return * keep,
                         episode_length * (1 - done.astype(jnp.int32)), {k: v * keep for k, v in info_sums.items()})
        return (obs_stats, return_stats, carry), transition

    keys = jax.random.split(key, config.ppo.n_steps)
    (obs_stats, return_stats, carry), transitions = jax.lax.scan(step, (obs_stats, return_stats, carry), keys)
    next_obs = normalize_obs(config, obs_stats, carry.obs)
    return obs_stats, return_stats, carry, transitions, next_obs


def estimate_advantages(params: Params, transitions: Any, next_obs: jnp.ndarray, config: Config):
    """The critic's values of a collected rollout, next_obs included ([T + 1, N]), and its GAE advantages and
    returns ([T, N])."""
    values = value(params, jnp.concatenate([transitions.obs, next_obs[None]], axis=0), config.net)
    advantages, returns = compute_gae(transitions.reward, values, transitions.terminated, transitions.done,
                                      transitions.valid, config.ppo.gamma, config.ppo.gae_lambda)
    return values, advantages, returns
