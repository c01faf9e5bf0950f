"""Keys a command sets itself are refused when given otherwise, settings check their own values, a config written
with none reads back as none over any preset, and tune reads metrics.csv as every other reader does."""

import math
import re
from dataclasses import fields, replace
from pathlib import Path

import pytest

from canter.cli.main import main
from canter.config.build import build_config
from canter.config.serialize import from_toml_text, to_toml
from canter.errors import CanterError
from canter.orchestrate.bench_grid import BenchSettings, make_cells
from canter.orchestrate.tune import (
    TuneSettings,
    check_settings,
    config_file_toml,
    logged_evaluations,
    logged_steps,
    owned_keys,
    trial_config,
)
from canter.run_layout import CONFIG_FILE, METRICS_FILE
from canter.training.run_folder import read_config


def _tune_settings(tmp_path: Path, **kwargs) -> TuneSettings:
    return TuneSettings(env_id="Pendulum-v1", total_steps=1024, out_dir=str(tmp_path / "tune"), **kwargs)


# ------------------------------------------------------------------------------------- keys tune sets every trial


@pytest.mark.parametrize(
    "given, message",
    [
        ("run.max_minutes=5", "run.max_minutes is set by tune, as none (a trial trains its whole budget; --trial-"),
        ("run.stop_at_return=100", "run.stop_at_return is set by tune, as none (every trial trains its whole budget"),
        ("run.eval_every=7", "run.eval_every is set by tune's --evaluations (an evaluation every 1/N of the budget)"),
        ("run.eval_episodes=3", "run.eval_episodes is set by tune's --eval-episodes; leave out --set run.eval_ep"),
        ("run.out_dir=elsewhere", "run.out_dir is set by tune's --out-dir (each trial trains in its own folder"),
        ("run.tensorboard=true", "run.tensorboard is set by tune, as false"),
        # tune passes these two to every trial's config as its own arguments, given or not (a seed of 0 by default)
        ("run.seed=3", "run.seed is set by tune's --seed and --seeds-per-trial (every trial trains the same seeds); "),
        ("run.total_steps=9", "run.total_steps is set by tune's --total-steps (every trial trains the same budget); "),
    ],
)
def test_tune_refuses_a_set_of_a_key_it_sets_in_every_trial(tmp_path, given, message):
    with pytest.raises(CanterError, match="^" + message.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")):
        check_settings(_tune_settings(tmp_path, sets=(given,)))


def test_a_config_file_may_give_the_keys_tune_sets_and_tune_s_values_win(tmp_path):
    """A run folder's config.toml gives every run key; it is a base config that tune can start from."""
    path = tmp_path / "base.toml"
    path.write_text("[ppo]\nlr = 0.001\n\n[run]\nmax_minutes = 5\ntensorboard = true\ncheckpoint_every = 1000\n")
    settings = _tune_settings(tmp_path, config_file=str(path))
    base, _space = check_settings(settings)
    assert base.ppo.lr == 0.001 and base.run.max_minutes == 5
    trial = trial_config(base, {}, tmp_path / "trial", settings)
    owned = owned_keys(settings, tmp_path / "trial")
    assert trial.ppo.lr == 0.001
    assert (trial.run.max_minutes, trial.run.tensorboard, trial.run.checkpoint_every) == tuple(
        owned[f"run.{name}"][0] for name in ("max_minutes", "tensorboard", "checkpoint_every")
    )


def test_the_keys_tune_refuses_are_every_key_a_trial_takes_from_tune(tmp_path):
    settings = _tune_settings(tmp_path)
    base, _space = check_settings(settings)
    # Every run key away from what tune gives it, so that each key a trial takes from tune shows as a change.
    away = dict(checkpoint_every=7, keep_checkpoints=7, eval_every=7, eval_episodes=7, tensorboard=True)
    base = replace(base, run=replace(base.run, out_dir="x", max_minutes=7.0, stop_at_return=7.0, **away))
    trial = trial_config(base, {}, tmp_path / "trial", settings)
    changed = {f"run.{f.name}" for f in fields(base.run) if getattr(base.run, f.name) != getattr(trial.run, f.name)}
    assert changed == set(owned_keys(settings, tmp_path / "trial"))
    assert replace(trial, run=base.run) == base  # nothing else of the base config changes


def test_tune_refuses_a_set_of_an_owned_key_before_anything_starts(tmp_path, capsys, monkeypatch):
    import canter.orchestrate.tune

    def no_worker(*_):
        raise AssertionError("a worker started")

    monkeypatch.setattr(canter.orchestrate.tune, "worker", no_worker)
    code = main(["tune", "Pendulum-v1", "--set", "run.max_minutes=5", "--out-dir", str(tmp_path / "t")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "leave out --set run.max_minutes" in err, err
    assert not (tmp_path / "t").exists()


# ---------------------------------------------------------------------------------------- keys the bench sets


@pytest.mark.parametrize(
    "given, flag",
    [("run.out_dir=elsewhere", "--out"), ("run.seed=3", "--seeds"), ("run.total_steps=5", "--total-steps")],
)
def test_bench_refuses_a_set_of_a_key_it_sets(given, flag):
    key = given.partition("=")[0]
    settings = BenchSettings(("ppo",), ("Pendulum-v1",), (0,), 1000, sets=(given,))
    with pytest.raises(CanterError, match=f"^{key} is set by the bench's {flag}; give {flag} rather than --set {key}$"):
        make_cells(settings)


# ------------------------------------------------------------------------------------------------ train's flags


def test_max_minutes_inf_is_no_limit_and_still_refuses_a_set_of_the_same_key(monkeypatch, capsys):
    import canter.training.loop

    trained = []

    def record(config, **_):
        trained.append(config)
        raise SystemExit(0)  # the config is all this test needs

    monkeypatch.setattr(canter.training.loop, "train", record)
    code = main(["train", "Pendulum-v1", "--max-minutes", "inf", "--set", "run.max_minutes=5"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and trained == [], "the flag would have been dropped for the --set"
    assert err == (
        "canter: error: run.max_minutes is given twice, by --max-minutes and by --set run.max_minutes; give it once"
    )
    with pytest.raises(SystemExit):
        main(["train", "Pendulum-v1", "--max-minutes", "inf"])
    assert trained[0].run.max_minutes is None


# ---------------------------------------------------------------------------------- settings check their values


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"heartbeat_seconds": 0}, "--heartbeat (heartbeat_seconds) must be >= 1, got 0"),
        ({"seeds": ()}, "--seeds-per-trial (the number of seeds) must be >= 1, got 0"),
        ({"eval_episodes": 0}, "--eval-episodes (eval_episodes) must be >= 1, got 0"),
        ({"startup_trials": -1}, "--startup-trials (startup_trials) must be >= 0, got -1"),
        ({"trial_minutes": 0.0}, "--trial-minutes (trial_minutes) must be > 0, got 0"),
    ],
)
def test_tune_settings_refuse_bad_values_from_python_too(kwargs, message):
    with pytest.raises(CanterError) as caught:
        TuneSettings(env_id="Pendulum-v1", **kwargs)
    assert str(caught.value) == message


def test_bench_settings_refuse_bad_values_from_python_too():
    for kwargs, message in [
        ({"heartbeat_seconds": 0}, "--heartbeat (heartbeat_seconds) must be >= 1, got 0"),
        ({"jobs": 0}, "--jobs must be >= 1, got 0"),
        ({"eval_episodes": 0}, "--episodes (eval_episodes) must be >= 1, got 0"),
    ]:
        with pytest.raises(CanterError) as caught:
            BenchSettings(("ppo",), ("Pendulum-v1",), (0,), 1000, **kwargs)
        assert str(caught.value) == message


def test_the_heartbeat_grace_follows_the_heartbeat():
    assert TuneSettings(env_id="Pendulum-v1", heartbeat_seconds=10).storage.grace_seconds == 30
    assert TuneSettings(env_id="Pendulum-v1").storage.grace_seconds == 180


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--heartbeat", "0"], "--heartbeat (heartbeat_seconds) must be >= 1, got 0"),
        (["--seeds-per-trial", "0"], "--seeds-per-trial must be >= 1, got 0"),
    ],
)
def test_tune_command_line_says_the_same(tmp_path, capsys, argv, message):
    code = main(["tune", "Pendulum-v1", "--out-dir", str(tmp_path / "t"), *argv])
    assert code == 2 and capsys.readouterr().err.strip() == f"canter: error: {message}"
    assert not (tmp_path / "t").exists()


