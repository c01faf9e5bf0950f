"""CLI smoke runs of every command, and every bad input as a one-line error with a non-zero exit."""

import json
import shutil
from pathlib import Path

import pytest

from canter.cli.main import main
from conftest import TINY

FAST = [
    "--quiet",
    "--set",
    "env.num_envs=4",
    "--set",
    "ppo.n_steps=128",
    "--set",
    "ppo.minibatch_size=256",
    "--set",
    "ppo.epochs=2",
] + [x for s in TINY for x in ("--set", s)]


def run_cli(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def only_run(folder: Path) -> Path:
    runs = [p for p in folder.iterdir() if p.is_dir()]
    assert len(runs) == 1
    return runs[0]


@pytest.mark.slow
def test_train_eval_resume_smoke(tmp_path, capsys):
    code, out, err = run_cli(
        [
            "train",
            "Pendulum-v1",
            "--seed",
            "3",
            "--total-steps",
            "2e3",
            "--out-dir",
            str(tmp_path),
            "--preset",
            "cleanrl",
            "--set",
            "ppo.clip=0.1",
            "--set",
            "net.hidden=16,8",
            "--max-minutes",
            "1e-4",
        ]
        + FAST,
        capsys,
    )
    assert code == 0, err
    assert "steps 512 |" in out and "stopped: max_minutes" in out, "the limit stops this process after one iteration"
    run = only_run(tmp_path)
    assert run.name.startswith("Pendulum-v1__ppo__cleanrl__s3__")
    assert "SPS" in out and "compile" in out
    text = (run / "config.toml").read_text()
    assert "clip = 0.1" in text and "hidden = [16, 16]" in text  # TINY's later --set wins over 16,8

    # A resume may replace the saved minute limit, which would otherwise stop this process after one iteration too.
    resume = ["train", "--resume", str(run), "--total-steps", "4096", "--max-minutes", "60", "--quiet"]
    code, out, err = run_cli(resume, capsys)
    assert code == 0, err
    assert "steps 4," in out
    assert "max_minutes = 60.0" in (run / "config.toml").read_text()
    # inf lifts the limit: the config then holds none, so the run still resumes and evaluates (it once held inf,
    # which every later read refused).
    resume = ["train", "--resume", str(run), "--total-steps", "4608", "--max-minutes", "inf", "--quiet"]
    code, out, err = run_cli(resume, capsys)
    assert code == 0, err
    assert 'max_minutes = "none"' in (run / "config.toml").read_text()

    code, out, err = run_cli(["eval", str(run), "--episodes", "3", "--json", str(tmp_path / "e.json")], capsys)
    assert code == 0, err
    rows = json.loads((tmp_path / "e.json").read_text())["runs"]
    assert rows[0]["episodes"] == 3 and len(rows[0]["returns"]) == 3 and rows[0]["deterministic"] is True
    assert "±" in out
    twin = shutil.copytree(run, tmp_path / "twin")  # a second run of the same config: a group of two
    code, out, err = run_cli(["eval", str(run), str(twin), "--episodes", "2", "--stochastic", "--seed", "1"], capsys)
    assert code == 0, err
    assert "group:" in out


@pytest.mark.slow
def test_custom_gymnasium_env(tmp_path, capsys):
    code, _out, err = run_cli(
        ["train", "canter_test_envs:DictObs-v0", "--total-steps", "1000", "--out-dir", str(tmp_path)] + FAST, capsys
    )
    assert code == 0, err
    run = only_run(tmp_path)
    assert 'backend = "auto"' in (run / "config.toml").read_text()
    code, _out, err = run_cli(["eval", str(run), "--episodes", "2"], capsys)
    assert code == 0, err


@pytest.mark.slow
def test_gymnasium_backend_flag(tmp_path, capsys):
    code, _out, err = run_cli(
        ["train", "Pendulum-v1", "--backend", "gymnasium", "--total-steps", "600", "--out-dir", str(tmp_path)] + FAST,
        capsys,
    )
    assert code == 0, err
    assert 'backend = "gymnasium"' in (only_run(tmp_path) / "config.toml").read_text()


def _bad_inputs(tmp_path, run):
    corrupt = tmp_path / "corrupt_run"
    shutil.copytree(run, corrupt)
    ckpts = sorted((corrupt / "checkpoints").iterdir())
    ckpts[-1].write_bytes(ckpts[-1].read_bytes()[:100])
    bad_toml = tmp_path / "bad.toml"
    bad_toml.write_text("[ppo\n")
    unknown_toml = tmp_path / "unknown.toml"
    unknown_toml.write_text("[ppo]\nnot_a_key = 1\n")
    empty = tmp_path / "empty"
    empty.mkdir()
    return [
        (["train", "Hoper-v5"], "did you mean Hopper-v5"),
        (["train", "Hopper-v5", "--set", "ppo.lr=-1"], "ppo.lr must be > 0"),
        (["train", "Hopper-v5", "--set", "ppo.lr=0"], "ppo.lr must be > 0"),
        (["train", "Hopper-v5", "--set", "ppo.clipp=0.1"], "unknown config key"),
        (["train", "Hopper-v5", "--set", "ppo.epochs=many"], "expected an integer"),
        (["train", "Hopper-v5", "--set", "ppo.minibatch_size=1000"], "does not divide"),
        (["train", "Hopper-v5", "--config", str(bad_toml)], "malformed TOML"),
        (["train", "Hopper-v5", "--config", str(unknown_toml)], "unknown config key 'ppo.not_a_key'"),
        (["train", "Hopper-v5", "--total-steps", "abc"], "step count"),
        (["train", "Hopper-v5", "--preset", "turbo"], "unknown preset"),
        (["train"], "no environment given"),
        (["train", "canter_test_envs:DiscreteObs-v0"], "Box or a Dict of Boxes"),
        (["train", "--resume", str(tmp_path / "missing")], "run folder not found"),
        (["train", "--resume", str(empty)], "no config.toml"),
        (
            ["train", "--resume", str(run), "--seed", "4"],
            "only --total-steps, --max-minutes, --stop-at-return, --quiet,",
        ),
        (
            ["train", "--resume", str(run), "--seed", "0"],
            "only --total-steps, --max-minutes, --stop-at-return, --quiet,",
        ),
        (["train", "Hopper-v5", "--seed", "-1"], "argument --seed: expected a seed from 0 to 4294967295"),
        (["train", "--resume", str(corrupt), "--total-steps", "9999"], "corrupt or truncated"),
        (["eval", str(tmp_path / "missing")], "run folder not found"),
        (["eval", str(empty)], "has no config.toml and no checkpoint; is it a canter run folder?"),
        (["eval", str(corrupt)], "corrupt or truncated"),
        (["eval", str(run), "--env", "Hopper-v5"], "pick a matching --env"),
        (["eval", str(run), "--episodes", "0"], "--episodes must be >= 1"),
        (["eval", str(run), "--episodes", "1", "--json", str(bad_toml / "x.json")], "cannot write"),
        (["frobnicate"], "invalid choice"),
        (["train", "Hopper-v5", "--bogus"], "canter: error: train: unrecognized arguments: --bogus"),
        (
            ["train", "Hopper-v5", "--totalsteps", "9"],
            "unrecognized arguments: --totalsteps 9; did you mean --total-steps?",
        ),
        (["train", "Hopper-v5", "--algo", "PPO"], "unknown algorithm 'PPO'; did you mean ppo?"),
        # A flag and --set of one key: the flag won, silently.
        (
            ["train", "Hopper-v5", "--set", "env.id=Ant-v5"],
            "env.id is given twice, by the env (its argument, or --envs) and by --set",
        ),
        (
            ["train", "Hopper-v5", "--seeds", "0,1", "--set", "run.seed=7"],
            "run.seed is given twice, by --seed (or --seeds) and",
        ),
        (
            ["train", "Hopper-v5", "--out-dir", "a", "--set", "run.out_dir=b"],
            "run.out_dir is given twice, by --out-dir",
        ),
        (["train", "Hopper-v5", "--total-steps"], "canter: error: train: argument --total-steps"),
    ]


@pytest.mark.slow
def test_bad_inputs_are_one_line_errors(tmp_path, capsys, tiny_run):
    for argv, message in _bad_inputs(tmp_path, tiny_run.run_dir):
        code, _out, err = run_cli(argv, capsys)
        assert code != 0, argv
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1, (argv, err)
        assert "Traceback" not in err and message in lines[0], (argv, lines[0])


def test_quiet_is_offered_where_there_is_a_progress_bar_only(capsys):
    """train draws a progress bar; eval and video print only their results, so they refuse --quiet."""
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    assert "--quiet" in capsys.readouterr().out
    for argv in (["eval", "run"], ["video", "run", "--out", "a.mp4"]):
        code, _out, err = run_cli(argv + ["--quiet"], capsys)
        assert code == 2 and err.count("\n") == 1 and "unrecognized arguments: --quiet" in err, err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["--stop-at-return", "-inf"],
            "train: argument --stop-at-return: expected a finite number, or inf for no limit, got '-inf' (see --help)",
        ),
        (
            ["--max-minutes", "-NaN"],
            "train: argument --max-minutes: expected a finite number, or inf for no limit, got '-NaN' (see --help)",
        ),
    ],
)
def test_a_value_that_starts_with_a_dash_reaches_its_own_check(argv, message, capsys):
    """argparse reads `-inf` as an option, and the error was `expected one argument`."""
    assert main(["train", "Pendulum-v1", "--total-steps", "100", *argv]) == 2
    assert capsys.readouterr().err == f"canter: error: {message}\n"


def test_an_out_dir_under_a_file_names_the_file(tmp_path, capsys):
    (tmp_path / "cl.toml").write_text("x")
    argv = ["train", "Pendulum-v1", "--total-steps", "100", "--out-dir", str(tmp_path / "cl.toml" / "x")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    blocker = tmp_path / "cl.toml"
    fix = f"{blocker} is a file, not a folder; move {blocker} out of the way, or pick another path"
    assert err.count("\n") == 1 and fix in err, err


@pytest.mark.parametrize(("given", "target"), [(None, "keep"), ("inf", None), ("-50", -50.0)])
def test_a_resume_takes_a_return_target_and_inf_lifts_it(given, target, monkeypatch, tmp_path):
    from canter.training import resume

    class Resumed(Exception):
        pass

    def stand_in(run_dir, total_steps, max_minutes=None, stop_at_return=resume.Saved.KEEP):
        raise Resumed(stop_at_return)

    monkeypatch.setattr(resume, "resume_config", stand_in)
    flags = [] if given is None else ["--stop-at-return", given]
    with pytest.raises(Resumed) as resumed:
        main(["train", "--resume", str(tmp_path), *flags])
    assert resumed.value.args[0] == (resume.Saved.KEEP if target == "keep" else target)
