"""Running statistics as pure functions over a small pytree, so they live inside the jitted train state.

The update is the parallel (Chan et al.) merge of batch moments, weighted by a mask so that EnvPool's autoreset
steps contribute nothing.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import jax.numpy as jnp

if TYPE_CHECKING:
    from canter.config.schema import Config, EnvConfig

EPSILON = 1e-8  # added to variances before the square root


class RunningStats(NamedTuple):
    mean: jnp.ndarray
    var: jnp.ndarray
    # Shadows tuple.count, but the name is part of every checkpoint's leaf paths. All three are float32, as the
    # physics may be (Gymnasium and SB3 keep float64): past 2^24 merges of a batch (16.8M steps per env) adding a
    # batch no longer moves the count, and the statistics go on as a moving average whose weight per batch stays at
    # 2^-24. With one env over millions of steps, a mean near 1e3 that drifts by a few units lags it by about 2.
    count: jnp.ndarray  # type: ignore[assignment]


def init_stats(shape: tuple[int, ...]) -> RunningStats:
    # count starts at a tiny epsilon, as Gymnasium's RunningMeanStd does, so the first update is well defined.
    return RunningStats(jnp.zeros(shape, jnp.float32), jnp.ones(shape, jnp.float32), jnp.asarray(1e-4, jnp.float32))


def update_stats(stats: RunningStats, batch: jnp.ndarray, mask: jnp.ndarray) -> RunningStats:
    """Merge the rows of `batch` (leading axis) whose `mask` is true into `stats`."""
    weights = mask.astype(jnp.float32).reshape((-1,) + (1,) * (batch.ndim - 1))
    batch_count = weights.sum()
    safe_count = jnp.maximum(batch_count, 1.0)
    batch_mean = (batch * weights).sum(0) / safe_count
    batch_var = (jnp.square(batch - batch_mean) * weights).sum(0) / safe_count
    total = stats.count + batch_count
    delta = batch_mean - stats.mean
    mean = stats.mean + delta * batch_count / total
    m2 = stats.var * stats.count + batch_var * batch_count + jnp.square(delta) * stats.count * batch_count / total
    updated = RunningStats(mean, m2 / total, total)
    keep = batch_count > 0
    return RunningStats(*(jnp.where(keep, new, old) for new, old in zip(updated, stats)))


def normalize(stats: RunningStats, x: jnp.ndarray, clip: float, eps: float = EPSILON) -> jnp.ndarray:
    return jnp.clip((x - stats.mean) / jnp.sqrt(stats.var + eps), -clip, clip)


def normalize_obs(config: Config, stats: RunningStats, obs: jnp.ndarray) -> jnp.ndarray:
    """The observation a policy sees: normalized by the running statistics when `env.normalize_obs`, else raw."""
    return normalize(stats, obs, config.env.clip_obs) if config.env.normalize_obs else obs


def scale_reward(stats: RunningStats, reward: jnp.ndarray, clip: float, eps: float = EPSILON) -> jnp.ndarray:
    """Divide by the std of the discounted return (no mean shift, which would change the optimal policy)."""
    return jnp.clip(reward / jnp.sqrt(stats.var + eps), -clip, clip)


def learning_reward(reward: jnp.ndarray, return_stats: RunningStats, env: EnvConfig) -> jnp.ndarray:
    """The reward a learner trains on: scaled by the return's running std when `env.normalize_reward`, else by the
    fixed factor `env.reward_scale`."""
    if env.normalize_reward:
        return scale_reward(return_stats, reward, env.clip_reward)
    return reward * env.reward_scale
