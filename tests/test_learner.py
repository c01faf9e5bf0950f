import jax.numpy as jnp
import pytest

from canter.algos.ppo.learner import KL_BETA_MAX, KL_BETA_MIN, adapt_kl_beta


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


def test_gradient_norms_are_those_of_each_step_before_the_clip():
    """One minibatch per epoch, two epochs: `grad_norm` is the mean and `grad_norm_max` the larger of the two
    steps' global gradient norms, computed here step by step in plain Python with numpy norms, and the clip (far
    below them) leaves the logged norms as they were before it."""
    import jax
    import numpy as np
    import optax

    from canter.algos.ppo.learner import _apply_lrs, make_optimizer, ppo_update
    from canter.algos.ppo.losses import LossVariant, Minibatch, ppo_loss
    from canter.config.build import build_config
    from canter.core.networks import init_params

    sets = ["env.num_envs=2", "ppo.n_steps=4", "ppo.minibatch_size=8", "ppo.epochs=2", "ppo.max_grad_norm=0.01"]
    config = build_config("InvertedPendulum-v4", seed=0, sets=sets)
    params = init_params(jax.random.key(1), config.net, 4, 1)
    rng = np.random.default_rng(0)
    batch = Minibatch(
        obs=jnp.asarray(rng.normal(size=(8, 4)), jnp.float32),
        actions=jnp.asarray(rng.normal(size=(8, 1)), jnp.float32),
        log_probs=jnp.asarray(rng.normal(size=8) - 1.0, jnp.float32),
        values=jnp.asarray(rng.normal(size=8), jnp.float32),
        advantages=jnp.asarray(rng.normal(size=8), jnp.float32),
        returns=jnp.asarray(rng.normal(size=8) * 5.0, jnp.float32),
        mask=jnp.ones(8, jnp.float32),
    )
    optimizer = make_optimizer(config)
    result = ppo_update(params, optimizer.init(params), batch, jax.random.key(2), 3e-4, 3e-4, config)

    def numpy_norm(tree):
        return float(
            np.sqrt(sum(np.sum(np.square(np.asarray(x, np.float64))) for x in jax.tree_util.tree_leaves(tree)))
        )

    norms, state, reference = [], optimizer.init(params), params
    for _ in range(2):
        grads = jax.grad(lambda p: ppo_loss(p, batch, config.net, config.ppo, LossVariant(), None, 0.0)[0])(reference)
        norms.append(numpy_norm(grads))
        updates, state = optimizer.update(grads, state, reference)
        reference = optax.apply_updates(reference, _apply_lrs(updates, 3e-4, 3e-4))
    assert min(norms) > 100 * config.ppo.max_grad_norm  # the clip acted on both steps
    assert float(result.diagnostics["grad_norm"]) == pytest.approx(np.mean(norms), rel=1e-4)
    assert float(result.diagnostics["grad_norm_max"]) == pytest.approx(max(norms), rel=1e-4)
    assert norms[0] != pytest.approx(norms[1], rel=1e-3)  # two different steps, so mean and max are told apart
