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

`make_iteration` binds what a call never changes (a `LoopContext`) to `iteration`; the functions after it follow
in the order a call runs them, each taking what it reads as arguments.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from canter.algos.offpolicy.learner import OffPolicyLearner
from canter.algos.offpolicy.sections import OffPolicyConfig, vector_steps
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
from canter.envs.episodes import EnvCarry, EpisodeStep, track_episodes


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


def init_train_state(
    config: Config, learner: OffPolicyLearner, obs_dim: int, act_dim: int, seed: Any
) -> OffPolicyState:
    """The state of run seed `seed` (a Python int or a uint32 scalar, traced or not: the same state either way)."""
    key, init_key = jax.random.split(jax.random.key(seed))
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


@dataclass(frozen=True, eq=False)  # compared by identity: its fields include arrays and a function
class LoopContext:
    """What every step of the env loop reads and never changes, fixed when the iteration is built. The action box is
    kept as arrays computed once here, so that the compiled program holds them as constants."""

    config: Config  # of which the loop reads `env.*`: the algorithm's keys come from `learner.cfg`
    learner: OffPolicyLearner
    env_step: Callable[[Any, jnp.ndarray], tuple[Any, StepOutput]]
    center: jnp.ndarray  # [act_dim] the middle of the env's action box, where the learner's action 0 lands
    half: jnp.ndarray  # [act_dim] its half-range, where the learner's action 1 lands


def make_iteration(
    config: Config, learner: OffPolicyLearner, spec: Any, env_step: Callable[[Any, jnp.ndarray], tuple[Any, StepOutput]]
) -> Callable[[OffPolicyState, EnvCarry, jnp.ndarray], tuple[OffPolicyState, EnvCarry, dict[str, Any]]]:
    """Return `iteration(state, carry, lr_fraction) -> (state, carry, metrics)`; lr_fraction is unused (constant
    learning rates). Of `config`, only `env.*` is read: the algorithm's keys come from `learner.cfg`."""
    low = jnp.asarray(spec.action_low, jnp.float32)
    high = jnp.asarray(spec.action_high, jnp.float32)
    context = LoopContext(config, learner, env_step, center=(high + low) / 2.0, half=(high - low) / 2.0)
    return partial(iteration, context)


def iteration(
    context: LoopContext, state: OffPolicyState, carry: EnvCarry, lr_fraction: jnp.ndarray
) -> tuple[OffPolicyState, EnvCarry, dict[str, Any]]:
    """One jitted call: `vector_steps_per_call` env steps with their updates, scanned so that the host loop runs
    once per call rather than once per step."""
    names = context.learner.update_metrics
    key, loop_key = jax.random.split(jax.random.wrap_key_data(state.key))
    start = start_loop(state, carry, names)
    num_steps = vector_steps_per_call(context.config, context.learner)
    final, records = jax.lax.scan(partial(env_loop_step, context), start, jax.random.split(loop_key, num_steps))
    finite = final.healthy & all_finite(final.learner_state)
    new_state = keep_last_good(finite, end_state(state, final, key), state)
    return new_state, final.carry, call_metrics(context.learner.cfg, names, final, records, finite)


def zero_metrics(names: tuple[str, ...]) -> dict[str, jnp.ndarray]:
    """A zero for each update metric: the start of a call's sums and counts, and what a step without updates adds."""
    return {k: jnp.float32(0.0) for k in names}


