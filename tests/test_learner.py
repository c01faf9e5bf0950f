import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from canter.algos.ppo.learner import KL_BETA_MAX, KL_BETA_MIN, adapt_kl_beta, make_optimizer, ppo_update
from canter.algos.ppo.losses import LossVariant, Minibatch, ppo_loss
from canter.config.build import build_config
from canter.core.networks import init_params
from numpy_references import Adam, clip_by_global_norm, gaussian_kl, mlp


@pytest.mark.parametrize(
    "kl, expected",
    [
        (0.0066, 0.5),  # < 0.01 / 1.5 = 0.00667: halve
        (0.0067, 1.0),  # inside [d/1.5, 1.5 d]: keep
        (0.015, 1.0),
        (0.0151, 2.0),  # > 1.5 d: double
    ],
)
def test_adaptive_kl_rule_of_the_ppo_paper(kl, expected):
    assert float(adapt_kl_beta(jnp.float32(1.0), jnp.float32(kl), 0.01)) == expected


def test_beta_stays_recoverable():
    assert float(adapt_kl_beta(jnp.float32(KL_BETA_MIN), jnp.float32(0.0), 0.01)) == pytest.approx(KL_BETA_MIN)
    assert float(adapt_kl_beta(jnp.float32(KL_BETA_MAX), jnp.float32(1.0), 0.01)) == pytest.approx(KL_BETA_MAX)


def _random_batch(size, seed=0):
    rng = np.random.default_rng(seed)
    return Minibatch(
        obs=jnp.asarray(rng.normal(size=(size, 4)), jnp.float32),
        actions=jnp.asarray(rng.normal(size=(size, 1)), jnp.float32),
        log_probs=jnp.asarray(rng.normal(size=size) - 1.0, jnp.float32),
        values=jnp.asarray(rng.normal(size=size), jnp.float32),
        advantages=jnp.asarray(rng.normal(size=size), jnp.float32),
        returns=jnp.asarray(rng.normal(size=size) * 5.0, jnp.float32),
        mask=jnp.asarray(rng.random(size) > 0.2, jnp.float32),
    )


_jit_ppo_update = jax.jit(ppo_update, static_argnames=("config",))


def numpy_ppo_update(params, batch, key, actor_lr, critic_lr, config):
    """ppo_update as a plain loop over flat float64 parameters: per epoch a permutation of the batch (drawn from
    the same keys) cut into minibatches; per minibatch the loss gradient (ppo_loss, tested by hand elsewhere), the
    global-norm clip, numpy Adam with the critic's entries at `critic_lr`; per epoch the minibatch means of the
    diagnostics, summed; after an epoch, a stop once its last minibatch's approx_kl exceeds target_kl. Returns
    (flat parameters, their unravel, diagnostics averaged over the epochs run, epochs run, each step's norm)."""
    ppo = config.ppo
    theta, unravel = ravel_pytree(params)
    theta = np.asarray(theta, np.float64)
    is_critic = np.asarray(
        ravel_pytree(
            {k: jax.tree_util.tree_map(lambda x, k=k: jnp.full_like(x, k == "critic"), v) for k, v in params.items()}
        )[0],
        bool,
    )

    @jax.jit
    def loss_and_grad(flat, indices):
        minibatch = jax.tree_util.tree_map(lambda x: x[indices], batch)
        loss = lambda p: ppo_loss(p, minibatch, config.net, ppo, LossVariant(), None, 0.0)  # noqa: E731
        (_, diag), grads = jax.value_and_grad(loss, has_aux=True)(unravel(flat))
        return diag, ravel_pytree(grads)[0]

    adam = Adam(theta.size, np.where(is_critic, critic_lr, actor_lr), eps=ppo.adam_eps)
    size = batch.mask.shape[0]
    minibatches = size // ppo.minibatch_size
    sums, epochs_run, norms = {}, 0, []
    for epoch_key in jax.random.split(key, ppo.epochs):
        order = np.asarray(jax.random.permutation(epoch_key, size)).reshape(minibatches, -1)
        steps = []
        for indices in order:
            diag, grad = jax.device_get(loss_and_grad(theta.astype(np.float32), indices))
            grad, norm = clip_by_global_norm(grad, ppo.max_grad_norm)
            theta = adam.step(theta, grad)
            steps.append({k: float(v) for k, v in diag.items()} | {"grad_norm": norm})
            norms.append(norm)
        epochs_run += 1
        for k in steps[0]:
            sums[k] = sums.get(k, 0.0) + np.mean([s[k] for s in steps])
        if ppo.target_kl is not None and steps[-1]["approx_kl"] > ppo.target_kl:
            break
    diagnostics = {k: v / epochs_run for k, v in sums.items()} | {"grad_norm_max": max(norms)}
    return theta, unravel, diagnostics, epochs_run, norms


