"""The jitted unit of off-policy training, shared by td3, ddpg and sac, which plug in as an `OffPolicyLearner`
(canter.algos.offpolicy.learner).

One call runs `steps_per_call / num_envs` vector-env steps in `lax.scan`. Each step acts (uniformly random actions
until `learning_starts` env steps have been taken, then the exploring policy), steps the envs, stores the valid
transitions in the replay buffer, and every `train_freq` steps runs `gradient_steps` updates on uniform samples.
The host loop is therefore called rarely, and the replay buffer, donated to jit with the rest of the train state,
is updated in place.

Stored transitions hold raw observations and rewards; observation normalization and reward scaling, when enabled,
are applied to each sampled batch with the current statistics. EnvPool's autoreset steps are never stored, the
done step stores its true final observation, and only `terminated` stops bootstrapping.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from canter.algos.offpolicy.learner import OffPolicyLearner
from canter.algos.offpolicy.sections import vector_steps
from canter.config.schema import Config
from canter.core.counters import count_dtype
from canter.core.networks import all_finite
from canter.core.normalize import (
    RunningStats,
    init_stats,
    learning_reward,
    normalize_obs,
    update_stats,
)
from canter.core.replay import ReplayBuffer, Transitions, init_buffer, insert, sample
from canter.envs.base import StepOutput
from canter.envs.episodes import EnvCarry, track_episodes


class OffPolicyState(NamedTuple):
    """Everything a checkpoint must hold to continue learning exactly, the replay buffer included."""

    learner: Any  # the algorithm's learner state
    buffer: ReplayBuffer
    ou_state: jnp.ndarray  # [num_envs, act_dim] Ornstein-Uhlenbeck noise (zeros unless noise = ou)
    obs_stats: RunningStats
    return_stats: RunningStats
    key: jax.Array
    iteration: jnp.ndarray
    global_step: jnp.ndarray
    vector_steps: jnp.ndarray  # vector-env steps taken, for train_freq


class EnvLoop(NamedTuple):
    """What the scan over one call's env steps carries from each step to the next."""

    learner_state: Any
    buffer: ReplayBuffer
    ou_state: jnp.ndarray
    obs_stats: RunningStats
    return_stats: RunningStats
    carry: EnvCarry
    global_step: jnp.ndarray
    vector_steps: jnp.ndarray
    healthy: jnp.ndarray  # False once anything non-finite has appeared in this call
    sums: dict[str, jnp.ndarray]  # the update metrics summed over the call's gradient steps
    counts: dict[str, jnp.ndarray]


def vector_steps_per_call(config: Config, learner: OffPolicyLearner) -> int:
    return vector_steps(learner.cfg.steps_per_call, config.env.num_envs)


def init_train_state(config: Config, learner: OffPolicyLearner, obs_dim: int, act_dim: int) -> OffPolicyState:
    key, init_key = jax.random.split(jax.random.key(config.run.seed))
    return OffPolicyState(
        learner=learner.init(init_key, obs_dim, act_dim),
        buffer=init_buffer(learner.cfg.buffer_size, obs_dim, act_dim),
        ou_state=jnp.zeros((config.env.num_envs, act_dim), jnp.float32),
        obs_stats=init_stats((obs_dim,)),
        return_stats=init_stats(()),
        key=jax.random.key_data(key),
        iteration=jnp.zeros((), jnp.int32),
        global_step=jnp.zeros((), count_dtype()),
        vector_steps=jnp.zeros((), count_dtype()),
    )


