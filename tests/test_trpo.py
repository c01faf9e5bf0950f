import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from canter.algos.trpo.iteration import (
    PolicyBatch,
    critic_optimizer,
    critic_regression,
    policy_objectives,
    policy_step,
    split_policy,
)
from canter.algos.trpo.natural import (
    backtracking_line_search,
    conjugate_gradient,
    fisher_vector_product,
)
from canter.algos.trpo.sections import TRPOConfig
from canter.config.schema import Config
from canter.core.netconfig import NetConfig
from canter.core.networks import init_params, value


def test_conjugate_gradient_matches_a_direct_solve():
    rng = np.random.default_rng(0)
    m = rng.normal(size=(6, 6))
    a = m @ m.T + 0.5 * np.eye(6)
    b = rng.normal(size=6)
    result = conjugate_gradient(lambda v: jnp.asarray(a) @ v, jnp.asarray(b), max_iters=6)
    np.testing.assert_allclose(np.asarray(result.x), np.linalg.solve(a, b), rtol=1e-6, atol=1e-8)
    assert float(result.residual_norm) < 1e-5
    # Fewer iterations: a worse but finite answer, and the iteration count is reported.
    short = conjugate_gradient(lambda v: jnp.asarray(a) @ v, jnp.asarray(b), max_iters=2)
    assert int(short.iterations) == 2 and np.all(np.isfinite(np.asarray(short.x)))
    # A zero right-hand side stops at once (no 0/0).
    zero = conjugate_gradient(lambda v: jnp.asarray(a) @ v, jnp.zeros(6), max_iters=6)
    assert int(zero.iterations) == 0 and np.all(np.asarray(zero.x) == 0)


def _tiny_problem(state_dependent_std=False, seed=0):
    net = NetConfig(hidden=(3,), state_dependent_std=state_dependent_std, log_std_init=-0.3)
    config = Config().replace(net=net, trpo=TRPOConfig(max_kl=0.01, cg_iters=20, cg_damping=0.0))
    key = jax.random.key(seed)
    params = init_params(key, net, 2, 2)
    # Larger output weights than the 0.01 init, so the means depend visibly on the observation.
    params["actor"][-1]["w"] = jax.random.normal(jax.random.key(seed + 1), params["actor"][-1]["w"].shape)
    rng = np.random.default_rng(seed)
    batch = PolicyBatch(
        obs=jnp.asarray(rng.normal(size=(12, 2)), jnp.float32),
        actions=jnp.asarray(rng.normal(size=(12, 2)), jnp.float32),
        advantages=jnp.asarray(rng.normal(size=12), jnp.float32),
        mask=jnp.asarray([1.0] * 10 + [0.0] * 2),
    )
    policy, _ = split_policy(params)
    return config, policy, batch


@pytest.mark.parametrize("state_dependent_std", [False, True])
def test_fisher_vector_product_matches_the_explicit_hessian_of_the_kl(state_dependent_std):
    config, policy, batch = _tiny_problem(state_dependent_std)
    objectives = policy_objectives(policy, batch, config)
    theta = objectives.theta
    hessian = np.asarray(jax.jit(jax.hessian(objectives.mean_kl))(theta), np.float64)
    assert float(objectives.mean_kl(theta)) == pytest.approx(0.0, abs=1e-7)
    v = jax.random.normal(jax.random.key(7), theta.shape)
    for damping in (0.0, 0.1):
        fvp = fisher_vector_product(objectives.mean_kl, theta, damping)
        expected = hessian @ np.asarray(v, np.float64) + damping * np.asarray(v, np.float64)
        np.testing.assert_allclose(np.asarray(jax.jit(fvp)(v)), expected, rtol=1e-4, atol=1e-6)
    # At the old policy the KL Hessian is the Fisher matrix: symmetric positive semi-definite.
    np.testing.assert_allclose(hessian, hessian.T, atol=1e-6)
    assert np.linalg.eigvalsh(hessian).min() > -1e-5