# ------------------------------------------------------------------------------------------- none in a config


PRESET = "report002-bipedalwalker-ppo"


def test_none_reads_back_as_none_over_a_preset_that_gives_a_value(tmp_path):
    config = build_config("BipedalWalker-v3", preset=PRESET, sets=["ppo.target_kl=none", "run.stop_at_return=none"])
    under = build_config("BipedalWalker-v3", preset=PRESET)
    assert under.ppo.target_kl is not None and under.run.stop_at_return is not None, "the preset gives both"
    assert config.ppo.target_kl is None and config.run.stop_at_return is None
    text = to_toml(config)
    assert 'target_kl = "none"' in text and 'stop_at_return = "none"' in text
    (tmp_path / CONFIG_FILE).write_text(text)
    # --config over the same preset, as `canter train --config RUN/config.toml --preset ...` reads it
    assert build_config(None, preset=PRESET, config_file=str(tmp_path / CONFIG_FILE)) == config
    # a run folder and a checkpoint header (resume, canter.load, eval) read it with from_toml_text
    assert read_config(tmp_path) == config
    assert from_toml_text(text, "header") == config
    # tune's best.toml is written by the same writer
    best = tmp_path / "best.toml"
    best.write_text(config_file_toml(config))
    again = build_config(None, preset=PRESET, config_file=str(best))
    assert again.ppo.target_kl is None


