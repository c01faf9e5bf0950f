"""Evaluation: the mean matches a plain Gymnasium loop, normalizer statistics stay frozen, seed groups."""

import hashlib
import json
import shutil
from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest

from canter.cli.main import main
from canter.config.experiment import group_by_experiment
from canter.core.seeding import EVAL, env_seeds
from canter.training.checkpoint import latest
from canter.use.evaluate import evaluate
from canter.use.policy import load


def hand_loop(policy, env_id, seeds, deterministic=True):
    returns, lengths = [], []
    for seed in seeds:
        env = gym.make(env_id)
        obs, _ = env.reset(seed=int(seed))
        total, steps, done = 0.0, 0, False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(policy(obs, deterministic=deterministic))
            total += reward
            steps += 1
            done = terminated or truncated
        returns.append(total)
        lengths.append(steps)
        env.close()
    return np.array(returns), np.array(lengths)


@pytest.mark.slow
def test_eval_mean_matches_a_hand_written_gymnasium_loop(tiny_run):
    policy = load(tiny_run.run_dir)
    result = evaluate(policy, episodes=3, seed=4, backend="gymnasium")  # the run trained on EnvPool
    returns, lengths = hand_loop(policy, "Pendulum-v1", env_seeds(4, 3, EVAL))
    np.testing.assert_allclose(np.sort(result.returns), np.sort(returns), rtol=1e-5)
    assert result.mean == pytest.approx(returns.mean(), rel=1e-5)
    assert result.lengths.tolist() == lengths.tolist() == [200] * 3


@pytest.mark.slow
def test_envpool_run_on_the_gymnasium_backend_matches_the_hand_loop(tiny_hopper_run):
    policy = load(tiny_hopper_run)
    result = evaluate(policy, episodes=2, seed=0, backend="gymnasium")
    returns, lengths = hand_loop(policy, "Hopper-v5", env_seeds(0, 2, EVAL))
    np.testing.assert_allclose(np.sort(result.returns), np.sort(returns), rtol=1e-5)
    assert sorted(result.lengths.tolist()) == sorted(lengths.tolist())


@pytest.mark.slow
def test_evaluation_never_changes_the_normalizer_statistics(tiny_hopper_run):
    policy = load(tiny_hopper_run)
    before = [np.array(x, copy=True) for x in policy.obs_stats]
    assert not np.allclose(before[0], 0.0)  # trained statistics, so "unchanged" means something
    digest = hashlib.sha256(latest(tiny_hopper_run).read_bytes()).hexdigest()
    evaluate(policy, episodes=2)
    evaluate(policy, episodes=2, deterministic=False, backend="gymnasium")
    for old, new in zip(before, policy.obs_stats):
        np.testing.assert_array_equal(old, np.asarray(new))
    assert hashlib.sha256(latest(tiny_hopper_run).read_bytes()).hexdigest() == digest


@pytest.mark.slow
def test_stochastic_evaluation_depends_on_the_seed(tiny_run):
    policy = load(tiny_run.run_dir)
    a = evaluate(policy, episodes=2, deterministic=False, seed=1)
    b = evaluate(policy, episodes=2, deterministic=False, seed=1)
    c = evaluate(policy, episodes=2, deterministic=True, seed=1)
    d = evaluate(policy, episodes=2, deterministic=False, seed=2)
    np.testing.assert_allclose(a.returns, b.returns)
    assert not np.allclose(a.returns, c.returns) and not np.allclose(a.returns, d.returns)


@pytest.mark.slow
def test_runs_that_differ_only_in_seed_form_a_group(tiny_run):
    config = load(tiny_run.run_dir).config
    seeds = [replace(config, run=replace(config.run, seed=s, out_dir=f"o{s}")) for s in (1, 2)]
    other = config.with_values("ppo", lr=1e-3)
    assert group_by_experiment(seeds + [other, config]) == [[0, 1, 3], [2]]


@pytest.mark.slow
def test_cli_group_row_and_json(tiny_run, tmp_path, capsys):
    run = str(tiny_run.run_dir)
    twin = str(shutil.copytree(run, tmp_path / "twin"))  # a second run of the same config: a group of two
    code = main(["eval", run, twin, "--episodes", "2", "--json", str(tmp_path / "e.json")])
    out, err = capsys.readouterr()
    assert code == 0, err
    report = json.loads((tmp_path / "e.json").read_text())
    assert len(report["runs"]) == 2 and len(report["groups"]) == 1
    group = report["groups"][0]
    means = [r["return_mean"] for r in report["runs"]]
    assert group["return_mean"] == pytest.approx(np.mean(means)) and group["return_std"] == pytest.approx(np.std(means))
    assert "group:" in out and sum(line.count("±") == 2 for line in out.splitlines()) == 3
    # The label names the budget (another budget is another group), and a copy of a run is the same seed twice.
    assert group["label"] == "Pendulum-v1 ppo, budget 8,192, seeds 0,0"  # tiny_run's
    assert "are both seed 0 of one experiment" in err


