import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from canter.algos.ppo.losses import Minibatch, normalize_advantages, ppo_loss
from canter.algos.ppo.sections import PPOConfig
from canter.core.netconfig import NetConfig
from canter.core.networks import init_params

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
    batch = Minibatch(
        obs=jnp.zeros((1, 2)),
        actions=jnp.ones((1, 1)),
        log_probs=jnp.array([new_lp - 0.5]),
        values=jnp.array([1.0]),
        advantages=jnp.array([3.0]),
        returns=jnp.array([4.0]),
        mask=jnp.ones(1),
    )
    ppo = PPOConfig(clip=0.2, norm_adv=False, clip_vloss=True, ent_coef=0.01, vf_coef=0.5)
    loss, d = ppo_loss(params, batch, NET, ppo)
    ratio = math.exp(0.5)
    policy_loss = max(-3.0 * ratio, -3.0 * 1.2)  # = -3.6: the clipped term wins
    value_loss = 0.5 * max((2.0 - 4.0) ** 2, (1.0 + 0.2 - 4.0) ** 2)  # clipped value 1.2 -> (2.8)^2
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
    batch = Minibatch(
        jnp.zeros((B, 2)),
        jnp.asarray(actions),
        jnp.asarray(old_lp),
        jnp.asarray(old_values),
        jnp.asarray(adv),
        jnp.asarray(returns),
        jnp.asarray(mask),
    )
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
    # The diagnostics that drive target_kl early stopping average over the kept rows only.
    approx_kl = ((ratio - 1.0) - np.log(ratio)).mean()
    clip_frac = (np.abs(ratio - 1.0) > 0.2).mean()
    assert 0.0 < clip_frac < 1.0  # the kept rows include clipped and unclipped ratios
    assert float(d["approx_kl"]) == pytest.approx(approx_kl, rel=1e-4)
    assert float(d["clip_frac"]) == pytest.approx(clip_frac, rel=1e-6)

    # Garbage in the masked rows changes nothing, the old log-probs (ratio e^30 there) included.
    poisoned = batch._replace(
        advantages=batch.advantages.at[2].set(1e6),
        returns=batch.returns.at[5].set(-1e6),
        log_probs=batch.log_probs.at[2].add(-30.0).at[5].add(-30.0),
    )
    loss2, d2 = ppo_loss(params, poisoned, NET, ppo)
    assert float(loss2) == pytest.approx(float(loss), rel=1e-6)
    for name in ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_frac"):
        assert float(d2[name]) == pytest.approx(float(d[name]), rel=1e-6), name


SDS_NET = NetConfig(hidden=(4,), state_dependent_std=True)


def sds_params():
    """state_dependent_std: mean = 0.3 + tanh(obs[1]) and log std = -0.2 + tanh(obs[0]), the critic a constant 0.7."""
    params = init_params(jax.random.key(0), SDS_NET, 2, 1)
    params = jax.tree_util.tree_map(jnp.zeros_like, params)
    params["actor"][0]["w"] = jnp.eye(2, 4, dtype=jnp.float32)  # hidden = tanh(obs[0]), tanh(obs[1]), 0, 0
    params["actor"][-1]["w"] = jnp.zeros((4, 2), jnp.float32).at[1, 0].set(1.0).at[0, 1].set(1.0)
    params["actor"][-1]["b"] = jnp.array([0.3, -0.2], jnp.float32)
    params["critic"][-1]["b"] = jnp.array([0.7], jnp.float32)
    return params


