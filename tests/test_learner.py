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
