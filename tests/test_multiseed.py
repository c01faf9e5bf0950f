"""Several seeds in one vmapped program (canter.training.seedgroup, trainer.train_seeds): the env split, seed-for-seed
equality with single-seed runs (seed 1 of [0, 1, 2] against seed 1 alone), the run folders, group resume,
signals and the --seeds flag.

Tolerance. A seed trained in a group runs the same operations as alone, but XLA compiles the vmapped program with
batched matmuls and reductions, so sums may be reassociated. Measured on exactly these tiny runs (seed 1 in
[0, 1, 2] on Hopper-v5 via EnvPool, 9 iterations; seed 1 in [2, 1] on InvertedPendulum-v5 via Gymnasium, 5
iterations): step counts, episode counts and episodic returns are identical, the loss columns and explained
variance differ by at most 3.6e-7 absolute, and the final parameters by at most 6e-8 (another seed's parameters
differ by about 1.3). The test allows 1e-5 absolute on losses and parameters and 1e-5 relative on returns: about
30x the measured drift, and about 100,000x smaller than the difference between two seeds. See docs/multiseed.md
for what happens on long runs.
"""

import csv
import json
import os
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import canter
from canter.cli.main import main
from canter.config.build import build_config
from canter.envs.base import StepOutput
from canter.errors import CanterError
from canter.training.loop import resume_seeds, train, train_seeds
from canter.training.restore import load_state
from canter.training.resume import resume_config
from canter.training.run_folder import read_config
from canter.training.seedgroup import group_step, split_first_obs, stack, unstack
from conftest import TINY
from signals import sigterm_once_logging

ATOL = 1e-5  # losses and parameters
RTOL = 1e-5  # episodic returns
LOSSES = ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_frac", "explained_variance")
SMALL = TINY + [
    "env.num_envs=4",
    "ppo.n_steps=64",
    "ppo.minibatch_size=64",
    "ppo.epochs=2",
    "run.checkpoint_every=1024",
]


def _config(out, env="Hopper-v5", total=2048, extra=(), seed=None):
    return build_config(env, total_steps=total, seed=seed, sets=SMALL + [f"run.out_dir={out}"] + list(extra))


def _rows(run_dir):
    with open(run_dir / "metrics.csv") as f:
        return list(csv.DictReader(f))


def _column(rows, name):
    return np.array([float(r[name]) if r[name] else np.nan for r in rows])


def _params(run_dir):
    return jax.tree_util.tree_leaves(load_state(run_dir)[2].params)


def _max_param_difference(a, b):
    return max(float(np.max(np.abs(np.asarray(x, np.float64) - np.asarray(y, np.float64)))) for x, y in zip(a, b))


def _assert_same_curve(alone_dir, grouped_dir):
    alone, grouped = _rows(alone_dir), _rows(grouped_dir)
    assert len(alone) == len(grouped) > 1
    for name in ("global_step", "iteration", "episodes"):
        assert np.array_equal(_column(alone, name), _column(grouped, name)), name
    np.testing.assert_allclose(_column(grouped, "episodic_return"), _column(alone, "episodic_return"), rtol=RTOL)
    for name in LOSSES:
        np.testing.assert_allclose(_column(grouped, name), _column(alone, name), rtol=0, atol=ATOL, err_msg=name)
    assert _max_param_difference(_params(alone_dir), _params(grouped_dir)) <= ATOL


# ------------------------------------------------------------------------------------------ the env split, alone


def _slot_env(num_slots):
    """A fake env whose every output names the slot it came from, so a wrong split is visible."""
    slots = jnp.arange(num_slots, dtype=jnp.float32)

    def step(counter, action):
        assert action.shape[0] == num_slots
        obs = jnp.stack([slots, action[:, 0], jnp.broadcast_to(counter.astype(jnp.float32), (num_slots,))], axis=1)
        out = StepOutput(obs, action.sum(axis=1) * 10 + slots, slots % 2 == 0, slots > 100, {"x": slots * 2})
        return counter + 1, out

    return step


def test_group_step_splits_one_env_seed_major_under_jit_and_scan():
    seeds, per = 3, 2
    step = group_step(_slot_env(seeds * per), seeds)

    def rollout(counter, action):
        def body(c, _):
            c, out = step(c, action)
            return c, out

        return jax.lax.scan(body, counter, None, length=4)

    counters = stack([jnp.int32(0)] * seeds)
    actions = jnp.arange(seeds * per * 2, dtype=jnp.float32).reshape(seeds, per, 2)
    counter, outs = jax.jit(jax.vmap(rollout))(counters, actions)
    assert counter.tolist() == [4] * seeds  # the shared handle advanced once per step, not once per seed
    for s in range(seeds):
        for i in range(per):
            slot = s * per + i
            assert outs.obs[s, :, i, 0].tolist() == [slot] * 4
            assert outs.obs[s, :, i, 1].tolist() == [float(actions[s, i, 0])] * 4
            assert outs.obs[s, :, i, 2].tolist() == [0, 1, 2, 3]
            assert outs.reward[s, 0, i] == pytest.approx(float(actions[s, i].sum()) * 10 + slot)
            assert bool(outs.terminated[s, 0, i]) == (slot % 2 == 0)
            assert float(outs.info["x"][s, 0, i]) == 2 * slot
    # An action that does not depend on the seed is broadcast to every seed's slots.
    _, out = jax.jit(jax.vmap(lambda c: step(c, jnp.ones((per, 2)))))(counters)
    assert out.obs[:, :, 0].tolist() == [[0, 1], [2, 3], [4, 5]]
    with pytest.raises(ValueError, match="built for 3 seeds"):
        jax.vmap(lambda c: step(c, jnp.ones((per, 2))))(stack([jnp.int32(0)] * 2))