@pytest.mark.parametrize("state_dependent_std", [False, True])
def test_every_diagnostic_is_a_mean_over_the_kept_rows(state_dependent_std):
    """Every term of the loss and every diagnostic (approx_kl and clip_frac drive target_kl early stopping) matches
    a numpy reference over the kept rows, while every per-row input of the masked rows is garbage. With a
    state-dependent std the per-row entropies differ, so the entropy's masking is observable too."""
    rng = np.random.default_rng(11)
    B = 12
    net = SDS_NET if state_dependent_std else NET
    params = sds_params() if state_dependent_std else constant_params(0.3, -0.2, 0.7)
    mask = np.ones(B, np.float32)
    mask[[1, 4, 9]] = 0.0
    keep = mask > 0
    obs = rng.normal(scale=0.7, size=(B, 2)).astype(np.float32)
    obs[~keep] = 5.0  # a log std of -0.2 + tanh(5) ~ 0.8 under state_dependent_std, far above the kept rows'
    if state_dependent_std:
        mean, log_std = 0.3 + np.tanh(obs[:, 1]), -0.2 + np.tanh(obs[:, 0])
    else:
        mean, log_std = np.full(B, 0.3), np.full(B, -0.2)
    actions = rng.normal(size=(B, 1)).astype(np.float32)
    actions[~keep] = 10.0
    new_lp = np.array([log_normal(a, m, s) for a, m, s in zip(actions[:, 0], mean, log_std)])
    old_lp = (new_lp + rng.normal(scale=0.3, size=B)).astype(np.float32)
    old_lp[~keep] = new_lp[~keep] - 30.0  # ratio e^30: approx_kl ~ 1e13 and clipped, were these rows counted
    adv = rng.normal(size=B).astype(np.float32)
    adv[~keep] = 1e6
    returns = rng.normal(size=B).astype(np.float32)
    returns[~keep] = -1e6
    old_values = (0.7 + rng.normal(scale=0.5, size=B)).astype(np.float32)
    old_values[~keep] = 1e3
    ppo = PPOConfig(clip=0.2, norm_adv=True, clip_vloss=True, ent_coef=0.05, vf_coef=0.5)
    batch = Minibatch(*map(jnp.asarray, (obs, actions, old_lp, old_values, adv, returns, mask)))
    loss, d = ppo_loss(params, batch, net, ppo)

    a = adv[keep]
    a = (a - a.mean()) / (a.std(ddof=1) + 1e-8)
    log_ratio = new_lp[keep] - old_lp[keep]
    ratio = np.exp(log_ratio)
    pg = np.maximum(-a * ratio, -a * np.clip(ratio, 0.8, 1.2)).mean()
    v_old, ret = old_values[keep], returns[keep]
    v_clipped = v_old + np.clip(0.7 - v_old, -0.2, 0.2)
    vl = 0.5 * np.maximum((0.7 - ret) ** 2, (v_clipped - ret) ** 2).mean()
    entropy = (log_std[keep] + 0.5 * (1.0 + math.log(2 * math.pi))).mean()
    approx_kl = ((ratio - 1.0) - log_ratio).mean()
    clip_frac = (np.abs(ratio - 1.0) > 0.2).mean()
    assert 0.0 < clip_frac < 1.0
    assert float(d["policy_loss"]) == pytest.approx(pg, rel=1e-4)
    assert float(d["value_loss"]) == pytest.approx(vl, rel=1e-5)
    assert float(d["entropy"]) == pytest.approx(entropy, rel=1e-5)
    assert float(d["approx_kl"]) == pytest.approx(approx_kl, rel=1e-4)
    assert float(d["clip_frac"]) == pytest.approx(clip_frac, rel=1e-6)
    assert float(loss) == pytest.approx(pg - 0.05 * entropy + 0.5 * vl, rel=1e-4)


def test_advantage_normalization_uses_valid_entries_only():
    adv = jnp.array([1.0, 2.0, 3.0, 100.0])
    out = normalize_advantages(adv, jnp.array([1.0, 1.0, 1.0, 0.0]))
    np.testing.assert_allclose(np.asarray(out[:3]), [-1.0, 0.0, 1.0], atol=1e-6)


# ----------------------------------------------------------------------------------- variants: rpo, kl_penalty, sym

from canter.algos.ppo.losses import LossVariant, gaussian_kl, rpo_shift  # noqa: E402
from canter.algos.ppo.symmetry import parse_groups  # noqa: E402


def vector_params(means, log_stds, value=0.0):
    """Zero weights: constant per-dimension means and log stds, obs_dim 2."""
    params = init_params(jax.random.key(0), NET, 2, len(means))
    params = jax.tree_util.tree_map(jnp.zeros_like, params)
    params["actor"][-1]["b"] = jnp.asarray(means, jnp.float32)
    params["critic"][-1]["b"] = jnp.array([value], jnp.float32)
    params["log_std"] = jnp.asarray(log_stds, jnp.float32)
    return params


def one_sample(actions, old_log_prob, advantage=1.0):
    n = 1
    return Minibatch(
        obs=jnp.zeros((n, 2), jnp.float32),
        actions=jnp.asarray([actions], jnp.float32),
        log_probs=jnp.array([old_log_prob], jnp.float32),
        values=jnp.zeros(n),
        advantages=jnp.array([advantage]),
        returns=jnp.zeros(n),
        mask=jnp.ones(n),
    )


PLAIN = PPOConfig(clip=0.2, norm_adv=False, clip_vloss=False, ent_coef=0.0, vf_coef=0.0)


def test_rpo_shift_is_uniform_within_alpha():
    z = np.asarray(rpo_shift(jax.random.key(1), jnp.zeros((20000, 3)), 0.5))
    assert z.min() < -0.49 and z.max() > 0.49  # the draws reach both ends of [-alpha, alpha]
    # The shift is added to the mean: another mean, the same draws.
    shifted = np.asarray(rpo_shift(jax.random.key(1), jnp.full((20000, 3), 3.0), 0.5))
    np.testing.assert_allclose(shifted - 3.0, z, atol=1e-6)
    assert abs(z.mean()) < 0.01 and z.var() == pytest.approx(0.25 / 3, rel=0.03)
    # Independent per dimension.
    assert abs(np.corrcoef(z[:, 0], z[:, 1])[0, 1]) < 0.03


