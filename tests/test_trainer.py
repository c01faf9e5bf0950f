import json
import shutil
from dataclasses import replace

import jax
import numpy as np
import pytest

from canter.config.algorithms import reads_key
from canter.config.build import build_config
from canter.errors import CanterError
from canter.training.loop import train, train_seeds
from canter.training.restore import load_state
from canter.training.resume import resume_config
from conftest import TINY
from signals import sigterm_during_setup, sigterm_once_logging

pytestmark = pytest.mark.slow

SMALL = TINY + [
    "env.num_envs=4",
    "ppo.n_steps=256",
    "ppo.minibatch_size=256",
    "ppo.epochs=2",
    "run.checkpoint_every=2048",
]


def _config(total=4096, env="Pendulum-v1", extra=()):
    return build_config(env, total_steps=total, sets=SMALL + list(extra))


def _leaves_equal(a, b):
    return all(
        np.array_equal(np.asarray(x), np.asarray(y))
        for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b))
    )


def _resume_twice(run_dir, total, copy):
    """Resume `run_dir` and a copy of it to `total` steps; both must land on the same state bit for bit."""
    shutil.copytree(run_dir, copy)
    r1 = train(resume_config(run_dir, total), resume=run_dir)
    r2 = train(resume_config(copy, total), resume=copy)
    _, _, s1, _ = load_state(r1.run_dir)
    _, _, s2, _ = load_state(r2.run_dir)
    assert _leaves_equal(s1, s2), "two resumes of one checkpoint must be identical"
    return r1, s1


def test_run_folder_contents(tiny_run):
    run = tiny_run.run_dir
    assert run.name.startswith("Pendulum-v1__ppo__fast__s0__")
    for name in ("config.toml", "versions.json", "metrics.csv", "summary.json"):
        assert (run / name).is_file()
    header = (run / "metrics.csv").read_text().splitlines()[0].split(",")
    for column in (
        "global_step",
        "episodic_return",
        "approx_kl",
        "clip_frac",
        "grad_norm",
        "grad_norm_max",
        "explained_variance",
        "sps",
        "learning_rate",
        "policy_loss",
        "value_loss",
        "entropy",
    ):
        assert column in header
    assert tiny_run.global_step >= 8192 and tiny_run.sps > 0 and tiny_run.compile_seconds > 0


def test_same_seed_same_result(tmp_path):
    a = train(_config(extra=[f"run.out_dir={tmp_path / 'a'}"]))
    b = train(_config(extra=[f"run.out_dir={tmp_path / 'b'}"]))
    _, _, sa, _ = load_state(a.run_dir)
    _, _, sb, _ = load_state(b.run_dir)
    assert _leaves_equal(sa, sb)
    c = train(_config(extra=[f"run.out_dir={tmp_path / 'c'}", "run.seed=1"]))
    _, _, sc, _ = load_state(c.run_dir)
    assert not _leaves_equal(sa.params, sc.params)


def test_resume_is_deterministic_and_continues(tmp_path):
    first = train(_config(total=4096, extra=[f"run.out_dir={tmp_path}"]))
    _, _, before, header = load_state(first.run_dir)
    assert int(header["global_step"]) == first.global_step
    r1, s1 = _resume_twice(first.run_dir, 8192, tmp_path / "copy")
    assert r1.global_step >= 8192 and int(s1.iteration) > int(before.iteration)
    assert not _leaves_equal(s1.params, before.params)
    rows = (first.run_dir / "metrics.csv").read_text().splitlines()
    steps = [int(r.split(",")[0]) for r in rows[1:]]
    assert steps == sorted(steps) and steps[-1] == r1.global_step and len(rows) == 1 + int(s1.iteration)
    # The stretched schedule: the first resumed iteration anneals from the old step against the new total.
    resumed_row = rows[1 + int(before.iteration)].split(",")
    lr_col = rows[0].split(",").index("learning_rate")
    assert float(resumed_row[lr_col]) == pytest.approx(3e-4 * (1 - first.global_step / 8192), rel=1e-4)
    assert "total_steps = 8192" in (first.run_dir / "config.toml").read_text()

    with pytest.raises(CanterError, match="already has"):
        train(resume_config(first.run_dir, None), resume=first.run_dir)


