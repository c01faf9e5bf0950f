"""The off-policy targets, losses, noise and single updates against hand-computed values."""

import math
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from canter.algos.offpolicy import losses, noise
from canter.algos.offpolicy.ddpg import DDPG
from canter.algos.offpolicy.networks import init_critics, q_values
from canter.algos.offpolicy.sac import SAC, SACLearner
from canter.algos.offpolicy.td3 import TD3
from canter.config.build import build_config
from canter.config.schema import Config
from canter.core.networks import mlp
from canter.core.replay import Transitions
from numpy_references import Adam


def test_td_target_takes_the_min_of_the_critics_and_stops_only_on_termination():
    reward = jnp.array([1.0, 2.0, 0.5])
    terminated = jnp.array([0.0, 1.0, 0.0])
    next_q = jnp.array([[3.0, 5.0, -1.0], [4.0, 1.0, -2.0]])
    np.testing.assert_allclose(losses.td_target(reward, terminated, next_q, 0.9), [1 + 0.9 * 3, 2.0, 0.5 - 0.9 * 2])
    # SAC's soft target adds the entropy bonus -alpha * log pi inside the bootstrap.
    bonus = jnp.array([0.1, 0.2, 0.3])
    np.testing.assert_allclose(
        losses.td_target(reward, terminated, next_q, 0.9, bonus),
        [1 + 0.9 * 3.1, 2.0, 0.5 + 0.9 * (-2 + 0.3)],
        rtol=1e-6,
    )


@pytest.mark.parametrize("critics", [1, 2, 3])
def test_the_min_over_critics_and_its_gradient_match_numpy(critics):
    q = np.random.default_rng(critics).normal(size=(critics, 5)).astype(np.float32)
    q[:, 0] = 1.5  # a tie: the gradient is shared, as jnp.min shares it
    np.testing.assert_array_equal(losses.min_over_critics(jnp.asarray(q)), q.min(axis=0))
    grad = np.asarray(jax.grad(lambda x: jnp.sum(losses.min_over_critics(x)))(jnp.asarray(q)))
    expected = (q == q.min(axis=0)).astype(np.float32)
    expected[:, 0] = 1.0 / critics
    if critics == 3:  # pairwise: the first two share half, and the third the other half
        expected[:, 0] = [0.25, 0.25, 0.5]
    np.testing.assert_allclose(grad, expected)
    np.testing.assert_allclose(grad.sum(axis=0), 1.0)


def test_target_smoothing_noise_is_clipped_then_the_action_is_clipped():
    action = jnp.array([0.9, -0.2, 0.0, -0.9])
    standard_normal = jnp.array([10.0, -10.0, 0.1, -1.0])
    out = losses.smoothed_target_action(action, standard_normal, noise_std=0.2, noise_clip=0.5)
    np.testing.assert_allclose(out, [1.0, -0.7, 0.02, -1.0], rtol=1e-6)


def test_polyak_and_critic_loss():
    target = {"w": jnp.array([1.0, 2.0])}
    online = {"w": jnp.array([3.0, -2.0])}
    np.testing.assert_allclose(losses.polyak(target, online, 0.25)["w"], [1.5, 1.0])
    np.testing.assert_allclose(losses.polyak(target, online, 1.0)["w"], [3.0, -2.0])
    q = jnp.array([[1.0, 2.0], [3.0, 4.0]])
    assert float(losses.critic_loss(q, jnp.array([1.0, 1.0]))) == pytest.approx((0 + 1) / 2 + (4 + 9) / 2)
    assert float(losses.deterministic_actor_loss(jnp.array([[1.0, 3.0]]))) == pytest.approx(-2.0)


def test_tanh_log_det_matches_the_naive_form_and_stays_finite():
    u = jnp.array([[-3.0, -0.5, 0.0, 0.7, 2.5]])
    naive = jnp.sum(jnp.log(1.0 - jnp.tanh(u) ** 2), axis=-1)
    np.testing.assert_allclose(losses.tanh_log_det_jacobian(u), naive, rtol=1e-5)
    far = losses.tanh_log_det_jacobian(jnp.array([[30.0, -30.0]]))
    assert np.isfinite(float(far[0])) and float(far[0]) == pytest.approx(2 * 2 * (math.log(2) - 30), rel=1e-6)