def numpy_policy_kl(params, new_params, batch):
    """The masked mean over the batch of KL(old || new), numpy forward passes and the closed form."""
    obs, mask = np.asarray(batch.obs), np.asarray(batch.mask, np.float64)
    old = mlp(params["actor"], obs, "tanh"), np.asarray(params["log_std"], np.float64)
    new = mlp(new_params["actor"], obs, "tanh"), np.asarray(new_params["log_std"], np.float64)
    kl = gaussian_kl(old[0], np.broadcast_to(old[1], old[0].shape), new[0], np.broadcast_to(new[1], new[0].shape))
    return float(np.sum(kl * mask) / mask.sum())


@pytest.mark.parametrize(
    "target_kl, actor_lr, critic_lr, stops_early",
    [
        ("none", 3e-2, 1e-3, False),  # a critic learning rate 30 times smaller than the actor's
        (0.05, 1e-2, 5e-3, True),  # the third epoch's last approx_kl passes target_kl: 3 of 4 epochs run
    ],
)
def test_ppo_update_matches_a_numpy_loop(target_kl, actor_lr, critic_lr, stops_early):
    sets = ["env.num_envs=1", "ppo.n_steps=12", "ppo.minibatch_size=4", "ppo.epochs=4", "ppo.max_grad_norm=0.3"]
    sets += [f"ppo.target_kl={target_kl}", "net.hidden=5", "ppo.ent_coef=0.01", "ppo.adam_eps=1e-3"]
    config = build_config("InvertedPendulum-v4", seed=0, sets=sets)
    params = init_params(jax.random.key(1), config.net, 4, 1)
    params["actor"][-1]["w"] = params["actor"][-1]["w"] * 100  # means that move visibly with the observation
    batch = _random_batch(12)
    # The stored log-probabilities are the policy's own, so approx_kl starts at 0 and grows epoch by epoch.
    mean = mlp(params["actor"], np.asarray(batch.obs), "tanh")
    log_std = np.asarray(params["log_std"], np.float64)
    z = (np.asarray(batch.actions, np.float64) - mean) / np.exp(log_std)
    log_probs = np.sum(-0.5 * z**2 - log_std - 0.5 * np.log(2 * np.pi), axis=-1)
    batch = batch._replace(log_probs=jnp.asarray(log_probs, jnp.float32))
    result = _jit_ppo_update(
        params, make_optimizer(config).init(params), batch, jax.random.key(2), actor_lr, critic_lr, config
    )
    theta, unravel, expected, epochs_run, _ = numpy_ppo_update(
        params, batch, jax.random.key(2), actor_lr, critic_lr, config
    )
    assert int(result.diagnostics["epochs_run"]) == epochs_run
    assert (epochs_run < config.ppo.epochs) == stops_early
    moved = np.abs(theta - np.asarray(ravel_pytree(params)[0])).max()
    np.testing.assert_allclose(np.asarray(ravel_pytree(result.params)[0]), theta, rtol=0, atol=1e-4 * moved)
    for k, v in expected.items():
        assert float(result.diagnostics[k]) == pytest.approx(v, rel=1e-4, abs=1e-6), k
    kl = numpy_policy_kl(params, unravel(jnp.asarray(theta)), batch)
    assert kl > 1e-3 and float(result.diagnostics["policy_kl"]) == pytest.approx(kl, rel=1e-3)


def test_gradient_norms_are_those_of_each_step_before_the_clip():
    """One minibatch per epoch, two epochs: `grad_norm` is the mean and `grad_norm_max` the larger of the two
    steps' global gradient norms, computed step by step by the numpy loop above (numpy norms, numpy Adam), and the
    clip (far below them) leaves the logged norms as they were before it."""
    sets = ["env.num_envs=2", "ppo.n_steps=4", "ppo.minibatch_size=8", "ppo.epochs=2", "ppo.max_grad_norm=0.01"]
    config = build_config("InvertedPendulum-v4", seed=0, sets=sets)
    params = init_params(jax.random.key(1), config.net, 4, 1)
    batch = _random_batch(8)._replace(mask=jnp.ones(8, jnp.float32))
    result = _jit_ppo_update(params, make_optimizer(config).init(params), batch, jax.random.key(2), 3e-4, 3e-4, config)
    *_, norms = numpy_ppo_update(params, batch, jax.random.key(2), 3e-4, 3e-4, config)
    assert len(norms) == 2
    assert min(norms) > 100 * config.ppo.max_grad_norm  # the clip acted on both steps
    assert float(result.diagnostics["grad_norm"]) == pytest.approx(np.mean(norms), rel=1e-4)
    assert float(result.diagnostics["grad_norm_max"]) == pytest.approx(max(norms), rel=1e-4)
    assert norms[0] != pytest.approx(norms[1], rel=1e-3)  # two different steps, so mean and max are told apart
