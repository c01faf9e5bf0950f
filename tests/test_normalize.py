import numpy as np

from canter.config.schema import Config, EnvConfig
from canter.core.normalize import (
    init_stats,
    learning_reward,
    normalize,
    normalize_obs,
    scale_reward,
    update_stats,
)


def test_running_stats_match_numpy_over_masked_batches():
    rng = np.random.default_rng(1)
    stats = init_stats((3,))
    kept = []
    for _ in range(20):
        batch = rng.normal(2.0, 3.0, size=(16, 3)).astype(np.float32)
        mask = rng.random(16) > 0.3
        stats = update_stats(stats, batch, mask)
        kept.append(batch[mask])
    data = np.concatenate(kept)
    np.testing.assert_allclose(np.asarray(stats.mean), data.mean(0), rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(np.asarray(stats.var), data.var(0), rtol=1e-3)
    assert np.isclose(float(stats.count), len(data) + 1e-4, rtol=1e-6)


def test_fully_masked_batch_leaves_stats_unchanged():
    stats = update_stats(init_stats((2,)), np.ones((4, 2), np.float32), np.ones(4, bool))
    same = update_stats(stats, np.full((4, 2), 1e6, np.float32), np.zeros(4, bool))
    for a, b in zip(stats, same):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_normalize_and_reward_scale_clip():
    stats = update_stats(init_stats(()), np.array([0.0, 2.0], np.float32), np.ones(2, bool))
    var = float(stats.var)
    out = normalize(stats, np.array([1.0, 1e6], np.float32), clip=10.0)
    np.testing.assert_allclose(np.asarray(out), [(1.0 - float(stats.mean)) / np.sqrt(var + 1e-8), 10.0], rtol=1e-5)
    scaled = scale_reward(stats, np.array([2.0, -1e9], np.float32), clip=10.0)
    np.testing.assert_allclose(np.asarray(scaled), [2.0 / np.sqrt(var + 1e-8), -10.0], rtol=1e-5)


def _env(**settings):
    return EnvConfig(id="Hopper-v5", **settings)


def test_learning_reward_is_the_normalized_reward_or_the_raw_reward_times_a_fixed_scale():
    stats = update_stats(init_stats(()), np.array([0.0, 4.0], np.float32), np.ones(2, bool))
    reward = np.array([3.0, -2.0, 0.0], np.float32)
    fixed = learning_reward(reward, stats, _env(normalize_reward=False, clip_reward=1.0, reward_scale=0.1))
    np.testing.assert_allclose(np.asarray(fixed), [0.3, -0.2, 0.0], rtol=1e-6)
    unscaled = learning_reward(reward, stats, _env(normalize_reward=False, clip_reward=1.0, reward_scale=1.0))
    np.testing.assert_array_equal(np.asarray(unscaled), reward)
    normalized = learning_reward(reward, stats, _env(normalize_reward=True, clip_reward=1.0, reward_scale=1.0))
    np.testing.assert_allclose(np.asarray(normalized), [1.0, -2.0 / 2.0, 0.0], rtol=1e-5)


def test_policies_see_observations_normalized_and_clipped_only_when_env_normalize_obs():
    stats = update_stats(init_stats((2,)), np.array([[0.0, 1.0], [2.0, 3.0]], np.float32), np.ones(2, bool))
    obs = np.array([[1.0, 1e6]], np.float32)
    on = normalize_obs(Config(env=_env(normalize_obs=True, clip_obs=5.0)), stats, obs)
    np.testing.assert_array_equal(np.asarray(on), np.asarray(normalize(stats, obs, 5.0)))
    assert float(on[0, 1]) == 5.0
    off = normalize_obs(Config(env=_env(normalize_obs=False, clip_obs=5.0)), stats, obs)
    np.testing.assert_array_equal(np.asarray(off), obs)