def test_squashed_log_prob_is_the_change_of_variables_density():
    mean, log_std = 0.3, math.log(0.8)
    u = np.linspace(-2.0, 2.5, 7)
    action, log_prob = losses.squashed_sample(
        jnp.full((7, 1), mean), jnp.full((7, 1), log_std), jnp.asarray((u - mean) / 0.8)[:, None]
    )
    # p_a(a) = p_u(u) / |da/du| with the derivative taken numerically.
    gauss = np.exp(-0.5 * ((u - mean) / 0.8) ** 2) / (0.8 * math.sqrt(2 * math.pi))
    h = 1e-4
    dadu = (np.tanh(u + h) - np.tanh(u - h)) / (2 * h)
    np.testing.assert_allclose(np.asarray(action)[:, 0], np.tanh(u), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(log_prob), np.log(gauss / dadu), rtol=1e-4, atol=1e-5)
    # And the density integrates to one over (-1, 1).
    a = np.linspace(-1 + 1e-6, 1 - 1e-6, 200_001)
    pre = np.arctanh(a)
    _, lp = losses.squashed_sample(
        jnp.full((a.size, 1), mean),
        jnp.full((a.size, 1), log_std),
        jnp.asarray((pre - mean) / 0.8, jnp.float32)[:, None],
    )
    assert np.trapezoid(np.exp(np.asarray(lp, np.float64)), a) == pytest.approx(1.0, abs=2e-3)


def test_temperature_and_sac_actor_losses():
    log_alpha = jnp.float32(0.5)
    log_prob = jnp.array([-1.0, -3.0])  # entropy estimate 2, above the target -2
    assert float(losses.temperature_loss(log_alpha, log_prob, -2.0)) == pytest.approx(-0.5 * -4.0)
    grad = float(jax.grad(losses.temperature_loss)(log_alpha, log_prob, -2.0))
    assert grad == pytest.approx(4.0)  # gradient descent lowers alpha when entropy exceeds the target
    assert float(jax.grad(losses.temperature_loss)(log_alpha, jnp.array([3.0]), -2.0)) < 0
    q = jnp.array([[1.0, 4.0], [2.0, 3.0]])
    assert float(losses.sac_actor_loss(q, log_prob, jnp.float32(0.5))) == pytest.approx(
        ((0.5 * -1 - 1) + (0.5 * -3 - 3)) / 2
    )


def test_ou_process_statistics():
    theta, sigma, dt = 1.0, 0.5, 0.1
    chains, steps = 2000, 400

    def step(x, key):
        x = noise.ou_step(x, key, theta, sigma, dt)
        return x, x

    _, xs = jax.lax.scan(step, jnp.zeros((chains,), jnp.float32), jax.random.split(jax.random.key(0), steps))
    settled = np.asarray(xs[100:])  # the process forgets its start within ~10 / (theta dt) steps
    # the discrete process at equilibrium: var = sigma^2 dt / (1 - (1 - theta dt)^2), here with 1 - theta dt = 0.9
    expected_std = sigma * math.sqrt(dt / (1 - 0.9**2))
    assert abs(settled.mean()) < 0.01
    assert settled.std() == pytest.approx(expected_std, rel=0.02)
    lag1 = np.mean(settled[1:] * settled[:-1]) / settled.var()
    assert lag1 == pytest.approx(1 - theta * dt, abs=0.01)


def test_exploration_noise_kinds():
    action = jnp.array([[0.95, 0.0]])
    ou = jnp.array([[0.2, -0.1]])
    key = jax.random.key(1)
    same, ou_same = noise.explore("none", action, ou, key, 0.1, 0.15, 0.01)
    np.testing.assert_array_equal(same, action)
    np.testing.assert_array_equal(ou_same, ou)
    noisy, _ = noise.explore("gaussian", action, ou, key, 0.1, 0.15, 0.01)
    expected = np.clip(np.asarray(action) + 0.1 * np.asarray(jax.random.normal(key, (1, 2), jnp.float32)), -1, 1)
    np.testing.assert_allclose(noisy, expected, rtol=1e-6)
    noisy, ou_next = noise.explore("ou", action, ou, key, 0.1, 0.15, 0.01)
    np.testing.assert_allclose(ou_next, noise.ou_step(ou, key, 0.15, 0.1, 0.01))
    np.testing.assert_allclose(noisy, np.clip(np.asarray(action) + np.asarray(ou_next), -1, 1))