@pytest.mark.slow
def test_cli_eval_on_another_env_with_matching_shapes(tiny_hopper_run, capsys):
    code = main(["eval", str(tiny_hopper_run), "--episodes", "1", "--env", "Hopper-v4"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "±" in out


def test_canter_evaluate_stays_the_function_after_the_module_is_imported():
    import canter
    import canter.use.evaluate

    assert callable(canter.evaluate) and canter.evaluate.__module__ == "canter"


def _mjx_policy(*sets):
    """What eval_physics reads of a policy: its config and the env and backend it trained on."""
    from types import SimpleNamespace

    from canter.config.build import build_config

    config = build_config("Hopper-v5", sets=["env.backend=mjx", *sets])
    return SimpleNamespace(config=config, facts=SimpleNamespace(env_id="Hopper-v5", backend="mjx"))


def test_eval_physics_are_the_runs_own_with_the_changes_over_them():
    from types import SimpleNamespace

    from canter.errors import CanterError
    from canter.use.evaluate import eval_physics, parse_physics

    policy = _mjx_policy("env.solver_iterations=4", "env.solver_ls_iterations=8")
    assert eval_physics(policy, "Hopper-v5", "mjx", {}) == {"solver_iterations": 4, "solver_ls_iterations": 8}
    changes = parse_physics({"env.solver_iterations": "0", "contacts": "floor"})
    assert changes == {"solver_iterations": 0, "contacts": "floor"}
    # 0 is the XML's own, so it leaves the make arguments; the run's line-search setting stays.
    assert eval_physics(policy, "Hopper-v5", "mjx", changes) == {"solver_ls_iterations": 8, "contacts": "floor"}
    # Another env starts from its model's own physics; a CPU backend steps the XML's own model.
    assert eval_physics(policy, "Walker2d-v5", "mjx", {}) == {}
    assert eval_physics(policy, "Walker2d-v5", "mjx", {"solver_iterations": 2}) == {"solver_iterations": 2}
    assert eval_physics(policy, "Hopper-v5", "envpool", {}) == {}
    for backend in ("envpool", "auto"):
        with pytest.raises(CanterError, match=r"^env.solver_iterations applies to the mjx backend only; add --backend"):
            eval_physics(policy, "Hopper-v5", backend, {"solver_iterations": 4})
    with pytest.raises(CanterError, match=r"^env.contacts must be all or floor, got 'none'$"):
        eval_physics(policy, "Hopper-v5", "mjx", parse_physics({"env.contacts": "none"}))
    with pytest.raises(CanterError, match=r"^env.solver_iterations must be >= 0"):
        eval_physics(policy, "Hopper-v5", "mjx", parse_physics({"env.solver_iterations": "-1"}))
    with pytest.raises(CanterError, match=r"^env.solver_iterations: expected an integer, got 'four'$"):
        parse_physics({"env.solver_iterations": "four"})
    brax_run = SimpleNamespace(config=None, facts=SimpleNamespace(env_id="ant", backend="brax"))
    with pytest.raises(CanterError, match=r"^brax runs evaluate on the brax backend only, which takes no physics"):
        eval_physics(brax_run, "ant", "brax", {"solver_iterations": 4})


@pytest.mark.parametrize(
    ("sets", "message"),
    [
        (["env.num_envs=4"], "an evaluation takes the physics settings env.solver_iterations, "),
        (["run.seed=1"], "got 'run.seed'; the rest is the run's own"),
        (["solver_iterations"], "canter: error: --set expects section.key=value"),  # physics= from Python
    ],
)
def test_cli_eval_set_takes_physics_settings_only(sets, message, tmp_path, capsys):
    """Refused before any run is read, so the folder need not exist."""
    code = main(["eval", str(tmp_path / "no-run"), *[x for s in sets for x in ("--set", s)]])
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_cli_eval_set_and_vary_are_two_commands(tmp_path, capsys):
    argv = ["eval", str(tmp_path), "--vary", "gravity=0.5,1", "--set", "env.contacts=floor"]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2 and "--vary sweeps the Gymnasium env, which takes no --set" in err, err
    assert main(["eval", str(tmp_path), "--vary", "gravity=0.5,1", "--backend", "mjx"]) == 2
    assert "--vary sweeps the Gymnasium env, whose MuJoCo model it edits; drop --backend mjx" in capsys.readouterr().err
    for backend in ("gymnasium", "auto"):  # the backend it sweeps, as auto picks it (then: not a run folder)
        assert main(["eval", str(tmp_path), "--vary", "gravity=0.5,1", "--backend", backend]) == 2
        assert "drop --backend" not in capsys.readouterr().err


@pytest.mark.slow
def test_cli_eval_set_on_a_cpu_backend_names_the_backend_that_takes_it(tiny_run, capsys):
    code = main(["eval", str(tiny_run.run_dir), "--set", "env.solver_iterations=4"])
    out, err = capsys.readouterr()
    assert code == 2 and not out, out
    # Pendulum has no MJX port, so --backend mjx would only fail next.
    assert err.strip().endswith(
        "env.solver_iterations applies to the mjx backend only; Pendulum-v1 has no mjx version: drop "
        "env.solver_iterations (physics= for evaluate)"
    ), err
