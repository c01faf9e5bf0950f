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
from numpy_references import Adam


def test_conjugate_gradient_matches_a_direct_solve():
    rng = np.random.default_rng(0)
    m = rng.normal(size=(6, 6))
    a = m @ m.T + 0.5 * np.eye(6)
    b = rng.normal(size=6)
    result = conjugate_gradient(lambda v: jnp.asarray(a) @ v, jnp.asarray(b), max_iters=6)
    np.testing.assert_allclose(np.asarray(result.x), np.linalg.solve(a, b), rtol=1e-6, atol=1e-8)
    assert float(result.residual_norm) < 1e-5
    # Fewer iterations: the iteration count is reported, and k iterations from 0 give the minimizer of the quadratic
    # x^T A x / 2 - b^T x over the Krylov space span{b, A b, ..., A^(k-1) b}: with K its basis, a direct solve of
    # (K^T A K) y = K^T b gives x = K y.
    short = conjugate_gradient(lambda v: jnp.asarray(a) @ v, jnp.asarray(b), max_iters=2)
    krylov = np.stack([b, a @ b], axis=1)
    expected = krylov @ np.linalg.solve(krylov.T @ a @ krylov, krylov.T @ b)
    assert int(short.iterations) == 2
    np.testing.assert_allclose(np.asarray(short.x), expected, rtol=1e-6, atol=1e-8)
    assert not np.allclose(expected, np.linalg.solve(a, b), rtol=1e-2)  # two iterations do not solve it yet
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


def _jnp_policy(theta, unravel, obs, state_dependent_std):
    """Mean and log std of the tanh MLP policy, written out here (jnp, so that jax can differentiate it)."""
    params = unravel(theta)
    x = obs
    for layer in params["actor"][:-1]:
        x = jnp.tanh(x @ layer["w"] + layer["b"])
    out = x @ params["actor"][-1]["w"] + params["actor"][-1]["b"]
    if state_dependent_std:
        half = out.shape[-1] // 2
        return out[:, :half], jnp.clip(out[:, half:], -20.0, 2.0)
    return out, jnp.broadcast_to(params["log_std"], out.shape)


@pytest.mark.parametrize(
    "state_dependent_std, max_kl, damping, backtracks",
    [
        (False, 0.01, 0.1, False),  # a small trust region: the quadratic model holds and the full step is taken
        (True, 2.0, 0.0, True),  # a large one: the full step overshoots and the search backtracks
    ],
)
def test_policy_step_matches_an_explicit_fisher_solve_and_a_python_line_search(
    state_dependent_std, max_kl, damping, backtracks
):
    """The natural gradient from an explicit matrix: A = F + damping I with F the Hessian (jax.hessian) of a KL
    written out here, solved with np.linalg.solve; the step scaled to sqrt(2 max_kl / x^T A x); then, in a Python
    loop, the first of shrink^j times it whose surrogate (written out here too) improves and whose KL is within
    max_kl."""
    net = NetConfig(hidden=(3,), log_std_init=-0.3, state_dependent_std=state_dependent_std)
    trpo = TRPOConfig(max_kl=max_kl, cg_iters=50, cg_damping=damping, line_search_iters=10, line_search_shrink=0.8)
    config = Config().replace(net=net, trpo=trpo)
    params = init_params(jax.random.key(0), net, 2, 2)
    params["actor"][-1]["w"] = jax.random.normal(jax.random.key(1), params["actor"][-1]["w"].shape) * 0.5
    policy, _ = split_policy(jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float64), params))
    rng = np.random.default_rng(0)
    obs, actions, advantages = rng.normal(size=(16, 2)), rng.normal(size=(16, 2)), rng.normal(size=16)
    mask = np.array([1.0] * 13 + [0.0] * 3)
    batch = PolicyBatch(*(jnp.asarray(x) for x in (obs, actions, advantages, mask)))
    new_policy, d = jax.jit(policy_step, static_argnums=2)(policy, batch, config)

    theta, unravel = ravel_pytree(policy)
    assert theta.dtype == jnp.float64
    old_mean, old_log_std = (np.asarray(x) for x in _jnp_policy(theta, unravel, obs, state_dependent_std))

    def log_prob(mean, log_std):
        return jnp.sum(-0.5 * jnp.square((actions - mean) / jnp.exp(log_std)) - log_std - 0.5 * np.log(2 * np.pi), -1)

    def surrogate(flat):
        mean, log_std = _jnp_policy(flat, unravel, obs, state_dependent_std)
        ratio = jnp.exp(log_prob(mean, log_std) - log_prob(old_mean, old_log_std))
        return jnp.sum(ratio * advantages * mask) / mask.sum()

    def mean_kl(flat):
        mean, log_std = _jnp_policy(flat, unravel, obs, state_dependent_std)
        spread = jnp.exp(2 * old_log_std) + jnp.square(old_mean - mean)
        kl = jnp.sum(log_std - old_log_std + spread / (2 * jnp.exp(2 * log_std)) - 0.5, -1)
        return jnp.sum(kl * mask) / mask.sum()

    theta = np.asarray(theta)
    gradient = np.asarray(jax.jit(jax.grad(surrogate))(theta))
    a = np.asarray(jax.jit(jax.hessian(mean_kl))(theta)) + damping * np.eye(theta.size)
    x = np.linalg.solve(a, gradient)
    full_step = np.sqrt(2 * max_kl / (x @ a @ x)) * x
    surrogate, mean_kl = jax.jit(surrogate), jax.jit(mean_kl)
    base = float(surrogate(theta))
    chosen, fraction, tries = theta, 0.0, 0
    for j in range(trpo.line_search_iters):
        tries = j + 1
        candidate = theta + trpo.line_search_shrink**j * full_step
        if float(surrogate(candidate)) > base and float(mean_kl(candidate)) <= max_kl:
            chosen, fraction = candidate, trpo.line_search_shrink**j
            break
    assert fraction > 0 and (tries > 1) == backtracks
    assert float(d["step_accepted"]) == 1.0 and int(d["line_search_steps"]) == tries
    assert float(d["step_fraction"]) == pytest.approx(fraction, rel=1e-9)
    # Conjugate gradient stops at a squared residual of 1e-10, not at the exact solve: agreement to 1e-3 of the step.
    np.testing.assert_allclose(
        np.asarray(ravel_pytree(new_policy)[0]), chosen, rtol=0, atol=1e-3 * np.abs(full_step).max()
    )
    assert float(d["surrogate_gain"]) == pytest.approx(float(surrogate(chosen)) - base, rel=1e-3)
    assert float(d["policy_kl"]) == pytest.approx(float(mean_kl(chosen)), rel=1e-3)