def test_stacked_critics_equal_separate_networks():
    critics = init_critics(jax.random.key(0), 3, 2, (8,), 2)
    obs, act = jnp.ones((4, 3)), jnp.full((4, 2), 0.5)
    q = jax.jit(q_values, static_argnums=3)(critics, obs, act, "relu")
    for i in range(2):
        one = jax.tree_util.tree_map(lambda leaf, i=i: leaf[i], critics)
        np.testing.assert_allclose(q[i], mlp(one, jnp.concatenate([obs, act], -1), "relu")[:, 0], rtol=1e-6)
    assert not np.allclose(q[0], q[1])  # independent initializations


# Jitted once per learner (a frozen dataclass of its config): eager dispatch of every op (and of both lax.cond
# branches) is far slower.
_update = jax.jit(lambda learner, state, batch, key: learner.update(state, batch, key), static_argnums=0)


def _batch(key, n=8, obs_dim=3, act_dim=2):
    k = jax.random.split(key, 4)
    return Transitions(
        jax.random.normal(k[0], (n, obs_dim), jnp.float32),
        jax.random.uniform(k[1], (n, act_dim), jnp.float32, -1, 1),
        jax.random.normal(k[2], (n,), jnp.float32),
        jax.random.normal(k[3], (n, obs_dim), jnp.float32),
        jnp.zeros((n,), jnp.float32),
    )


def _changed(a, b):
    return any(not np.array_equal(x, y) for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)))


DETERMINISTIC_FIELDS = ("actor", "critics", "target_actor", "target_critics", "actor_opt", "critic_opt", "updates")
SAC_FIELDS = ("actor", "critics", "target_critics", "actor_opt", "critic_opt", "log_alpha", "alpha_opt", "updates")


@pytest.mark.parametrize(
    "make, fields, critics, actor_out",
    [
        (lambda: DDPG(replace(Config().ddpg, hidden=(8,))), DETERMINISTIC_FIELDS, 1, 2),
        (lambda: TD3(replace(Config().td3, hidden=(8,))), DETERMINISTIC_FIELDS, 2, 2),
        (lambda: SAC(replace(Config().sac, hidden=(8,)), -2.0), SAC_FIELDS, 2, 4),
    ],
)
def test_learner_states_hold_exactly_what_their_algorithm_uses(make, fields, critics, actor_out):
    state = make().init(jax.random.key(0), 3, 2)
    assert state._fields == fields
    assert all(leaf is not None for leaf in jax.tree_util.tree_leaves(state, is_leaf=lambda x: x is None))
    assert jax.tree_util.tree_leaves(state.critics)[0].shape[0] == critics
    assert state.actor[-1]["w"].shape == (8, actor_out)


def test_acting_is_deterministic_on_request_and_explores_otherwise():
    obs = jax.random.normal(jax.random.key(1), (5, 3), jnp.float32)
    key = jax.random.key(2)
    sac = SAC(replace(Config().sac, hidden=(8,)), -2.0)
    actor = sac.init(jax.random.key(0), 3, 2).actor
    from canter.algos.offpolicy.networks import deterministic_action, squashed_gaussian

    mean, log_std = squashed_gaussian(actor, obs, "relu")
    np.testing.assert_array_equal(sac.act(actor, obs, key, True), jnp.tanh(mean))
    sampled = sac.act(actor, obs, key, False)
    # A sample of the Gaussian, then tanh: with the key's standard-normal draw, tanh(mean + std * noise).
    standard_normal = np.asarray(jax.random.normal(key, (5, 2), jnp.float32))
    np.testing.assert_allclose(sampled, np.tanh(mean + np.exp(log_std) * standard_normal), rtol=1e-5, atol=1e-6)
    assert not np.allclose(sampled, jnp.tanh(mean))
    # sac explores by sampling its policy; its OU state passes through untouched.
    ou = jnp.ones((5, 2))
    explored, ou_next = sac.explore(sac.init(jax.random.key(0), 3, 2), obs, ou, key)
    np.testing.assert_array_equal(explored, sampled)
    assert ou_next is ou
    td3 = TD3(replace(Config().td3, hidden=(8,), noise="none"))
    state = td3.init(jax.random.key(0), 3, 2)
    np.testing.assert_array_equal(td3.act(state.actor, obs, key, True), deterministic_action(state.actor, obs, "relu"))
    explored, _ = td3.explore(state, obs, ou, key)
    np.testing.assert_array_equal(explored, deterministic_action(state.actor, obs, "relu"))  # noise = none
    noisy = td3.act(state.actor, obs, key, False)
    # Gaussian noise of noise_std (0.1) on the deterministic action, clipped to the box.
    np.testing.assert_allclose(noisy, np.clip(explored + 0.1 * standard_normal, -1.0, 1.0), rtol=1e-5, atol=1e-6)
    assert not np.allclose(noisy, explored)