def test_a_run_folder_written_with_none_as_a_comment_still_reads_as_none(tmp_path):
    config = build_config("BipedalWalker-v3", preset=PRESET, sets=["ppo.target_kl=none", "run.stop_at_return=none"])
    old = re.sub(r'^(\w+) = "none"$', r"# \1 = none", to_toml(config), flags=re.MULTILINE)
    assert "# target_kl = none" in old and "# stop_at_return = none" in old
    (tmp_path / CONFIG_FILE).write_text(old)
    assert read_config(tmp_path) == config


# ----------------------------------------------------------------------------------------- tune's metrics reader


def test_tune_reads_evaluations_past_a_byte_order_mark_and_refuses_a_damaged_file(tmp_path):
    settings = TuneSettings(env_id="Pendulum-v1", total_steps=1000, evaluations=2)
    assert logged_evaluations(tmp_path, settings) == {}  # nothing logged yet
    rows = "global_step,eval/return_mean,eval/episodes\n500,-3.5,1\n1000,-1.5,1\n1200,-9"  # the last: half-written
    (tmp_path / METRICS_FILE).write_text("\ufeff" + rows, encoding="utf-8")
    assert logged_evaluations(tmp_path, settings) == {1: -3.5, 2: -1.5}
    # A damaged step or return is skipped, and stops nothing; a NaN return is a diverged evaluation, and counts.
    (tmp_path / METRICS_FILE).write_text(rows.replace("500,", "5x0,").replace("-1.5", "-1.x"), encoding="utf-8")
    assert logged_evaluations(tmp_path, settings) == {}
    assert logged_steps(tmp_path) == 1000
    (tmp_path / METRICS_FILE).write_text(rows.replace("-1.5", "nan"), encoding="utf-8")
    found = logged_evaluations(tmp_path, settings)
    assert found[1] == -3.5 and math.isnan(found[2])
    (tmp_path / METRICS_FILE).write_text("global_step,eval/return_mean,eval/episodes\n500," + "9" * 200_000 + ",1\n")
    with pytest.raises(CanterError, match=r"metrics\.csv is damaged .*; restore it from a copy, or move it away"):
        logged_evaluations(tmp_path, settings)