def test_stack_unstack_and_first_obs_split():
    trees = [{"a": np.full((2,), i), "b": (np.int32(i),)} for i in range(3)]
    stacked = stack(trees)
    assert stacked["a"].shape == (3, 2)
    assert unstack(stacked, 2)["a"].tolist() == [2, 2] and int(unstack(stacked, 1)["b"][0]) == 1
    blocks = split_first_obs(np.arange(12).reshape(6, 2), 3)
    assert [b.tolist() for b in blocks] == [[[0, 1], [2, 3]], [[4, 5], [6, 7]], [[8, 9], [10, 11]]]


# ---------------------------------------------------------------------------------------- seeds in a group


@pytest.fixture(scope="module")
def hopper_group(tmp_path_factory):
    out = tmp_path_factory.mktemp("group")
    cwd = os.getcwd()
    os.chdir(out)  # MuJoCo's log file
    try:
        # With EnvPool's default of one pool per core (2 here), seed 1's slots 4..7 straddle the two pools.
        grouped = train_seeds(_config(out / "group"), [0, 1, 2])
        alone = train(_config(out / "alone", seed=1))
    finally:
        os.chdir(cwd)
    return grouped, alone


@pytest.mark.slow
def test_a_seed_in_a_group_follows_its_single_seed_curve(hopper_group):
    grouped, alone = hopper_group
    assert grouped[1].global_step == alone.global_step and grouped[1].episodes == alone.episodes
    assert grouped[1].recent_return == pytest.approx(alone.recent_return, rel=RTOL)
    _assert_same_curve(alone.run_dir, grouped[1].run_dir)
    # The other seed is a different run, far outside the tolerance: the comparison above can fail.
    assert _max_param_difference(_params(alone.run_dir), _params(grouped[0].run_dir)) > 1e3 * ATOL


@pytest.mark.slow
def test_every_seed_of_a_group_writes_a_valid_run_folder(hopper_group):
    grouped, _ = hopper_group
    assert [r.run_dir.name.split("__")[3] for r in grouped] == ["s0", "s1", "s2"]
    for seed, result in enumerate(grouped):
        run = result.run_dir
        for name in ("config.toml", "versions.json", "metrics.csv", "summary.json"):
            assert (run / name).is_file(), name
        assert read_config(run).run.seed == seed
        assert result.stop_reason == "budget" and result.global_step >= 2048
        config, _, state, header = load_state(run)
        assert config.run.seed == seed and int(header["global_step"]) == result.global_step
        assert int(state.global_step) == result.global_step
        assert len(list((run / "checkpoints").glob("ckpt_*.npz"))) >= 2  # checkpoint_every and the final one
        policy = canter.load(run)
        action = policy(np.zeros((2, policy.obs_dim), np.float32))
        assert action.shape == (2, policy.act_dim) and np.isfinite(action).all()


@pytest.mark.slow
def test_a_group_resumes_together_like_each_folder_alone(hopper_group, tmp_path, capsys):
    grouped, _ = hopper_group
    folders = [tmp_path / f"s{i}" for i in range(2)]
    for result, folder in zip(grouped, folders):
        shutil.copytree(result.run_dir, folder)
    alone_copy = tmp_path / "alone_s1"
    shutil.copytree(grouped[1].run_dir, alone_copy)

    resumed = canter.resume_seeds(folders, 3072)  # the public API's, which keeps the saved return target
    alone = train(resume_config(alone_copy, 3072), resume=alone_copy)
    assert [r.run_dir for r in resumed] == folders and all(r.global_step >= 3072 for r in resumed)
    assert resumed[1].global_step == alone.global_step
    _assert_same_curve(alone_copy, folders[1])

    # A seed that already has the budget (it finished before a signal stopped the others) is left out, with a note.
    train(resume_config(folders[0], 4096), resume=folders[0])
    capsys.readouterr()
    [only] = resume_seeds(folders, 4096)
    assert only.run_dir == folders[1] and only.global_step >= 4096
    assert (
        f"canter: note: {folders[0]} already has its run.total_steps; the others resume without it"
        in capsys.readouterr().err
    )
    with pytest.raises(
        CanterError,
        match=r"s0 already has \d+ of run.total_steps=4096 steps; pass a --total-steps \(total_steps= from Python\) "
        r"larger",
    ):
        resume_seeds(folders, 4096)

    with pytest.raises(CanterError, match="repeated seeds"):
        resume_seeds([folders[0], folders[0]], 4096)
    (alone_copy / "config.toml").write_text(
        (alone_copy / "config.toml").read_text().replace("gamma = 0.99", "gamma = 0.9")
    )
    with pytest.raises(CanterError, match=r"differs .* in more than run.seed"):
        resume_seeds([folders[0], alone_copy], 4096)