def _numpy_value_and_grad(layers, obs, returns, mask):
    """The masked mean squared error of a tanh MLP's output to the returns, and its gradient by backpropagation
    written out in numpy, as layers of {"w", "b"}."""
    activations, x = [obs], obs
    for i, layer in enumerate(layers):
        x = x @ layer["w"] + layer["b"]
        if i < len(layers) - 1:
            x = np.tanh(x)
            activations.append(x)
    error = x[:, 0] - returns
    total = max(mask.sum(), 1.0)
    delta = (2 * error * mask / total)[:, None]
    grads = [None] * len(layers)
    for i in reversed(range(len(layers))):
        grads[i] = {"w": activations[i].T @ delta, "b": delta.sum(0)}
        if i > 0:
            delta = (delta @ layers[i]["w"].T) * (1 - np.square(activations[i]))
    return float(np.sum(np.square(error) * mask) / total), grads


def test_critic_regression_matches_numpy_adam_over_the_same_minibatches():
    """Adam (numpy, lr critic_lr, eps 1e-8) on the masked MSE with numpy backpropagation, over the minibatches of a
    permutation per epoch drawn from the same keys; the reported loss is the last epoch's minibatch mean."""
    config = Config().replace(
        net=NetConfig(hidden=(4,)), trpo=TRPOConfig(critic_lr=1e-2, critic_epochs=3, critic_minibatch_size=4)
    )
    critic = jax.tree_util.tree_map(
        lambda x: jnp.asarray(x, jnp.float64), init_params(jax.random.key(0), config.net, 2, 1)["critic"]
    )
    rng = np.random.default_rng(1)
    obs, returns, mask = rng.normal(size=(12, 2)), rng.normal(size=12), (rng.random(12) > 0.3).astype(float)
    key = jax.random.key(5)
    new_critic, _, last_loss = jax.jit(critic_regression, static_argnums=6)(
        critic, critic_optimizer(config).init(critic), *(jnp.asarray(x) for x in (obs, returns, mask)), key, config
    )

    theta, unravel = ravel_pytree(critic)
    theta = np.asarray(theta)
    adam = Adam(theta.size, lr=1e-2, eps=1e-8)
    for epoch_key in jax.random.split(key, 3):
        losses = []
        for indices in np.asarray(jax.random.permutation(epoch_key, 12)).reshape(3, -1):
            layers = jax.device_get(unravel(jnp.asarray(theta)))
            loss, grads = _numpy_value_and_grad(layers, obs[indices], returns[indices], mask[indices])
            losses.append(loss)
            theta = adam.step(theta, np.asarray(ravel_pytree(grads)[0]))
    np.testing.assert_allclose(np.asarray(ravel_pytree(new_critic)[0]), theta, rtol=0, atol=1e-9)
    assert float(last_loss) == pytest.approx(np.mean(losses), rel=1e-9)