def make_iteration(
    config: Config, learner: OffPolicyLearner, spec: Any, env_step: Callable[[Any, jnp.ndarray], tuple[Any, StepOutput]]
) -> Callable[[OffPolicyState, EnvCarry, jnp.ndarray], tuple[OffPolicyState, EnvCarry, dict[str, Any]]]:
    """Return `iteration(state, carry, lr_fraction) -> (state, carry, metrics)`; lr_fraction is unused (constant
    learning rates). Of `config`, only `env.*` is read: the algorithm's keys come from `learner.cfg`."""
    cfg = learner.cfg
    env_cfg = config.env
    low = jnp.asarray(spec.action_low, jnp.float32)
    high = jnp.asarray(spec.action_high, jnp.float32)
    center, half = (high + low) / 2.0, (high - low) / 2.0
    num_steps = vector_steps_per_call(config, learner)
    names = learner.update_metrics

    def prepare(batch: Transitions, obs_stats: RunningStats, return_stats: RunningStats) -> Transitions:
        return batch._replace(
            obs=normalize_obs(config, obs_stats, batch.obs),
            next_obs=normalize_obs(config, obs_stats, batch.next_obs),
            reward=learning_reward(batch.reward, return_stats, env_cfg),
        )

    def train(learner_state, buffer, obs_stats, return_stats, key):
        """`gradient_steps` updates; returns the learner state and per-metric (sums, counts) over them."""

        def one(learner_state, step_key):
            sample_key, update_key = jax.random.split(step_key)
            batch = prepare(sample(buffer, sample_key, cfg.batch_size), obs_stats, return_stats)
            return learner.update(learner_state, batch, update_key)

        if cfg.gradient_steps == 1:
            learner_state, diag = one(learner_state, key)
            diag = {k: v[None] for k, v in diag.items()}
        else:
            learner_state, diag = jax.lax.scan(one, learner_state, jax.random.split(key, cfg.gradient_steps))
        sums = {k: jnp.nansum(diag[k]) for k in names}
        counts = {k: jnp.sum(~jnp.isnan(diag[k])).astype(jnp.float32) for k in names}
        return learner_state, sums, counts

    def env_loop_step(loop: EnvLoop, step_key: jax.Array) -> tuple[EnvLoop, dict[str, Any]]:
        carry, obs_stats, global_step = loop.carry, loop.obs_stats, loop.global_step
        random_key, explore_key, train_key = jax.random.split(step_key, 3)
        valid = ~carry.prev_done
        if env_cfg.normalize_obs:
            obs_stats = update_stats(obs_stats, carry.obs, valid)
        policy_obs = normalize_obs(config, obs_stats, carry.obs)
        policy_action, next_ou = learner.explore(loop.learner_state, policy_obs, loop.ou_state, explore_key)
        random_action = jax.random.uniform(random_key, policy_action.shape, jnp.float32, -1.0, 1.0)
        action = jnp.where(global_step < cfg.learning_starts, random_action, policy_action)
        env_state, out = env_step(carry.env_state, center + half * action)
        next_carry, episodes = track_episodes(carry, env_state, out, cfg.gamma)

        # The action too: an env that ignores a NaN control (MuJoCo zeroes it) would return finite obs and rewards.
        step_finite = jnp.all(jnp.isfinite(out.obs)) & jnp.all(jnp.isfinite(out.reward)) & jnp.all(jnp.isfinite(action))
        healthy = loop.healthy & step_finite
        # Once anything non-finite appears, nothing more is stored or learned in this call.
        buffer = insert(
            loop.buffer,
            Transitions(carry.obs, action, out.reward, out.obs, out.terminated.astype(jnp.float32)),
            valid & healthy,
        )
        return_stats = loop.return_stats
        if env_cfg.normalize_reward:
            return_stats = update_stats(return_stats, episodes.discounted_return, valid)
        global_step = global_step + valid.sum().astype(count_dtype())
        # An autoreset step in which no env stored a transition is not a step of the algorithm: counting it would
        # make one more update per episode than the references (whose vector envs reset within the step) make.
        stored = valid.any()
        vector_steps = loop.vector_steps + stored.astype(loop.vector_steps.dtype)

        do_train = stored & healthy & (global_step >= cfg.learning_starts) & (vector_steps % cfg.train_freq == 0)

        def run(learner_state):
            return train(learner_state, buffer, obs_stats, return_stats, train_key)

        def skip(learner_state):
            zeros = {k: jnp.float32(0.0) for k in names}
            return learner_state, zeros, zeros

        learner_state, step_sums, step_counts = jax.lax.cond(do_train, run, skip, loop.learner_state)
        record = dict(
            done=episodes.done,
            valid=valid,
            episode_return=episodes.episode_return,
            episode_length=episodes.episode_length,
            episode_info=episodes.episode_info,
        )
        following = EnvLoop(
            learner_state=learner_state,
            buffer=buffer,
            # An autoreset step's action is ignored, so its noise does not advance: an episode's first action
            # then carries one OU increment from 0, as in the references.
            ou_state=jnp.where(valid[:, None], next_ou, loop.ou_state)
            * (1.0 - episodes.done.astype(jnp.float32))[:, None],
            obs_stats=obs_stats,
            return_stats=return_stats,
            carry=next_carry,
            global_step=global_step,
            vector_steps=vector_steps,
            healthy=healthy,
            sums={k: loop.sums[k] + step_sums[k] for k in names},
            counts={k: loop.counts[k] + step_counts[k] for k in names},
        )
        return following, record

    def iteration(
        state: OffPolicyState, carry: EnvCarry, lr_fraction: jnp.ndarray
    ) -> tuple[OffPolicyState, EnvCarry, dict[str, Any]]:
        key, loop_key = jax.random.split(jax.random.wrap_key_data(state.key))
        zeros = {k: jnp.float32(0.0) for k in names}
        start = EnvLoop(
            learner_state=state.learner,
            buffer=state.buffer,
            ou_state=state.ou_state,
            obs_stats=state.obs_stats,
            return_stats=state.return_stats,
            carry=carry,
            global_step=state.global_step,
            vector_steps=state.vector_steps,
            healthy=jnp.asarray(True),
            sums=zeros,
            counts=zeros,
        )
        final, records = jax.lax.scan(env_loop_step, start, jax.random.split(loop_key, num_steps))
        finite = final.healthy & all_finite(final.learner_state)
        new_state = OffPolicyState(
            final.learner_state,
            final.buffer,
            final.ou_state,
            final.obs_stats,
            final.return_stats,
            jax.random.key_data(key),
            state.iteration + 1,
            final.global_step,
            final.vector_steps,
        )
        # A non-finite call hands back the state it was given (its buffer keeps only the finite transitions it
        # stored), so the trainer can checkpoint the last good state although the input buffers were donated.
        small_new = {k: v for k, v in new_state._asdict().items() if k != "buffer"}
        small_old = {k: v for k, v in state._asdict().items() if k != "buffer"}
        kept = jax.tree_util.tree_map(lambda new, old: jnp.where(finite, new, old), small_new, small_old)
        new_state = OffPolicyState(buffer=final.buffer, **kept)
        steps = records["valid"].sum().astype(count_dtype())
        counts, sums = final.counts, final.sums
        metrics = {k: jnp.where(counts[k] > 0, sums[k] / jnp.maximum(counts[k], 1.0), jnp.nan) for k in names}
        metrics.update(
            gradient_steps=counts["critic_loss"],
            buffer_size=final.buffer.size.astype(jnp.float32),
            learning_rate=jnp.float32(cfg.actor_lr),
            steps=steps,
            finite=finite,
            finished=records["done"],
            episode_return=records["episode_return"],
            episode_length=records["episode_length"],
            episode_info=records["episode_info"],
        )
        return new_state, final.carry, metrics

    return iteration