@pytest.mark.slow
def test_gymnasium_backend_group_matches_alone(tmp_path):
    extra = ["env.backend=gymnasium"]
    grouped = train_seeds(_config(tmp_path / "g", "InvertedPendulum-v5", 1024, extra), [2, 1])
    alone = train(_config(tmp_path / "a", "InvertedPendulum-v5", 1024, extra, seed=1))
    _assert_same_curve(alone.run_dir, grouped[1].run_dir)


@pytest.mark.slow
def test_sigterm_stops_every_seed_with_a_checkpoint(tmp_path):
    with sigterm_once_logging(tmp_path, runs=3):
        results = train_seeds(_config(tmp_path, "InvertedPendulum-v5", 10_000_000), [0, 1, 2])
    assert [r.stop_reason for r in results] == ["signal"] * 3
    for r in results:
        _, _, _, header = load_state(r.run_dir)
        assert int(header["global_step"]) == r.global_step < 10_000_000
        # Each seed's summary names the group it trained in: bench adds the rates of such seeds only.
        assert json.loads((r.run_dir / "summary.json").read_text())["trained_with"] == [0, 1, 2]


@pytest.mark.slow
def test_non_finite_seeds_stop_with_their_last_good_checkpoint(tmp_path):
    config = _config(
        tmp_path, "canter_test_envs:NaNAfter-v0", 50_000, ["env.num_envs=1", "ppo.n_steps=128", "ppo.minibatch_size=64"]
    )
    with pytest.raises(CanterError, match=r"seed 0: non-finite .* after step \d+.*; seed 1: non-finite"):
        train_seeds(config, [0, 1])
    folders = sorted(tmp_path.iterdir())
    assert len(folders) == 2
    for folder in folders:
        _, _, state, _ = load_state(folder)
        assert all(np.isfinite(np.asarray(x)).all() for x in jax.tree_util.tree_leaves(state.params))
        assert not (folder / "summary.json").exists()


def test_group_step_keeps_non_finite_actions_out_of_the_env():
    seen = []

    def env_step(counter, action):
        seen.append(action)
        return counter, StepOutput(action[:, :1], action[:, 0], action[:, 0] > 0, action[:, 0] > 0, {})

    step = group_step(env_step, 2)
    actions = jnp.array([[[jnp.nan, 1.0]], [[0.5, -2.0]]])
    _, out = jax.vmap(step)(stack([jnp.int32(0)] * 2), actions)
    assert out.obs.tolist() == [[[0.0]], [[0.5]]] and out.reward.tolist() == [[0.0], [0.5]]


def test_bad_seed_lists_are_refused(tmp_path):
    config = _config(tmp_path)
    with pytest.raises(CanterError, match="no seeds"):
        train_seeds(config, [])
    with pytest.raises(CanterError, match="repeat"):
        train_seeds(config, [3, 3])
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--seeds", "0,x"], "expected whole numbers separated by commas"),
        (["--seeds", "1,2,1"], "each seed may appear once"),
        (["--seeds", ""], "expected whole numbers"),
        (["--seeds", "0,1", "--seed", "3"], "--seed and --seeds exclude each other"),
        (["--resume", "a", "b", "--seeds", "0,1"], "only --total-steps, --max-minutes, --stop-at-return, --quiet,"),
    ],
)
def test_bad_seeds_flag_is_a_one_line_error(argv, message, capsys):
    assert (
        main(["train", "Hopper-v5", "--total-steps", "1000"] + argv if argv[0] != "--resume" else ["train"] + argv) == 2
    )
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("canter: error:") and message in err


@pytest.mark.slow
def test_cli_seeds_trains_a_group(tmp_path, capsys):
    code = main(
        [
            "train",
            "Pendulum-v1",
            "--seeds",
            "4,5",
            "--total-steps",
            "512",
            "--quiet",
            "--out-dir",
            str(tmp_path),
            "--set",
            "env.num_envs=4",
            "--set",
            "ppo.n_steps=64",
            "--set",
            "ppo.minibatch_size=64",
            "--set",
            "ppo.epochs=1",
            "--set",
            "net.hidden=8",
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert out.count("run: ") == 2
    folders = sorted(tmp_path.iterdir())
    assert [read_config(f).run.seed for f in folders] == [4, 5]