def test_td3_delays_the_actor_and_target_updates():
    cfg = replace(Config().td3, hidden=(8,), policy_delay=2, tau=0.1)
    learner = TD3(cfg).init(jax.random.key(0), 3, 2)
    assert jax.tree_util.tree_leaves(learner.critics)[0].shape[0] == 2
    batch = _batch(jax.random.key(1))
    first, diag = _update(TD3(cfg), learner, batch, jax.random.key(2))
    # Step 0: critic, actor and targets all move; targets by exactly tau toward the new online nets.
    assert _changed(first.critics, learner.critics) and _changed(first.actor, learner.actor)
    for target, old, new in (
        (first.target_actor, learner.target_actor, first.actor),
        (first.target_critics, learner.target_critics, first.critics),
    ):
        for t, o, n in zip(*(jax.tree_util.tree_leaves(x) for x in (target, old, new))):
            np.testing.assert_allclose(t, 0.9 * np.asarray(o) + 0.1 * np.asarray(n), rtol=1e-5, atol=1e-7)
    assert np.isfinite(float(diag["actor_loss"])) and int(first.updates) == 1
    # Step 1: only the critics move.
    second, diag = _update(TD3(cfg), first, batch, jax.random.key(3))
    assert _changed(second.critics, first.critics)
    assert not _changed(second.actor, first.actor) and not _changed(second.actor_opt, first.actor_opt)
    assert not _changed(second.target_actor, first.target_actor)
    assert not _changed(second.target_critics, first.target_critics)
    assert np.isnan(float(diag["actor_loss"]))


def _flat(tree):
    """A network's parameters as one float64 numpy vector, in the order ravel_pytree gives its leaves."""
    return np.concatenate([np.ravel(np.asarray(x, np.float64)) for x in jax.tree_util.tree_leaves(tree)])


def _forward(layers, x):
    """A ReLU MLP written out, for the hand-written references."""
    for layer in layers[:-1]:
        x = jnp.maximum(x @ layer["w"] + layer["b"], 0.0)
    return x @ layers[-1]["w"] + layers[-1]["b"]


def _twin_q(unravel_critics):
    """q(critics_flat, i, obs, action): critic i of the stacked twin critics, from their flat parameters."""

    def q(critics_flat, i, obs, action):
        layers = [{"w": layer["w"][i], "b": layer["b"][i]} for layer in unravel_critics(critics_flat)]
        return _forward(layers, jnp.concatenate([obs, action], axis=-1))[:, 0]

    return q


def _twin_critic_loss(q):
    """critic_loss(critics, obs, action, y) -> (sum_i mean (Q_i - y)^2, the mean Q of both critics, the gradient)."""

    @jax.jit
    def critic_loss(critics, obs, action, y):
        def loss(critics):
            q1, q2 = q(critics, 0, obs, action), q(critics, 1, obs, action)
            return jnp.mean(jnp.square(q1 - y)) + jnp.mean(jnp.square(q2 - y)), (q1.mean() + q2.mean()) / 2

        (value, q_mean), grad = jax.value_and_grad(loss, has_aux=True)(critics)
        return value, q_mean, grad

    return critic_loss


