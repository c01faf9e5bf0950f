"""`canter bench --backend` and `canter tune --backend`: train's option, set as `--set env.backend` sets it, so that
the backend errors' advice (`pass --backend brax`) is an option these commands take; and refused beside a --set or
--grid of env.backend, as train refuses a key given both by a flag and by --set."""

import argparse

import pytest

from canter.cli.main import build_parser, main
from canter.orchestrate import bench as bench_module
from canter.orchestrate import bench_grid
from canter.orchestrate import tune as tune_module
from canter.orchestrate.bench_grid import make_cells
from canter.orchestrate.tune import base_config

BENCH = ["bench", "--algos", "ppo", "--seeds", "0", "--total-steps", "4096"]
TUNE = ["tune", "--trials", "1", "--total-steps", "4096"]


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def _captured(monkeypatch, module, name: str, argv: list[str]):
    """The settings that `canter ARGV` hands to bench or tune, which are replaced so that nothing trains."""
    seen = []
    monkeypatch.setattr(module, name, seen.append)
    assert main(argv) == 0
    [settings] = seen
    return settings


def _backend_action(command: str) -> argparse.Action:
    parser = build_parser()
    [sub] = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    [action] = [a for a in sub.choices[command]._actions if "--backend" in a.option_strings]
    return action


def test_bench_and_tune_take_trains_backend_option():
    train = _backend_action("train")
    for command in ("bench", "tune"):
        action = _backend_action(command)
        assert (action.choices, action.help, action.default) == (train.choices, train.help, train.default)
    assert "mjx" in train.choices and "brax" in train.choices


def test_bench_backend_sets_env_backend_as_set_does(tmp_path, monkeypatch):
    monkeypatch.setattr(bench_grid, "check_continuous", lambda env_id, backend: None)  # it would make an env
    argv = [*BENCH, "--envs", "Hopper-v5,Walker2d-v5", "--out", str(tmp_path / "b")]
    flag = _captured(monkeypatch, bench_module, "bench", [*argv, "--backend", "mjx"])
    setting = _captured(monkeypatch, bench_module, "bench", [*argv, "--set", "env.backend=mjx"])
    assert flag == setting  # the same settings, so the same cells, runs and (with --storage) job keys
    cells = make_cells(flag)
    assert [(c.env_id, c.config.env.backend) for c in cells] == [("Hopper-v5", "mjx"), ("Walker2d-v5", "mjx")]


def test_tune_backend_sets_env_backend_as_set_does(tmp_path, monkeypatch):
    argv = [*TUNE, "Hopper-v5", "--out-dir", str(tmp_path / "t")]
    flag = _captured(monkeypatch, tune_module, "tune", [*argv, "--backend", "mjx"])
    setting = _captured(monkeypatch, tune_module, "tune", [*argv, "--set", "env.backend=mjx"])
    assert flag == setting
    assert base_config(flag).env.backend == "mjx"


@pytest.mark.parametrize(
    "argv",
    [
        [*BENCH, "--envs", "hopper", "--backend", "mjx"],
        [*TUNE, "hopper", "--backend", "mjx"],
    ],
    ids=["bench", "tune"],
)
def test_a_backend_error_advises_an_option_the_command_takes(argv, tmp_path, capsys):
    """`hopper` is Brax's id: the error says `pass --backend brax`, which bench and tune must take too."""
    argv = [*argv, "--out" if argv[0] == "bench" else "--out-dir", str(tmp_path / "out")]
    assert main(argv) == 2
    err = _one_line_error(capsys)
    assert "pass --backend brax" in err, err
    assert not (tmp_path / "out").exists()
    args = build_parser().parse_args([argv[0], "--backend", "brax"])
    assert args.backend == "brax"


def test_bench_follows_the_advice(tmp_path, monkeypatch):
    """make_cells checks each env id on its cell's backend: on the auto backend it would refuse a Brax id with the
    very advice given here."""
    monkeypatch.setattr(bench_grid, "check_continuous", lambda env_id, backend: None)
    settings = _captured(
        monkeypatch, bench_module, "bench", [*BENCH, "--envs", "hopper", "--backend", "brax", "--out", str(tmp_path)]
    )
    assert [c.config.env.backend for c in make_cells(settings)] == ["brax"]


@pytest.mark.parametrize(
    ("argv", "given"),
    [
        ([*BENCH, "--envs", "Hopper-v5", "--set", "env.backend=brax"], "--set env.backend"),
        ([*BENCH, "--envs", "Hopper-v5", "--set", "env.backend=mjx"], "--set env.backend"),
        ([*BENCH, "--envs", "Hopper-v5", "--grid", "env.backend=mjx,gymnasium"], "--grid env.backend"),
        ([*TUNE, "Hopper-v5", "--set", "env.backend=brax"], "--set env.backend"),
    ],
    ids=["bench-set", "bench-set-same", "bench-grid", "tune-set"],
)
def test_backend_and_a_setting_of_env_backend_are_refused_together(argv, given, tmp_path, capsys):
    """One of the two would be ignored (train refuses the same, even with equal values)."""
    out = ["--out" if argv[0] == "bench" else "--out-dir", str(tmp_path / "out")]
    assert main([*argv, "--backend", "mjx", *out]) == 2
    err = _one_line_error(capsys)
    assert "--backend" in err and given in err, err
    assert not (tmp_path / "out").exists()