def test_rpo_loss_evaluates_the_stored_action_under_the_shifted_mean():
    params = vector_params([0.2, -0.1], [0.0, -0.5])
    action = [0.7, 0.3]
    old_lp = log_normal(0.7, 0.2, 0.0) + log_normal(0.3, -0.1, -0.5)
    batch = one_sample(action, old_lp, advantage=2.0)
    key = jax.random.key(5)
    _loss, d = ppo_loss(params, batch, NET, PLAIN, LossVariant(rpo_alpha=0.5), key)
    z = np.asarray(jax.random.uniform(key, (1, 2), jnp.float32, -0.5, 0.5))[0]  # the draw rpo_shift makes
    new_lp = log_normal(0.7, 0.2 + z[0], 0.0) + log_normal(0.3, -0.1 + z[1], -0.5)
    ratio = math.exp(new_lp - old_lp)
    assert float(d["policy_loss"]) == pytest.approx(max(-2.0 * ratio, -2.0 * min(max(ratio, 0.8), 1.2)), rel=1e-5)
    assert float(d["approx_kl"]) == pytest.approx((ratio - 1) - math.log(ratio), rel=1e-4)
    # alpha = 0 is exactly PPO.
    ppo_value, _ = ppo_loss(params, batch, NET, PLAIN)
    rpo_zero, _ = ppo_loss(params, batch, NET, PLAIN, LossVariant(rpo_alpha=0.0), key)
    assert float(rpo_zero) == float(ppo_value) == pytest.approx(-2.0, rel=1e-6)


def test_gaussian_kl_closed_form():
    def kl_1d(mp, lp, mq, lq):
        return lq - lp + (math.exp(2 * lp) + (mp - mq) ** 2) / (2 * math.exp(2 * lq)) - 0.5

    got = float(
        gaussian_kl(jnp.array([0.5, -1.0]), jnp.array([-0.3, 0.2]), jnp.array([0.0, 0.4]), jnp.array([0.0, -0.1]))
    )
    assert got == pytest.approx(kl_1d(0.5, -0.3, 0.0, 0.0) + kl_1d(-1.0, 0.2, 0.4, -0.1), rel=1e-6)
    assert float(gaussian_kl(jnp.ones(3), jnp.zeros(3), jnp.ones(3), jnp.zeros(3))) == 0.0


def test_kl_penalty_objective_by_hand():
    # New policy N(0, 1); old policy N(0.5, e^-0.3); stored action 1.0 with its old log-prob; beta 3.
    params = vector_params([0.0], [0.0])
    old_lp = log_normal(1.0, 0.5, -0.3)
    batch = one_sample([1.0], old_lp, advantage=1.5)._replace(
        old_mean=jnp.array([[0.5]]), old_log_std=jnp.array([[-0.3]])
    )
    ppo = PPOConfig(clip=0.2, norm_adv=False, clip_vloss=False, ent_coef=0.0, vf_coef=0.0, objective="kl_penalty")
    loss, d = ppo_loss(params, batch, NET, ppo, LossVariant(kl_penalty=True), None, 3.0)
    ratio = math.exp(log_normal(1.0, 0.0, 0.0) - old_lp)
    kl = 0.0 + 0.3 + (math.exp(-0.6) + 0.25) / 2 - 0.5
    assert float(d["policy_loss"]) == pytest.approx(-1.5 * ratio + 3.0 * kl, rel=1e-5)  # no clipping
    assert float(loss) == pytest.approx(-1.5 * ratio + 3.0 * kl, rel=1e-5)


@pytest.mark.parametrize("compare", ["mean", "log_prob"])
def test_symmetric_term_is_added_and_logged(compare):
    pairs = parse_groups("0=1,2=3", negate=(3,))
    variant = LossVariant(sym_coef=0.1, sym_pairs=pairs, sym_compare=compare)
    # Mirrored policy (mean 0.3 on both legs of pair 1; +-0.2 on pair 2, whose right joint is negated) and mirrored
    # action: the term is zero.
    mirrored = vector_params([0.3, 0.3, 0.2, -0.2], [-0.5, -0.5, 0.1, 0.1])
    action = [0.6, 0.6, 0.0, 0.0]
    batch = one_sample(action, 0.0)
    base, _ = ppo_loss(mirrored, batch, NET, PLAIN)
    loss, d = ppo_loss(mirrored, batch, NET, PLAIN, variant)
    assert float(d["sym_loss"]) == pytest.approx(0.0, abs=1e-7) and float(loss) == pytest.approx(float(base))
    # Break the symmetry of pair 1 only; the term is the hand value and enters the loss with its coefficient.
    lopsided = vector_params([0.3, -0.1, 0.2, -0.2], [-0.5, -0.5, 0.1, 0.1])
    base, _ = ppo_loss(lopsided, batch, NET, PLAIN)
    loss, d = ppo_loss(lopsided, batch, NET, PLAIN, variant)
    if compare == "mean":
        expected = ((0.3 - (-0.1)) ** 2 + 0.0) / 2
    else:
        per_dim = [log_normal(0.6, 0.3, -0.5), log_normal(0.6, -0.1, -0.5)]
        expected = ((per_dim[0] - per_dim[1]) ** 2 + 0.0) / 2
    assert float(d["sym_loss"]) == pytest.approx(expected, rel=1e-5)
    assert float(loss) == pytest.approx(float(base) + 0.1 * expected, rel=1e-5)
