"""Learning tests on tiny tasks with fixed seeds and a score threshold."""

import numpy as np
import pytest

from canter.config.algorithms import reads_key
from canter.config.build import build_config
from canter.training.loop import train
from canter.use.evaluate import evaluate
from canter.use.policy import load

pytestmark = pytest.mark.slow

PENDULUM = ["env.num_envs=8", "ppo.n_steps=64", "ppo.minibatch_size=128", "net.hidden=32,32", "run.tensorboard=false"]


def test_inverted_pendulum_reaches_900(tmp_path):
    config = build_config(
        "InvertedPendulum-v4", seed=0, total_steps=40_000, sets=PENDULUM + [f"run.out_dir={tmp_path}"]
    )
    result = train(config)
    policy = load(result.run_dir)
    score = evaluate(policy, episodes=10, deterministic=True, seed=0)
    assert score.mean >= 900, score.returns
    # The loaded policy returns actions within the env's bounds.
    actions = policy(np.random.default_rng(0).normal(size=(64, 4)) * 100)
    assert actions.shape == (64, 1) and np.all(np.abs(actions) <= 3.0)


@pytest.mark.parametrize(
    "algo, extra",
    [
        ("rpo", []),
        ("trpo", ["trpo.critic_minibatch_size=128"]),
        ("ppo", ["ppo.objective=kl_penalty"]),
    ],
)
def test_variants_balance_the_inverted_pendulum(tmp_path, algo, extra):
    common = [item for item in PENDULUM if reads_key(algo, item.partition("=")[0])]  # trpo has no minibatches
    config = build_config(
        "InvertedPendulum-v4",
        seed=0,
        total_steps=40_000,
        algo=algo,
        sets=common + extra + [f"run.out_dir={tmp_path}", "run.checkpoint_every=0"],
    )
    result = train(config)
    score = evaluate(load(result.run_dir), episodes=5, deterministic=True, seed=0)
    assert score.mean >= 900, (algo, score.returns)
    if config.ppo.objective == "kl_penalty":
        check_kl_beta_is_adapted_and_checkpointed(result.run_dir, config)


def check_kl_beta_is_adapted_and_checkpointed(run_dir, config):
    import csv

    from canter.algos.ppo.learner import adapt_kl_beta
    from canter.training.restore import load_state

    rows = list(csv.DictReader((run_dir / "metrics.csv").open()))
    betas = [float(r["kl_beta"]) for r in rows]
    assert betas[0] == config.ppo.kl_penalty_beta and len(set(betas)) > 1
    for row, next_beta in zip(rows, betas[1:]):  # each iteration's beta follows the rule from the previous one
        expected = adapt_kl_beta(np.float32(row["kl_beta"]), np.float32(row["policy_kl"]), config.ppo.kl_penalty_target)
        assert next_beta == pytest.approx(float(expected), rel=1e-4)
    _, _, state, _ = load_state(run_dir)
    last = rows[-1]
    saved = adapt_kl_beta(np.float32(last["kl_beta"]), np.float32(last["policy_kl"]), config.ppo.kl_penalty_target)
    assert float(state.kl_beta) == pytest.approx(float(saved), rel=1e-4)
