"""Episode bookkeeping of a vector env stepped inside `lax.scan`, as pure JAX functions shared by every env loop.

With EnvPool's episode semantics (canter.envs.base), the step after a done is an autoreset step: it is invalid,
counts toward nothing, and its reward and info are masked out of the running sums.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from canter.envs.base import StepOutput, is_summed_info


class EnvCarry(NamedTuple):
    """What the env loop carries between steps and iterations. A run on mjx or brax, whose envs are JAX arrays,
    checkpoints it, so that a resumed run continues its episodes in flight; one on envpool or gymnasium, whose envs
    live outside JAX, does not, so a resumed run restarts its episodes."""

    env_state: Any
    obs: jnp.ndarray  # [N, D] raw float32 observation to act on next
    prev_done: jnp.ndarray  # [N] the previous step ended an episode, so the next step is an autoreset
    discounted_return: jnp.ndarray  # [N] for reward scaling
    episode_return: jnp.ndarray  # [N] raw
    episode_length: jnp.ndarray  # [N] int32
    info_sums: dict  # key -> [N]


class EpisodeStep(NamedTuple):
    """What one vector-env step did to the episodes. The running values include this step; where `done`, they
    are the statistics of the episode that just finished."""

    valid: jnp.ndarray  # [N] not an autoreset step
    done: jnp.ndarray  # [N] an episode ended at this step (never on autoreset steps)
    discounted_return: jnp.ndarray  # [N] running discounted return, for the reward normalizer
    episode_return: jnp.ndarray  # [N] running raw return
    episode_length: jnp.ndarray  # [N] int32 running length in valid steps
    episode_info: dict  # key -> [N]: the sum for reward and cost terms, else the mean per step


def init_env_carry(env_state: Any, first_obs: np.ndarray | jnp.ndarray, info_keys: tuple[str, ...]) -> EnvCarry:
    n = first_obs.shape[0]
    zeros = jnp.zeros((n,), jnp.float32)
    return EnvCarry(
        env_state,
        jnp.asarray(first_obs, jnp.float32),
        jnp.zeros((n,), bool),
        zeros,
        zeros,
        jnp.zeros((n,), jnp.int32),
        dict.fromkeys(info_keys, zeros),
    )


def track_episodes(carry: EnvCarry, env_state: Any, out: StepOutput, gamma: float) -> tuple[EnvCarry, EpisodeStep]:
    """Account for the step `out` taken from `carry` (which led to `env_state`): the next carry, whose running
    sums restart where an episode ended, and this step's `EpisodeStep`."""
    valid = ~carry.prev_done
    valid_f = valid.astype(jnp.float32)
    done = (out.terminated | out.truncated) & valid
    discounted = carry.discounted_return * gamma * valid_f + out.reward * valid_f
    episode_return = carry.episode_return + out.reward * valid_f
    episode_length = carry.episode_length + valid.astype(jnp.int32)
    info_sums = {k: carry.info_sums[k] + out.info[k] * valid_f for k in carry.info_sums}
    length_f = jnp.maximum(episode_length.astype(jnp.float32), 1.0)
    episode_info = {k: v if is_summed_info(k) else v / length_f for k, v in info_sums.items()}
    keep = 1.0 - done.astype(jnp.float32)
    next_carry = EnvCarry(
        env_state,
        out.obs,
        done,
        discounted * keep,
        episode_return * keep,
        episode_length * (1 - done.astype(jnp.int32)),
        {k: v * keep for k, v in info_sums.items()},
    )
    return next_carry, EpisodeStep(valid, done, discounted, episode_return, episode_length, episode_info)