def test_line_search_on_a_hand_made_case():
    # surrogate(x) = -(x - 1)^2 is maximal at 1; kl(x) = x^2 / 2. From 0 with full step 4 and shrink 0.5 the
    # candidates are 4 (worse: -9), 2 (equal: -1, not an improvement), 1 (gain 1, KL 0.5).
    surrogate = lambda x: -jnp.sum(jnp.square(x - 1.0))  # noqa: E731
    kl = lambda x: 0.5 * jnp.sum(jnp.square(x))  # noqa: E731
    theta, step = jnp.zeros(1), jnp.full(1, 4.0)
    r = backtracking_line_search(surrogate, kl, theta, step, max_kl=1.0, shrink=0.5, max_iters=10)
    assert bool(r.accepted) and int(r.steps) == 3 and float(r.fraction) == 0.25
    assert float(r.theta[0]) == 1.0 and float(r.improvement) == 1.0 and float(r.kl) == 0.5
    # A tighter trust region rejects 1 (KL 0.5) and 0.5 (KL 0.125) and takes 0.25 (KL 0.03125, gain 0.4375).
    r = backtracking_line_search(surrogate, kl, theta, step, max_kl=0.1, shrink=0.5, max_iters=10)
    assert int(r.steps) == 5 and float(r.theta[0]) == 0.25 and float(r.improvement) == pytest.approx(0.4375)
    # Too few candidates: nothing qualifies, the parameters stay put.
    r = backtracking_line_search(surrogate, kl, theta, step, max_kl=0.1, shrink=0.5, max_iters=4)
    assert not bool(r.accepted) and int(r.steps) == 4 and float(r.theta[0]) == 0.0 and float(r.fraction) == 0.0
    # A step in the wrong direction is never taken.
    r = backtracking_line_search(surrogate, kl, theta, -step, max_kl=10.0, shrink=0.5, max_iters=10)
    assert not bool(r.accepted) and float(r.theta[0]) == 0.0


@pytest.mark.parametrize("max_kl", [0.01, 1e-4])
def test_policy_step_improves_the_surrogate_within_the_trust_region(max_kl):
    config, policy, batch = _tiny_problem()
    config = Config().replace(net=config.net, trpo=TRPOConfig(max_kl=max_kl, cg_iters=10, cg_damping=0.1))
    new_policy, d = jax.jit(policy_step, static_argnums=2)(policy, batch, config)
    objectives = policy_objectives(policy, batch, config)
    flat_new = ravel_pytree(new_policy)[0]
    gain = float(objectives.surrogate(flat_new) - objectives.surrogate(objectives.theta))
    kl = float(objectives.mean_kl(flat_new))
    assert float(d["step_accepted"]) == 1.0
    assert gain > 0 and gain == pytest.approx(float(d["surrogate_gain"]), rel=1e-4)
    assert kl <= max_kl and kl == pytest.approx(float(d["policy_kl"]), rel=1e-4)
    # The quadratic model aims at the edge of the region, so the KL of the taken step is of the order of max_kl.
    assert kl > max_kl * 0.8**10 * 0.5


def test_critic_regression_fits_the_returns():
    config = Config().replace(
        net=NetConfig(hidden=(8,)), trpo=TRPOConfig(critic_lr=1e-2, critic_epochs=50, critic_minibatch_size=8)
    )
    params = init_params(jax.random.key(0), config.net, 2, 1)
    rng = np.random.default_rng(0)
    obs = jnp.asarray(rng.normal(size=(32, 2)), jnp.float32)
    returns = obs[:, 0] * 2.0 - obs[:, 1]
    mask = jnp.ones(32).at[5].set(0.0)
    poisoned = returns.at[5].set(1e6)  # a masked row must not pull the fit
    regression = jax.jit(critic_regression, static_argnums=6)
    critic, _, loss = regression(
        params["critic"],
        critic_optimizer(config).init(params["critic"]),
        obs,
        poisoned,
        mask,
        jax.random.key(1),
        config,
    )
    initial = float(jnp.mean(jnp.square(returns)))
    assert math.isfinite(float(loss)) and float(loss) < 0.05 * initial
    fitted = np.asarray(value({"critic": critic}, obs, config.net))
    assert np.mean(np.square(np.delete(fitted - np.asarray(returns), 5))) < 0.05 * initial
