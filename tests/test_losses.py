import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from canter.algos.ppo.losses import Minibatch, normalize_advantages, ppo_loss
from canter.config import NetConfig, PPOConfig
from canter.networks import init_params

NET = NetConfig(hidden=(4,))


def constant_params(mean: float, log_std: float, value: float):
    """Zero weights: the actor outputs `mean` and the critic `value` for every observation."""
    params = init_params(jax.random.key(0), NET, 2, 1)
    params = jax.tree_util.tree_map(jnp.zeros_like, params)
    params["actor"][-1]["b"] = jnp.array([mean], jnp.float32)
    params["critic"][-1]["b"] = jnp.array([value], jnp.float32)
    params["log_std"] = jnp.array([log_std], jnp.float32)
    return params


def log_normal(x, mu, log_sigma):
    return -0.5 * ((x - mu) / math.exp(log_sigma)) ** 2 - log_sigma - 0.5 * math.log(2 * math.pi)


def test_single_sample_by_hand():
    # mean 0, log std 0 -> log pi(a=1) = -0.5 - 0.5 log 2 pi; old log prob chosen so that ratio = e^0.5 > 1 + clip.
    params = constant_params(0.0, 0.0, 2.0)
    new_lp = log_normal(1.0, 0.0, 0.0)
    batch = Minibatch(obs=jnp.zeros((1, 2)), actions=jnp.ones((1, 1)), log_probs=jnp.array([new_lp - 0.5]),
                      values=jnp.array([1.0]), advantages=jnp.array([3.0]), returns=jnp.array([4.0]),
                      mask=jnp.ones(1))
    ppo = PPOConfig(clip=0.2, norm_adv=False, clip_vloss=True, ent_coef=0.01, vf_coef=0.5)
    loss, d = ppo_loss(params, batch, NET, ppo)
    ratio = math.exp(0.5)
    policy_loss = max(-3.0 * ratio, -3.0 * 1.2)              # = -3.6: the clipped term wins
    value_loss = 0.5 * max((2.0 - 4.0) ** 2, (1.0 + 0.2 - 4.0) ** 2)   # clipped value 1.2 -> (2.8)^2
    entropy = 0.5 * (1 + math.log(2 * math.pi))
    assert float(d["policy_loss"]) == pytest.approx(policy_loss, rel=1e-5)
    assert float(d["value_loss"]) == pytest.approx(value_loss, rel=1e-5)
    assert float(d["entropy"]) == pytest.approx(entropy, rel=1e-5)
    assert float(loss) == pytest.approx(policy_loss - 0.01 * entropy + 0.5 * value_loss, rel=1e-5)
    assert float(d["approx_kl"]) == pytest.approx((ratio - 1) - 0.5, rel=1e-5)
    assert float(d["clip_frac"]) == 1.0


def test_batch_matches_numpy_reference_and_ignores_masked_rows():
    rng = np.random.default_rng(3)
    B = 9
    params = constant_params(0.3, -0.2, 0.7)
    actions = rng.normal(size=(B, 1)).astype(np.float32)
    new_lp = np.array([log_normal(a, 0.3, -0.2) for a in actions[:, 0]])
    old_lp = (new_lp + rng.normal(scale=0.3, size=B)).astype(np.float32)
    adv = rng.normal(size=B).astype(np.float32)
    returns = rng.normal(size=B).astype(np.float32)
    old_values = rng.normal(size=B).astype(np.float32)
    mask = np.ones(B, np.float32)
    mask[[2, 5]] = 0.0
    ppo = PPOConfig(clip=0.2, norm_adv=True, clip_vloss=False, ent_coef=0.0, vf_coef=0.5)
    batch = Minibatch(jnp.zeros((B, 2)), jnp.asarray(actions), jnp.asarray(old_lp), jnp.asarray(old_values),
                      jnp.asarray(adv), jnp.asarray(returns), jnp.asarray(mask))
    loss, d = ppo_loss(params, batch, NET, ppo)

    keep = mask > 0
    a = adv[keep]
    a = (a - a.mean()) / (a.std(ddof=1) + 1e-8)
    ratio = np.exp(new_lp[keep] - old_lp[keep])
    pg = np.maximum(-a * ratio, -a * np.clip(ratio, 0.8, 1.2)).mean()
    vl = 0.5 * ((0.7 - returns[keep]) ** 2).mean()
    assert float(d["policy_loss"]) == pytest.approx(pg, rel=1e-4)
    assert float(d["value_loss"]) == pytest.approx(vl, rel=1e-5)
    assert float(loss) == pytest.approx(pg + 0.5 * vl, rel=1e-4)

    # Garbage in the masked rows changes nothing.
    poisoned = batch._replace(advantages=batch.advantages.at[2].set(1e6), returns=batch.returns.at[5].set(-1e6))
    loss2, _ = ppo_loss(params, poisoned, NET, ppo)
    assert float(loss2) == pytest.approx(float(loss), rel=1e-6)


def test_advantage_normalization_uses_valid_entries_only():
    adv = jnp.array([1.0, 2.0, 3.0, 100.0])
    out = normalize_advantages(adv, jnp.array([1.0, 1.0, 1.0, 0.0]))
    np.testing.assert_allclose(np.asarray(out[:3]), [-1.0, 0.0, 1.0], atol=1e-6)