def test_td3_updates_match_a_hand_written_td3():
    """Three td3 updates against TD3 written out here (Fujimoto et al. 2018, Algorithm 1): the target actor's action
    smoothed by the same standard-normal draw (std target_noise, clipped to noise_clip, the action to [-1, 1]), the
    target y = r + gamma (1 - terminated) min(Q1', Q2'), the critic loss sum_i mean (Q_i - y)^2, numpy Adam on each
    network (its own step count), the actor loss -mean Q1(s, mu(s)) through the critics just updated, the actor and
    the Polyak targets only on updates 0 and 2 (policy_delay 2). Gradients by jax.grad of the losses as written
    here, in float64."""
    cfg = replace(Config().td3, hidden=(8,), policy_delay=2, tau=0.05, gamma=0.9, target_noise=0.3, noise_clip=0.4)
    cfg = replace(cfg, actor_lr=1e-2, critic_lr=3e-2)
    td3 = TD3(cfg)
    state = td3.init(jax.random.key(0), 3, 2)
    # Targets that differ from the online nets, so that mixing them up would show.
    state = jax.jit(
        lambda s: s._replace(
            target_critics=jax.tree_util.tree_map(lambda x: x + 0.1 * jnp.sign(x + 0.3), s.target_critics),
            target_actor=jax.tree_util.tree_map(lambda x: x * 1.5 + 0.05, s.target_actor),
        )
    )(state)

    unravel_actor, unravel_critics = ravel_pytree(state.actor)[1], ravel_pytree(state.critics)[1]
    theta = {name: _flat(getattr(state, name)) for name in ("actor", "critics", "target_actor", "target_critics")}
    actor_adam = Adam(theta["actor"].size, cfg.actor_lr)
    critic_adam = Adam(theta["critics"].size, cfg.critic_lr)

    q = _twin_q(unravel_critics)

    def mu(actor_flat, obs):
        return jnp.tanh(_forward(unravel_actor(actor_flat), obs))

    @jax.jit
    def target(target_actor, target_critics, reward, next_obs, terminated, noise):
        next_action = jnp.clip(mu(target_actor, next_obs) + jnp.clip(0.3 * noise, -0.4, 0.4), -1.0, 1.0)
        next_q = jnp.minimum(q(target_critics, 0, next_obs, next_action), q(target_critics, 1, next_obs, next_action))
        return reward + 0.9 * (1.0 - terminated) * next_q

    critic_loss = _twin_critic_loss(q)

    @jax.jit
    @jax.value_and_grad
    def actor_loss(actor, critics, obs):
        return -jnp.mean(q(critics, 0, obs, mu(actor, obs)))

    for step in range(3):
        batch = _batch(jax.random.key(10 + step), n=16)._replace(
            terminated=(jax.random.uniform(jax.random.key(20 + step), (16,)) < 0.3).astype(jnp.float32)
        )
        key = jax.random.key(30 + step)
        state, diag = _update(td3, state, batch, key)
        obs, action, reward, next_obs, terminated = (np.asarray(x, np.float64) for x in batch)
        noise = np.asarray(jax.random.normal(key, (16, 2), jnp.float32), np.float64)
        y = target(theta["target_actor"], theta["target_critics"], reward, next_obs, terminated, noise)
        loss, q_mean, grad = critic_loss(theta["critics"], obs, action, y)
        theta["critics"] = critic_adam.step(theta["critics"], grad)
        assert float(diag["critic_loss"]) == pytest.approx(float(loss), rel=1e-5)
        assert float(diag["q_mean"]) == pytest.approx(float(q_mean), rel=1e-5)
        np.testing.assert_allclose(_flat(state.critics), theta["critics"], rtol=0, atol=1e-5)
        if step % 2 == 0:
            loss, grad = actor_loss(theta["actor"], theta["critics"], obs)
            theta["actor"] = actor_adam.step(theta["actor"], grad)
            for name in ("actor", "critics"):
                theta["target_" + name] = 0.05 * theta[name] + 0.95 * theta["target_" + name]
            assert float(diag["actor_loss"]) == pytest.approx(float(loss), rel=1e-5)
        else:
            assert np.isnan(float(diag["actor_loss"]))
        for name in ("actor", "target_actor", "target_critics"):
            got = _flat(getattr(state, name))
            np.testing.assert_allclose(got, theta[name], rtol=0, atol=1e-5, err_msg=f"{name} after update {step}")
    assert int(state.updates) == 3 and actor_adam.t == 2 and critic_adam.t == 3


def test_ddpg_has_one_critic_and_updates_the_actor_every_step():
    cfg = replace(Config().ddpg, hidden=(8,))
    learner = DDPG(cfg).init(jax.random.key(0), 3, 2)
    assert jax.tree_util.tree_leaves(learner.critics)[0].shape[0] == 1
    batch = _batch(jax.random.key(1))
    state = learner
    for i in range(2):
        new, _ = _update(DDPG(cfg), state, batch, jax.random.key(i))
        assert _changed(new.actor, state.actor) and _changed(new.target_actor, state.target_actor)
        state = new


