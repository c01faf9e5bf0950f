"""The autoreset step is masked out of the normalizers, episode statistics, step count and loss."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from canter.algos.onpolicy_rollout import collect, estimate_advantages, explained_variance
from canter.algos.ppo.iteration import init_train_state, make_iteration
from canter.config.build import build_config
from canter.core.networks import gaussian_log_prob, policy_dist, value
from canter.envs import make_vec_env
from canter.envs.episodes import init_env_carry
from test_gae import reference_gae


def _setup(env_id, backend, num_envs, n_steps, sets=()):
    config = build_config(
        env_id,
        sets=[
            f"env.backend={backend}",
            f"env.num_envs={num_envs}",
            f"ppo.n_steps={n_steps}",
            f"ppo.minibatch_size={n_steps}",
            "net.hidden=8",
            *sets,
        ],
    )
    env = make_vec_env(config.env.id, config.env.backend, num_envs, list(range(num_envs)))
    state = init_train_state(config, env.spec.obs_dim, env.spec.act_dim, config.run.seed)
    carry = init_env_carry(env.initial_state(), env.reset(), env.spec.info_keys)
    return config, env, state, carry


def _collect(config, env, state, carry):
    low = jnp.asarray(env.spec.action_low, jnp.float32)
    high = jnp.asarray(env.spec.action_high, jnp.float32)
    fn = jax.jit(lambda s, c, k: collect(s.params, s.obs_stats, s.return_stats, c, k, env.jax_step, low, high, config))
    return fn(state, carry, jax.random.key(0))


def test_masking_on_a_known_episode_structure():
    """DictObs terminates after 7 steps with reward t: every 8th step is the autoreset step."""
    config, env, state, carry = _setup("canter_test_envs:DictObs-v0", "gymnasium", 2, 24)
    obs_stats, return_stats, carry, tr, _ = _collect(config, env, state, carry)
    valid = np.asarray(tr.valid)
    expected_valid = np.array([(t % 8) != 7 for t in range(24)])
    np.testing.assert_array_equal(valid, np.stack([expected_valid] * 2, 1))
    finished = np.asarray(tr.done)
    assert finished.sum() == 6
    np.testing.assert_array_equal(np.asarray(tr.episode_return)[finished], 28.0)
    np.testing.assert_array_equal(np.asarray(tr.episode_length)[finished], 7)
    np.testing.assert_array_equal(np.asarray(tr.episode_info["reward_step"])[finished], 28.0)
    # Normalizers saw exactly the valid steps (count starts at 1e-4).
    assert float(obs_stats.count) == pytest.approx(valid.sum() + 1e-4)
    assert float(return_stats.count) == pytest.approx(valid.sum() + 1e-4)
    # Acted-on observations of valid steps only: the terminal obs (t=7) never enters the obs statistics.
    seen_a = [t / 10 for t in range(7)]
    assert float(obs_stats.mean[0]) == pytest.approx(np.mean(seen_a), abs=1e-5)
    # Rewards of reset steps are zero and their transitions are excluded from learning.
    assert np.all(np.asarray(tr.reward)[~valid] == 0.0)


def _reference_normalized(raw, valid, clip):
    """Plain numpy: raw[t] ([T, N, D]) normalized by the statistics of every valid row of steps 0..t (the update
    comes before use), merged with the prior of init_stats (mean 0, var 1, count 1e-4), epsilon 1e-8, clipped."""
    c0 = 1e-4
    out = np.empty(raw.shape, np.float64)
    for t in range(raw.shape[0]):
        seen = raw[: t + 1][valid[: t + 1]].astype(np.float64)  # [n, D]
        n = c0 + len(seen)
        mean = seen.sum(0) / n
        var = (c0 * (1.0 + mean**2) + np.square(seen - mean).sum(0)) / n
        out[t] = np.clip((raw[t] - mean) / np.sqrt(var + 1e-8), -clip, clip)
    return out


def test_the_policy_acts_on_and_the_rollout_stores_normalized_observations():
    """DictObs's raw obs at episode step k is (a, b, b) = (k/10, -k/10, -k/10); the autoreset step (k = 7) shows the
    terminal obs, which the stats never see. tr.obs must be the raw obs normalized by the running stats as they
    stand after that step's update, and the stored log-prob must be the policy's on tr.obs."""
    config, env, state, carry = _setup("canter_test_envs:DictObs-v0", "gymnasium", 2, 24)
    # A policy head that the observation moves visibly (the 0.01-gain init barely does).
    actor = list(state.params["actor"])
    actor[-1] = {**actor[-1], "w": actor[-1]["w"] * 100.0}
    params = {**state.params, "actor": actor}
    state = state._replace(params=params)
    obs_stats, _, _, tr, _ = _collect(config, env, state, carry)
    valid = np.asarray(tr.valid)
    assert valid.all(axis=1).sum() == 21 and valid.any(axis=1).sum() == 21  # both envs in step
    k = np.arange(24) % 8
    raw = np.stack([k / 10, -k / 10, -k / 10], 1).astype(np.float32)[:, None].repeat(2, 1)  # [T, N, 3]
    expected = _reference_normalized(raw, valid, config.env.clip_obs)
    assert config.env.normalize_obs
    assert not np.allclose(expected, raw, atol=0.05), "normalization must move the observations"
    np.testing.assert_allclose(np.asarray(tr.obs), expected, rtol=1e-4, atol=1e-5)
    # The final stats are the reference's too.
    np.testing.assert_allclose(np.asarray(obs_stats.mean), raw[valid].mean(0) * 42 / (42 + 1e-4), rtol=1e-5)
    # The action was drawn from the policy on the stored (normalized) obs.
    mean, log_std = policy_dist(params, tr.obs, config.net)
    np.testing.assert_allclose(
        np.asarray(tr.log_prob), np.asarray(gaussian_log_prob(mean, log_std, tr.action)), rtol=1e-5, atol=1e-5
    )
    raw_mean, _ = policy_dist(params, jnp.asarray(raw), config.net)
    assert not np.allclose(np.asarray(raw_mean), np.asarray(mean), atol=1e-3), "raw and normalized obs must differ"


def test_estimate_advantages_bootstraps_from_the_last_observation_and_matches_a_python_loop():
    config, env, state, carry = _setup("canter_test_envs:DictObs-v0", "gymnasium", 2, 24)
    _, _, _, tr, next_obs = _collect(config, env, state, carry)
    values, advantages, returns = estimate_advantages(state.params, tr, next_obs, config)
    assert values.shape == (25, 2) and advantages.shape == returns.shape == (24, 2)
    np.testing.assert_allclose(values[-1], value(state.params, next_obs, config.net), rtol=1e-6)
    np.testing.assert_allclose(values[:-1], value(state.params, tr.obs, config.net), rtol=1e-6)
    expected_adv, expected_ret = reference_gae(
        np.asarray(tr.reward),
        np.asarray(values),
        np.asarray(tr.terminated),
        np.asarray(tr.done),
        np.asarray(tr.valid),
        config.ppo.gamma,
        config.ppo.gae_lambda,
    )
    np.testing.assert_allclose(advantages, expected_adv, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(returns * tr.valid, expected_ret, rtol=1e-4, atol=1e-5)


def test_a_fixed_reward_scale_reaches_the_learner_and_not_the_logged_returns():
    """DictObs's reward at episode step t is t; with env.reward_scale=0.1 the learner sees 0.1 t."""
    sets = ("env.normalize_reward=false", "env.reward_scale=0.1")
    config, env, state, carry = _setup("canter_test_envs:DictObs-v0", "gymnasium", 2, 16, sets)
    _, return_stats, _, tr, _ = _collect(config, env, state, carry)
    valid = np.asarray(tr.valid)
    step_reward = np.array([(t % 8) + 1 if (t % 8) != 7 else 0 for t in range(16)], np.float32)
    np.testing.assert_allclose(np.asarray(tr.reward)[:, 0], 0.1 * step_reward, rtol=1e-6)
    finished = np.asarray(tr.done)
    np.testing.assert_array_equal(np.asarray(tr.episode_return)[finished], 28.0)
    assert valid.sum() == 28 and float(return_stats.count) == pytest.approx(1e-4)