def start_loop(state: OffPolicyState, carry: EnvCarry, names: tuple[str, ...]) -> EnvLoop:
    """The scan's first carry: the train state unpacked, healthy, with nothing summed yet."""
    zeros = zero_metrics(names)
    return EnvLoop(
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


def env_loop_step(context: LoopContext, loop: EnvLoop, step_key: jax.Array) -> tuple[EnvLoop, dict[str, Any]]:
    """One vector-env step of the scan: act, step the envs, store what is valid, and update when it is time.
    Returns the next carry and this step's episode record, which the scan stacks for the call's metrics."""
    cfg, names = context.learner.cfg, context.learner.update_metrics
    env_cfg = context.config.env
    carry, obs_stats = loop.carry, loop.obs_stats
    random_key, explore_key, train_key = jax.random.split(step_key, 3)
    valid = ~carry.prev_done
    if env_cfg.normalize_obs:
        obs_stats = update_stats(obs_stats, carry.obs, valid)
    action, next_ou = choose_action(context, loop, obs_stats, random_key, explore_key)
    env_state, out = context.env_step(carry.env_state, context.center + context.half * action)
    next_carry, episodes = track_episodes(carry, env_state, out, cfg.gamma)
    healthy = loop.healthy & step_is_finite(out, action)
    buffer = store_transitions(loop.buffer, carry.obs, action, out, valid, healthy)
    return_stats = loop.return_stats
    if env_cfg.normalize_reward:
        return_stats = update_stats(return_stats, episodes.discounted_return, valid)
    global_step, vector_steps, stored = count_step(loop.global_step, loop.vector_steps, valid)
    do_train = should_train(cfg, stored, healthy, global_step, vector_steps)
    learner_state, step_sums, step_counts = jax.lax.cond(
        do_train,
        partial(train, context, buffer, obs_stats, return_stats, train_key),
        partial(skip_training, names),
        loop.learner_state,
    )
    following = EnvLoop(
        learner_state=learner_state,
        buffer=buffer,
        ou_state=next_ou_state(loop.ou_state, next_ou, valid, episodes.done),
        obs_stats=obs_stats,
        return_stats=return_stats,
        carry=next_carry,
        global_step=global_step,
        vector_steps=vector_steps,
        healthy=healthy,
        sums=add_metrics(names, loop.sums, step_sums),
        counts=add_metrics(names, loop.counts, step_counts),
    )
    return following, episode_record(valid, episodes)


def choose_action(
    context: LoopContext, loop: EnvLoop, obs_stats: RunningStats, random_key: jax.Array, explore_key: jax.Array
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """The [-1, 1] action to take and the next OU noise: uniformly random until `learning_starts` env steps have
    been taken, so that the first updates see a spread of actions, then the learner's exploring policy."""
    cfg = context.learner.cfg
    policy_obs = normalize_obs(context.config, obs_stats, loop.carry.obs)
    policy_action, next_ou = context.learner.explore(loop.learner_state, policy_obs, loop.ou_state, explore_key)
    random_action = jax.random.uniform(random_key, policy_action.shape, jnp.float32, -1.0, 1.0)
    action = jnp.where(loop.global_step < cfg.learning_starts, random_action, policy_action)
    return action, next_ou


def step_is_finite(out: StepOutput, action: jnp.ndarray) -> jnp.ndarray:
    """Whether a step's observations, rewards and actions are all finite. The action too: an env that ignores a NaN
    control (MuJoCo zeroes it) would return finite obs and rewards."""
    return jnp.all(jnp.isfinite(out.obs)) & jnp.all(jnp.isfinite(out.reward)) & jnp.all(jnp.isfinite(action))


def store_transitions(
    buffer: ReplayBuffer,
    obs: jnp.ndarray,
    action: jnp.ndarray,
    out: StepOutput,
    valid: jnp.ndarray,
    healthy: jnp.ndarray,
) -> ReplayBuffer:
    """Insert the step's raw transitions, the done step with its true final observation. Autoreset steps (not
    `valid`) are skipped, and once anything non-finite appears (not `healthy`), nothing more is stored in this call."""
    transitions = Transitions(obs, action, out.reward, out.obs, out.terminated.astype(jnp.float32))
    return insert(buffer, transitions, valid & healthy)


def count_step(
    global_step: jnp.ndarray, vector_steps: jnp.ndarray, valid: jnp.ndarray
) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """The env steps and the vector steps taken, this one included, and whether it stored anything. An autoreset
    step in which no env stored a transition is not a step of the algorithm: counting it would make one more update
    per episode than the references (whose vector envs reset within the step) make."""
    global_step = global_step + valid.sum().astype(count_dtype())
    stored = valid.any()
    return global_step, vector_steps + stored.astype(vector_steps.dtype), stored


def should_train(
    cfg: OffPolicyConfig, stored: jnp.ndarray, healthy: jnp.ndarray, global_step: jnp.ndarray, vector_steps: jnp.ndarray
) -> jnp.ndarray:
    """Whether this step updates: it stored something, nothing non-finite has appeared, `learning_starts` is
    reached, and it is a `train_freq`-th counted vector step."""
    return stored & healthy & (global_step >= cfg.learning_starts) & (vector_steps % cfg.train_freq == 0)


def train(
    context: LoopContext,
    buffer: ReplayBuffer,
    obs_stats: RunningStats,
    return_stats: RunningStats,
    key: jax.Array,
    learner_state: Any,
) -> tuple[Any, dict[str, jnp.ndarray], dict[str, jnp.ndarray]]:
    """`gradient_steps` updates; returns the learner state and per-metric (sums, counts) over them. The learner
    state comes last, as the operand of the `lax.cond` that calls this."""
    cfg = context.learner.cfg
    step = partial(gradient_step, context, buffer, obs_stats, return_stats)
    if cfg.gradient_steps == 1:
        learner_state, diag = step(learner_state, key)
        diag = {k: v[None] for k, v in diag.items()}
    else:
        learner_state, diag = jax.lax.scan(step, learner_state, jax.random.split(key, cfg.gradient_steps))
    names = context.learner.update_metrics
    sums = {k: jnp.nansum(diag[k]) for k in names}
    # NaN marks a metric that a step did not compute (a delayed actor step), so it is neither summed nor counted.
    counts = {k: jnp.sum(~jnp.isnan(diag[k])).astype(jnp.float32) for k in names}
    return learner_state, sums, counts


def skip_training(
    names: tuple[str, ...], learner_state: Any
) -> tuple[Any, dict[str, jnp.ndarray], dict[str, jnp.ndarray]]:
    """The other branch of `train`'s `lax.cond`: the learner state unchanged, and nothing to sum or count."""
    zeros = zero_metrics(names)
    return learner_state, zeros, zeros


def gradient_step(
    context: LoopContext,
    buffer: ReplayBuffer,
    obs_stats: RunningStats,
    return_stats: RunningStats,
    learner_state: Any,
    step_key: jax.Array,
) -> tuple[Any, dict[str, jnp.ndarray]]:
    """One update on a fresh uniform sample; the learner state and key come last, as the scan's carry and input."""
    sample_key, update_key = jax.random.split(step_key)
    batch = learning_batch(
        context.config, sample(buffer, sample_key, context.learner.cfg.batch_size), obs_stats, return_stats
    )
    return context.learner.update(learner_state, batch, update_key)


def learning_batch(
    config: Config, batch: Transitions, obs_stats: RunningStats, return_stats: RunningStats
) -> Transitions:
    """A sampled batch as the learner trains on it. The buffer holds raw observations and rewards, so normalization
    and reward scaling apply here, with the current statistics, to old transitions as to new ones."""
    return batch._replace(
        obs=normalize_obs(config, obs_stats, batch.obs),
        next_obs=normalize_obs(config, obs_stats, batch.next_obs),
        reward=learning_reward(batch.reward, return_stats, config.env),
    )


def next_ou_state(ou_state: jnp.ndarray, next_ou: jnp.ndarray, valid: jnp.ndarray, done: jnp.ndarray) -> jnp.ndarray:
    """The OU noise after a step, restarted at 0 where an episode ended. An autoreset step's action is ignored, so
    its noise does not advance: an episode's first action then carries one OU increment from 0, as in the
    references."""
    return jnp.where(valid[:, None], next_ou, ou_state) * (1.0 - done.astype(jnp.float32))[:, None]


def episode_record(valid: jnp.ndarray, episodes: EpisodeStep) -> dict[str, Any]:
    """What the trainer needs of one step to log the episodes that ended in the call; the scan stacks them."""
    return dict(
        done=episodes.done,
        valid=valid,
        episode_return=episodes.episode_return,
        episode_length=episodes.episode_length,
        episode_info=episodes.episode_info,
    )


def add_metrics(
    names: tuple[str, ...], totals: dict[str, jnp.ndarray], step: dict[str, jnp.ndarray]
) -> dict[str, jnp.ndarray]:
    """The call's running sums (or counts) of the update metrics, with one step's added, in `names` order: the dicts
    that come back out of the scan and the cond have their keys sorted."""
    return {k: totals[k] + step[k] for k in names}


def end_state(state: OffPolicyState, final: EnvLoop, key: jax.Array) -> OffPolicyState:
    """The train state after the scan, with the key for the next call."""
    return OffPolicyState(
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


def keep_last_good(finite: jnp.ndarray, new_state: OffPolicyState, state: OffPolicyState) -> OffPolicyState:
    """`new_state`, or where the call was not `finite`, the state it was given, so that the trainer can checkpoint
    the last good state although the input buffers were donated. The buffer is always the new one: it kept only
    the finite transitions stored before anything non-finite appeared."""
    small_new = {k: v for k, v in new_state._asdict().items() if k != "buffer"}
    small_old = {k: v for k, v in state._asdict().items() if k != "buffer"}
    kept = jax.tree_util.tree_map(lambda new, old: jnp.where(finite, new, old), small_new, small_old)
    return OffPolicyState(buffer=new_state.buffer, **kept)


def call_metrics(
    cfg: OffPolicyConfig, names: tuple[str, ...], final: EnvLoop, records: dict[str, Any], finite: jnp.ndarray
) -> dict[str, Any]:
    """The call's metrics: each update metric's mean over the gradient steps that computed it (NaN if none did),
    the loop's own, and the stacked per-step episode records that the trainer logs episodes from."""
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
    return metrics