def test_ddpg_critic_step_descends_on_the_hand_computed_target():
    """With tau = 1 the targets equal the online nets, so the critic gradient can be checked directly."""
    cfg = replace(Config().ddpg, hidden=(4,), critic_lr=1e-3, gamma=0.5)
    learner = DDPG(cfg).init(jax.random.key(0), 3, 2)
    batch = _batch(jax.random.key(1))
    from canter.algos.offpolicy.networks import deterministic_action

    next_q = q_values(
        learner.target_critics,
        batch.next_obs,
        deterministic_action(learner.target_actor, batch.next_obs, "relu"),
        "relu",
    )
    target = batch.reward + 0.5 * next_q[0]
    before = float(jnp.mean((q_values(learner.critics, batch.obs, batch.action, "relu")[0] - target) ** 2))
    new, diag = _update(DDPG(cfg), learner, batch, jax.random.key(2))
    assert float(diag["critic_loss"]) == pytest.approx(before, rel=1e-5)
    after = float(jnp.mean((q_values(new.critics, batch.obs, batch.action, "relu")[0] - target) ** 2))
    assert after < before


def test_sac_update_moves_alpha_toward_the_target_entropy():
    cfg = replace(Config().sac, hidden=(8,), alpha=0.5)
    learner = SAC(cfg, -10.0).init(jax.random.key(0), 3, 2)
    assert isinstance(learner, SACLearner) and "target_actor" not in learner._fields
    batch = _batch(jax.random.key(1))
    # A freshly initialized policy has near-maximal entropy, far above a target of -10: alpha must fall.
    new, diag = _update(SAC(cfg, -10.0), learner, batch, jax.random.key(2))
    assert float(diag["alpha"]) < 0.5 and float(new.log_alpha) < math.log(0.5)
    for t, o, n in zip(
        *(jax.tree_util.tree_leaves(x) for x in (new.target_critics, learner.target_critics, new.critics))
    ):
        np.testing.assert_allclose(t, (1 - cfg.tau) * np.asarray(o) + cfg.tau * np.asarray(n), rtol=1e-5, atol=1e-7)
    # An unreachable target entropy (+10) raises it.
    new, _ = _update(SAC(cfg, 10.0), learner, batch, jax.random.key(2))
    assert float(new.log_alpha) > math.log(0.5)
    fixed = replace(cfg, autotune=False)
    new, _ = _update(SAC(fixed, -10.0), SAC(fixed, -10.0).init(jax.random.key(0), 3, 2), batch, jax.random.key(2))
    assert float(new.log_alpha) == pytest.approx(math.log(0.5))


