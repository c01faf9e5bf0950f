import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import norm

from canter.core.netconfig import NetConfig
from canter.core.networks import (
    all_finite,
    gaussian_entropy,
    gaussian_log_prob,
    gaussian_log_prob_per_dim,
    init_params,
    policy_dist,
    value,
)


def test_log_prob_and_entropy_match_scipy():
    rng = np.random.default_rng(0)
    mean = rng.normal(size=(5, 3)).astype(np.float32)
    log_std = rng.normal(scale=0.3, size=(5, 3)).astype(np.float32)
    action = rng.normal(size=(5, 3)).astype(np.float32)
    expected = norm.logpdf(action, mean, np.exp(log_std)).sum(-1)
    np.testing.assert_allclose(np.asarray(gaussian_log_prob(mean, log_std, action)), expected, rtol=1e-5)
    per_dim = norm.logpdf(action, mean, np.exp(log_std))
    np.testing.assert_allclose(np.asarray(gaussian_log_prob_per_dim(mean, log_std, action)), per_dim, rtol=1e-5)
    np.testing.assert_allclose(
        np.asarray(gaussian_entropy(log_std)), norm.entropy(mean, np.exp(log_std)).sum(-1), rtol=1e-5
    )


def test_shapes_dtypes_and_log_std_options():
    key = jax.random.key(0)
    net = NetConfig(hidden=(32, 16), critic_hidden=(8,), log_std_init=-0.5)
    params = init_params(key, net, 7, 2)
    assert [layer["w"].shape for layer in params["actor"]] == [(7, 32), (32, 16), (16, 2)]
    assert [layer["w"].shape for layer in params["critic"]] == [(7, 8), (8, 1)]
    assert all(x.dtype == jnp.float32 for x in jax.tree_util.tree_leaves(params))
    obs = jnp.ones((4, 7), jnp.float32)
    mean, log_std = policy_dist(params, obs, net)
    assert mean.shape == (4, 2) and np.allclose(np.asarray(log_std), -0.5)
    assert value(params, obs, net).shape == (4,)

    sd = NetConfig(hidden=(8,), state_dependent_std=True, log_std_init=-1.0)
    params = init_params(key, sd, 3, 2)
    assert "log_std" not in params
    _, log_std = policy_dist(params, jnp.asarray(np.random.default_rng(0).normal(size=(5, 3)), jnp.float32), sd)
    np.testing.assert_allclose(np.asarray(log_std), -1.0)


def test_orthogonal_init_gains():
    params = init_params(jax.random.key(1), NetConfig(hidden=(64, 64)), 64, 4)
    w = np.asarray(params["actor"][1]["w"])
    np.testing.assert_allclose(w.T @ w, 2.0 * np.eye(64), atol=1e-4)
    assert np.linalg.norm(np.asarray(params["actor"][-1]["w"]), axis=0).max() < 0.011


def test_all_finite_checks_every_floating_leaf_and_passes_integer_counters():
    tree = {"w": jnp.ones((2, 3)), "b": [jnp.zeros(3), jnp.float32(1.0)], "count": jnp.int32(7)}
    assert bool(all_finite(tree))
    for bad in (jnp.nan, jnp.inf, -jnp.inf):
        assert not bool(all_finite({**tree, "b": [jnp.zeros(3).at[1].set(bad), jnp.float32(1.0)]}))
    assert not bool(jax.jit(all_finite)((jnp.ones(2), jnp.float32(jnp.nan))))