def test_resume_after_a_hard_kill_redoes_the_lost_rows_and_keeps_whole_run_totals(tmp_path):
    import csv

    first = train(_config(total=4096, extra=[f"run.out_dir={tmp_path}", "run.tensorboard=true"]))
    run = first.run_dir
    # A kill without SIGTERM: every row was logged, but the newest checkpoint left is the periodic one.
    saved = sorted((run / "checkpoints").iterdir())
    assert len(saved) == 2
    saved[-1].unlink()
    (run / "summary.json").unlink()
    _, _, _, header = load_state(run)
    assert 2048 <= int(header["global_step"]) < first.global_step and header["totals"]["wall_seconds"] > 0

    again = train(resume_config(run, 4096), resume=run)
    with open(run / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    steps = [int(r["global_step"]) for r in rows]
    walls = [float(r["wall_time"]) for r in rows]
    assert steps == sorted(set(steps)) and steps[-1] == again.global_step >= 4096
    assert [int(r["iteration"]) for r in rows] == list(range(1, len(rows) + 1))
    assert walls == sorted(walls), "wall_time continues across the resume"
    assert again.episodes == sum(int(r["episodes"]) for r in rows)
    train_seconds = sum((b - a) / float(r["sps"]) for a, b, r in zip([0] + steps, steps, rows))
    assert again.sps == pytest.approx(again.global_step / train_seconds, rel=0.01)
    assert again.wall_seconds >= walls[-1] > header["totals"]["wall_seconds"]
    assert list((run / "tb").glob("events.out.tfevents.*"))


def test_stop_conditions(tmp_path):
    r = train(
        _config(total=100_000, extra=[f"run.out_dir={tmp_path}", "run.stop_at_return=-100000", "run.tensorboard=true"])
    )
    assert r.stop_reason == "stop_at_return" and r.global_step < 100_000
    events = list((r.run_dir / "tb").glob("events.out.tfevents.*"))
    assert events and events[0].stat().st_size > 0
    r = train(_config(total=100_000, extra=[f"run.out_dir={tmp_path}", "run.max_minutes=0.0001"]))
    assert r.stop_reason == "max_minutes" and r.global_step < 100_000
    assert any((r.run_dir / "checkpoints").iterdir())
    # The budget spent in the iteration that passes the deadline: the run is complete, not stopped early.
    r = train(_config(total=1, extra=[f"run.out_dir={tmp_path}", "run.max_minutes=0.0001"]))
    assert r.stop_reason == "budget" and r.global_step >= 1


def test_sigterm_writes_a_checkpoint_and_stops(tmp_path):
    with sigterm_once_logging(tmp_path, runs=1):
        r = train(_config(total=10_000_000, extra=[f"run.out_dir={tmp_path}"]))
    assert r.stop_reason == "signal" and r.global_step < 10_000_000
    _, _, _, header = load_state(r.run_dir)
    assert int(header["global_step"]) == r.global_step


def test_sigterm_during_setup_stops_before_the_first_iteration_with_a_checkpoint_to_resume(tmp_path):
    with sigterm_during_setup():
        r = train(_config(total=4096, extra=[f"run.out_dir={tmp_path}"]))
    assert r.stop_reason == "signal" and r.global_step == 0
    _, _, _, header = load_state(r.run_dir)
    assert int(header["global_step"]) == 0
    assert '"stop_reason": "signal"' in (r.run_dir / "summary.json").read_text()

    resumed = train(resume_config(r.run_dir, 2048), resume=r.run_dir)
    assert resumed.stop_reason == "budget" and resumed.global_step >= 2048
    # ... as the run would have gone without the stop: the same env seeds, the same policy at the end.
    uninterrupted = train(_config(total=2048, extra=[f"run.out_dir={tmp_path / 'uninterrupted'}"]))
    assert uninterrupted.global_step == resumed.global_step
    assert _leaves_equal(load_state(uninterrupted.run_dir)[2].params, load_state(r.run_dir)[2].params)

    # A resumed run stopped in its setup keeps its checkpoints as they were: the newest already holds where it is,
    # and a rewrite would record the new budget without the training toward it. Its summary says it was stopped.
    kept = {path.name: path.read_bytes() for path in (r.run_dir / "checkpoints").iterdir()}
    with sigterm_during_setup():
        again = train(resume_config(r.run_dir, 8192), resume=r.run_dir)
    assert again.stop_reason == "signal" and again.global_step == resumed.global_step
    assert {path.name: path.read_bytes() for path in (r.run_dir / "checkpoints").iterdir()} == kept
    summary = json.loads((r.run_dir / "summary.json").read_text())
    assert summary["stop_reason"] == "signal" and summary["global_step"] == resumed.global_step


def test_only_a_checkpoint_written_before_training_resumes_with_the_seeds_of_a_fresh_start(tmp_path):
    """A resume draws new env seeds, so that it does not replay the episodes before it; a run stopped in its setup
    is the exception, since it has played none. A run whose first iteration was non-finite also resumes from step 0,
    and must not replay that iteration."""
    from canter.training.seed_run import SeedStart

    config = _config()
    fresh = SeedStart(tmp_path).env_seeds(config)
    checkpoint_at_0 = tmp_path / "checkpoints" / "ckpt_000000000000.npz"
    assert SeedStart(tmp_path, step=0, resumed_from=checkpoint_at_0, untrained=True).env_seeds(config) == fresh
    assert SeedStart(tmp_path, step=0, resumed_from=checkpoint_at_0).env_seeds(config) != fresh


def test_a_resumed_run_stopped_in_setup_keeps_the_totals_and_the_group_of_the_session_that_trained_it(tmp_path):
    first = train_seeds(_config(total=2048, extra=[f"run.out_dir={tmp_path}"]), [0, 1])[0]
    before = json.loads((first.run_dir / "summary.json").read_text())
    assert before["trained_with"] == [0, 1]
    with sigterm_during_setup():
        again = train(resume_config(first.run_dir, 8192), resume=first.run_dir)
    after = json.loads((first.run_dir / "summary.json").read_text())
    assert again.stop_reason == "signal" and after["stop_reason"] == "signal"
    # The wall time is the final checkpoint's, a moment before the first summary was written: no setup time added.
    assert after["trained_with"] == [0, 1] and after["wall_seconds"] == pytest.approx(before["wall_seconds"], abs=0.1)


def test_summary_names_the_run_folder_by_its_absolute_path_when_given_a_relative_one(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    first = train(_config(total=2048, extra=["run.out_dir=rel"]))
    assert not first.run_dir.is_absolute()
    expected = str((tmp_path / first.run_dir).resolve())
    assert json.loads((first.run_dir / "summary.json").read_text())["run_dir"] == expected
    # `canter train --resume rel/RUN`: a resume stopped in its setup writes its summary too, without training.
    (first.run_dir / "summary.json").unlink()
    with sigterm_during_setup():
        again = train(resume_config(first.run_dir, 8192), resume=first.run_dir)
    assert again.stop_reason == "signal"
    assert json.loads((first.run_dir / "summary.json").read_text())["run_dir"] == expected


def test_non_finite_observation_stops_with_step_and_keeps_last_good_checkpoint(tmp_path):
    config = _config(
        total=50_000,
        env="canter_test_envs:NaNAfter-v0",
        extra=[f"run.out_dir={tmp_path}", "env.num_envs=1", "ppo.n_steps=128", "ppo.minibatch_size=64"],
    )
    with pytest.raises(CanterError, match=r"non-finite .* after step \d+") as stopped:
        train(config)
    assert "first suspects, the settings changed from preset fast: " in str(stopped.value)
    run_dir = next(tmp_path.iterdir())
    _, _, state, _header = load_state(run_dir)
    assert all(np.isfinite(np.asarray(x)).all() for x in jax.tree_util.tree_leaves(state.params))


def test_a_diverged_run_names_the_settings_it_changed_from_its_preset(capsys):
    from canter.training.seed_run import divergence_hint

    assert divergence_hint(build_config("Hopper-v5")) == (
        "it diverged with its preset's own settings; a resume keeps the run's settings and would diverge again: train "
        "anew from its config.toml (canter train --config, canter.build_config(None, config_file=...) from Python) "
        "with a lower learning rate"
    )
    changed = divergence_hint(build_config("Hopper-v5", sets=["ppo.lr=1e30", "ppo.clip=0.3"], total_steps=5000))
    assert changed.endswith("the settings changed from preset fast: ppo.lr=1e+30, ppo.clip=0.3"), changed
    many = [
        f"{key}={value}" for key, value in [("ppo.lr", 1), ("ppo.clip", 0.5), ("ppo.epochs", 3), ("ppo.gamma", 0.9)]
    ]
    hint = divergence_hint(build_config("Hopper-v5", sets=many + ["ppo.ent_coef=0.5", "ppo.vf_coef=0.1"]))
    assert hint.endswith(" and 2 more"), hint
    # Where the physics runs is no suspect, and a changed learning rate comes first, however many others changed.
    gpu = ["env.backend=mjx", "env.num_envs=4", "ppo.n_steps=16", "ppo.minibatch_size=32", "ppo.epochs=3", "ppo.lr=100"]
    hint = divergence_hint(build_config("Hopper-v5", sets=gpu))
    assert hint.endswith("preset fast: ppo.lr=100, env.num_envs=4, ppo.n_steps=16, ppo.minibatch_size=32 and 1 more")
    switched = divergence_hint(build_config("Hopper-v5", sets=["ppo.anneal_lr=false", "ppo.clip=0.3", "ppo.lr=1"]))
    assert switched.endswith("preset fast: ppo.lr=1, ppo.anneal_lr=false, ppo.clip=0.3"), switched
    # Values read as --set gives them, so that the hint can be pasted back.
    shaped = divergence_hint(build_config("Hopper-v5", sets=["env.normalize_obs=false", "net.hidden=128,64"]))
    assert shaped.endswith("preset fast: env.normalize_obs=false, net.hidden=128,64"), shaped
    # Mid-training it prints nothing: not the note of a preset made for another env.
    humanoid = build_config("Hopper-v5", preset="humanoid", sets=["ppo.clip=0.5"])
    capsys.readouterr()
    assert divergence_hint(humanoid).endswith("preset humanoid: ppo.clip=0.5") and capsys.readouterr().err == ""
    gone = replace(humanoid, run=replace(humanoid.run, preset="no-such-preset"))
    assert "(preset no-such-preset could not be built to compare with)" in divergence_hint(gone)


def test_trpo_resume_is_deterministic_and_continues(tmp_path):
    extra = [f"run.out_dir={tmp_path}", "trpo.critic_minibatch_size=256", "trpo.critic_epochs=2"]
    small = [item for item in SMALL if reads_key("trpo", item.partition("=")[0])]  # trpo has no ppo epochs
    first = train(build_config("Pendulum-v1", algo="trpo", total_steps=2048, sets=small + extra))
    _, _, before, _ = load_state(first.run_dir)
    assert before.critic_opt_state is not None and int(before.iteration) >= 2
    r1, s1 = _resume_twice(first.run_dir, 4096, tmp_path / "copy")
    assert int(s1.iteration) > int(before.iteration) and not _leaves_equal(s1.params, before.params)
    header = (r1.run_dir / "metrics.csv").read_text().splitlines()[0].split(",")
    assert {"surrogate_gain", "policy_kl", "step_accepted", "cg_iterations", "value_loss"} <= set(header)


def test_clipped_ppo_checkpoints_hold_no_kl_beta(tiny_run):
    # The clipped objective keeps no beta, so its checkpoints hold the same arrays as before the option existed.
    _, _, state, _ = load_state(tiny_run.run_dir)
    assert state.kl_beta is None
    header = (tiny_run.run_dir / "metrics.csv").read_text().splitlines()[0].split(",")
    assert {"policy_kl", "kl_beta", "sym_loss"} <= set(header)