def test_sac_entropies_in_the_envs_action_coordinates_match_a_reference():
    from canter.algos.offpolicy import losses
    from canter.algos.offpolicy.networks import q_values, squashed_gaussian
    from canter.algos.offpolicy.sac import log_scale

    # Humanoid's 17 actions have half-range 0.4: CleanRL's log pi is the unit box's minus 17 log 0.4 = +15.58.
    env_box = replace(Config().sac, entropy_box="env")
    assert build_config("Humanoid-v5", algo="sac", preset="cleanrl").sac.entropy_box == "env"  # as CleanRL's
    assert build_config("Humanoid-v5", algo="sac").sac.entropy_box == "unit"
    assert log_scale(env_box, [-0.4] * 17, [0.4] * 17) == pytest.approx(17 * math.log(0.4))
    assert log_scale(Config().sac, [-0.4] * 17, [0.4] * 17) == 0.0
    assert log_scale(env_box, [-1.0, 0.0], [1.0, 4.0]) == pytest.approx(math.log(2.0))

    cfg = replace(env_box, hidden=(8,), alpha=0.5, gamma=0.9)
    c = 2 * math.log(0.4)
    sac = SAC(cfg, -2.0, c)
    learner = sac.init(jax.random.key(0), 3, 2)
    batch = _batch(jax.random.key(1))
    diag = _update(sac, learner, batch, jax.random.key(2))[1]
    # Reference, written out: the same draws, with log pi_env = log pi_unit - c in the soft target, the actor loss,
    # the temperature loss and the logged entropy.
    next_key, actor_key = jax.random.split(jax.random.key(2))
    mean, log_std = squashed_gaussian(learner.actor, batch.next_obs, "relu")
    next_action, next_log_prob = losses.squashed_sample(
        mean, log_std, jax.random.normal(next_key, mean.shape, jnp.float32)
    )
    next_q = jnp.min(q_values(learner.target_critics, batch.next_obs, next_action, "relu"), axis=0)
    target = batch.reward + 0.9 * (1 - batch.terminated) * (next_q - 0.5 * (next_log_prob - c))
    q = q_values(learner.critics, batch.obs, batch.action, "relu")
    np.testing.assert_allclose(diag["critic_loss"], float(jnp.mean(jnp.sum((q - target) ** 2, axis=0))), rtol=1e-5)
    mean, log_std = squashed_gaussian(learner.actor, batch.obs, "relu")
    _, log_prob = losses.squashed_sample(mean, log_std, jax.random.normal(actor_key, mean.shape, jnp.float32))
    # The entropy is logged from the actor step, whose actor has not moved yet.
    np.testing.assert_allclose(diag["entropy"], -float(jnp.mean(log_prob - c)), rtol=1e-5)
    # The unit box reads the same policy's entropy -c (1.8 nats) higher; without bootstrapping (gamma 0) nothing
    # else differs, so its temperature moves as the env box's does with the target shifted by c.
    unit_diag = _update(SAC(cfg, -2.0 - c), learner, batch, jax.random.key(2))[1]  # log_scale 0: the unit box
    np.testing.assert_allclose(unit_diag["entropy"], float(diag["entropy"]) - c, rtol=1e-5)
    myopic = replace(cfg, gamma=0.0)
    env_alpha = _update(SAC(myopic, -2.0, c), learner, batch, jax.random.key(2))[0].log_alpha
    unit_alpha = _update(SAC(myopic, -2.0 - c), learner, batch, jax.random.key(2))[0].log_alpha
    np.testing.assert_allclose(env_alpha, unit_alpha, rtol=1e-6)
    assert float(env_alpha) != float(_update(SAC(myopic, -2.0), learner, batch, jax.random.key(2))[0].log_alpha)