def test_envpool_truncation_masking_and_step_count():
    """Pendulum truncates at 200: with 402 steps the autoreset steps are t=200 and t=401; 400 steps count."""
    config, env, state, carry = _setup("Pendulum-v1", "envpool", 1, 402)
    iteration = jax.jit(make_iteration(config, env.spec, env.jax_step))
    new_state, _, metrics = iteration(state, carry, jnp.float32(1.0))
    assert int(metrics["steps"]) == 400 and int(new_state.global_step) == 400
    finished = np.asarray(metrics["finished"])
    assert finished.sum() == 2
    np.testing.assert_array_equal(np.asarray(metrics["episode_length"])[finished], 200)
    assert float(new_state.obs_stats.count) == pytest.approx(400 + 1e-4)
    assert float(new_state.return_stats.count) == pytest.approx(400 + 1e-4)


def test_explained_variance_against_numpy_over_the_valid_steps():
    rng = np.random.default_rng(3)
    target = rng.normal(size=(64, 4)).astype(np.float32)
    predicted = (target + 0.5 * rng.normal(size=target.shape)).astype(np.float32)
    mask = (rng.random(target.shape) < 0.7).astype(np.float32)
    valid = mask.astype(bool)
    expected = 1.0 - np.var(target[valid] - predicted[valid]) / np.var(target[valid])
    found = float(explained_variance(jnp.asarray(predicted), jnp.asarray(target), jnp.asarray(mask)))
    assert found == pytest.approx(expected, rel=1e-5)
    # A perfect prediction explains everything, predicting the mean explains nothing, and a flat target gives NaN.
    assert float(explained_variance(jnp.asarray(target), jnp.asarray(target), jnp.asarray(mask))) == 1.0
    mean = np.full_like(target, target[valid].mean())
    assert float(explained_variance(jnp.asarray(mean), jnp.asarray(target), jnp.asarray(mask))) == pytest.approx(
        0.0, abs=1e-6
    )
    flat = jnp.ones_like(jnp.asarray(target))
    assert np.isnan(float(explained_variance(flat, flat, jnp.asarray(mask))))