def test_sac_updates_match_a_hand_written_sac():
    """Three sac updates against SAC written out here (Haarnoja et al. 2018, with CleanRL's update order): the next
    action a' = tanh(u'), u' = mean + std * noise from the actor at s' (log std squashed into [-5, 2] by tanh), its
    log density log N(u'; mean, std) - sum log(1 - tanh(u')^2) - c (c the env box's log half-range), the soft target
    y = r + gamma (1 - terminated) (min(Q1', Q2')(s', a') - alpha log pi(a'|s')) of the target critics, the critic
    loss sum_i mean (Q_i - y)^2, numpy Adam on each network and on log alpha (its own step count), the Polyak target,
    then on updates 0 and 2 only (policy_delay 2) the actor loss mean(alpha log pi(a|s) - min(Q1, Q2)(s, a)) through
    the critics just updated, with alpha from before the update, and the temperature loss
    -log_alpha mean(log pi(a|s) + target entropy) of the actor's sample before its step. The noise is the standard
    normal draw of the same keys canter splits. Gradients by jax.grad of the losses as written here, in float64."""
    cfg = replace(Config().sac, hidden=(8,), policy_delay=2, tau=0.05, gamma=0.9, alpha=0.5, entropy_box="env")
    cfg = replace(cfg, actor_lr=1e-2, critic_lr=3e-2, alpha_lr=3e-2)
    c, target_entropy = 2 * math.log(0.7), -1.5
    sac = SAC(cfg, target_entropy, c)
    state = sac.init(jax.random.key(0), 3, 2)
    # Targets that differ from the online critics, so that mixing them up would show.
    state = jax.jit(
        lambda s: s._replace(
            target_critics=jax.tree_util.tree_map(lambda x: x + 0.1 * jnp.sign(x + 0.3), s.target_critics)
        )
    )(state)

    unravel_actor, unravel_critics = ravel_pytree(state.actor)[1], ravel_pytree(state.critics)[1]
    theta = {name: _flat(getattr(state, name)) for name in ("actor", "critics", "target_critics")}
    log_alpha = math.log(0.5)
    actor_adam = Adam(theta["actor"].size, cfg.actor_lr)
    critic_adam = Adam(theta["critics"].size, cfg.critic_lr)
    alpha_adam = Adam(1, cfg.alpha_lr)

    q = _twin_q(unravel_critics)

    def policy(actor_flat, obs, noise):
        """(the action tanh(u), log pi(a|s) in the env box) of u = mean + std * noise."""
        out = _forward(unravel_actor(actor_flat), obs)
        mean, log_std = out[:, :2], -5.0 + 3.5 * (jnp.tanh(out[:, 2:]) + 1.0)
        u = mean + jnp.exp(log_std) * noise
        gaussian = -0.5 * noise**2 - log_std - 0.5 * math.log(2 * math.pi)
        return jnp.tanh(u), jnp.sum(gaussian - jnp.log(1.0 - jnp.tanh(u) ** 2), axis=-1) - c

    @jax.jit
    def target(actor, target_critics, alpha, reward, next_obs, terminated, noise):
        next_action, next_log_prob = policy(actor, next_obs, noise)
        next_q = jnp.minimum(q(target_critics, 0, next_obs, next_action), q(target_critics, 1, next_obs, next_action))
        return reward + 0.9 * (1.0 - terminated) * (next_q - alpha * next_log_prob)

    critic_loss = _twin_critic_loss(q)

    @jax.jit
    def actor_loss(actor, critics, alpha, obs, noise):
        """(the loss, log pi(a|s) of the actor before its step, the gradient)"""

        def loss(actor):
            action, log_prob = policy(actor, obs, noise)
            q_pi = jnp.minimum(q(critics, 0, obs, action), q(critics, 1, obs, action))
            return jnp.mean(alpha * log_prob - q_pi), log_prob

        (value, log_prob), grad = jax.value_and_grad(loss, has_aux=True)(actor)
        return value, log_prob, grad

    for step in range(3):
        batch = _batch(jax.random.key(10 + step), n=16)._replace(
            terminated=(jax.random.uniform(jax.random.key(20 + step), (16,)) < 0.3).astype(jnp.float32)
        )
        key = jax.random.key(30 + step)
        state, diag = _update(sac, state, batch, key)
        obs, action, reward, next_obs, terminated = (np.asarray(x, np.float64) for x in batch)
        next_noise, actor_noise = (
            np.asarray(jax.random.normal(k, (16, 2), jnp.float32), np.float64) for k in jax.random.split(key)
        )
        alpha = math.exp(log_alpha)
        y = target(theta["actor"], theta["target_critics"], alpha, reward, next_obs, terminated, next_noise)
        loss, q_mean, grad = critic_loss(theta["critics"], obs, action, y)
        theta["critics"] = critic_adam.step(theta["critics"], grad)
        theta["target_critics"] = 0.05 * theta["critics"] + 0.95 * theta["target_critics"]
        assert float(diag["critic_loss"]) == pytest.approx(float(loss), rel=1e-5)
        assert float(diag["q_mean"]) == pytest.approx(float(q_mean), rel=1e-5)
        if step % 2 == 0:
            loss, log_prob, grad = actor_loss(theta["actor"], theta["critics"], alpha, obs, actor_noise)
            theta["actor"] = actor_adam.step(theta["actor"], grad)
            # d/d log_alpha of -log_alpha mean(log pi + target entropy)
            log_alpha = float(alpha_adam.step(np.array([log_alpha]), [-np.mean(log_prob + target_entropy)])[0])
            assert float(diag["actor_loss"]) == pytest.approx(float(loss), rel=1e-5)
            assert float(diag["entropy"]) == pytest.approx(-float(np.mean(log_prob)), rel=1e-5)
        else:
            assert np.isnan(float(diag["actor_loss"])) and np.isnan(float(diag["entropy"]))
        for name in ("actor", "critics", "target_critics"):
            got = _flat(getattr(state, name))
            np.testing.assert_allclose(got, theta[name], rtol=1e-5, atol=1e-6, err_msg=f"{name} after update {step}")
        assert float(state.log_alpha) == pytest.approx(log_alpha, rel=1e-5)
        assert float(diag["alpha"]) == pytest.approx(math.exp(log_alpha), rel=1e-5)
    assert int(state.updates) == 3 and actor_adam.t == alpha_adam.t == 2 and critic_adam.t == 3


def test_every_noise_the_config_accepts_has_its_function():
    from canter.algos.offpolicy.sections import NOISE_KINDS

    assert tuple(noise.NOISES) == NOISE_KINDS
