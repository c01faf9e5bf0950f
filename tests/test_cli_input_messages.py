"""Flag values and run folders that got a bare argparse message, a misleading example or a stray warning: each is
now taken, or refused in one line that names the problem and the fix."""

from __future__ import annotations

import argparse
import json
import shutil
import warnings
from pathlib import Path

import pytest

from canter.cli.main import build_parser, main
from conftest import error_line

VARY_TOO_FAR = (
    "--vary 'gravity=1,1e+308': scale 1e+308 takes gravity past the largest number a float holds (about 1.8e308); "
    "give a smaller scale"
)


def test_a_scale_past_the_float_range_is_refused_before_any_episode(archived_run, capsys):
    assert error_line(capsys, ["eval", str(archived_run), "--episodes", "1", "--vary", "gravity=1,1e308"]) == (
        VARY_TOO_FAR
    )
    assert not (archived_run / "robustness").exists()


def test_a_diverging_sweep_writes_valid_json_and_no_warnings(archived_run, capsys):
    """A finite but huge scale diverges; its point is marked unstable, and Gymnasium's word for the same divergence
    (an observation outside its space) is not printed."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["eval", str(archived_run), "--episodes", "1", "--vary", "gravity=1e300"]) == 0
    assert [str(w.message) for w in caught] == []
    assert capsys.readouterr().err == ""
    text = (archived_run / "robustness" / "gravity.json").read_text()
    point = json.loads(text, parse_constant=pytest.fail)["runs"][0]["points"][0]
    assert point["unstable_warnings"] > 0


@pytest.fixture
def two_runs(archived_run: Path) -> tuple[Path, Path]:
    other = archived_run.with_name("other")
    shutil.copytree(archived_run, other)
    return archived_run, other


@pytest.mark.parametrize(
    "command, flags",
    [
        ("eval", ["--episodes", "1"]),
        ("plot", ["--out", "q.png"]),
        ("report", ["--episodes", "0", "--out", "r.html"]),
    ],
)
def test_run_folders_may_follow_a_flag(command, flags, two_runs):
    first, second = two_runs
    args = build_parser().parse_args([command, str(first), *flags, str(second)])
    assert args.runs == [str(first), str(second)]


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["train", "--algo", "sac", "Hopper-v5", "--seed", "3"], {"env": "Hopper-v5", "algo": "sac", "seed": 3}),
        (["train", "--resume", "a", "b", "--total-steps", "1e3"], {"resume": ["a", "b"], "total_steps": 1000}),
        (["tune", "--trials", "3", "Hopper-v5"], {"env": "Hopper-v5", "trials": 3}),
        (["export", "--out", "p.onnx", "run"], {"run": "run", "out": "p.onnx"}),
        (["eval", "--", "-odd-name"], {"runs": ["-odd-name"]}),
    ],
)
def test_other_commands_parse_as_before(argv, expected):
    args = vars(build_parser().parse_args(argv))
    assert {key: args[key] for key in expected} == expected


def test_a_stray_word_after_the_run_folders_is_still_unrecognized(archived_run, capsys):
    line = error_line(capsys, ["eval", str(archived_run), "--episods", "1"])
    assert line == "eval: unrecognized arguments: --episods 1; did you mean --episodes? (see --help)"


def test_the_example_for_a_json_that_is_a_run_folder_is_accepted(archived_run, capsys):
    line = error_line(capsys, ["eval", str(archived_run), "--episodes", "1", "--json", str(archived_run)])
    example = line.rsplit("e.g. --json ", 1)[1]
    assert main(["eval", str(archived_run), "--episodes", "1", "--json", example]) == 0
    assert json.loads(Path(example).read_text())["runs"]


def test_an_empty_storage_is_named(capsys):
    for argv in (["tune", "Hopper-v5"], ["bench", "--envs", "Hopper-v5"]):
        line = error_line(capsys, [*argv, "--storage", ""])
        assert line.startswith("--storage is empty; give a database URL such as sqlite:///study.db"), line
    assert not Path("tune").exists() and not Path("bench").exists()


@pytest.mark.parametrize("command", [["tune", "Hopper-v5"], ["bench", "--envs", "Hopper-v5"]])
def test_a_storage_of_an_unknown_scheme_names_the_ones_to_use(command, capsys):
    assert error_line(capsys, [*command, "--storage", "foo://u:secret@bar/db"]) == (
        "--storage 'foo://u:***@bar/db': unknown database scheme 'foo'; use sqlite:///path/study.db or "
        "postgresql://user:password@host:5432/dbname"
    )


@pytest.mark.parametrize(
    "command, example",
    [(["plot", "run"], "curves.png"), (["report", "run"], "report.html")],
)
def test_an_empty_out_is_named(command, example, capsys):
    assert error_line(capsys, [*command, "--out", ""]) == (
        f"--out is empty; give the file to write, e.g. --out {example}"
    )


@pytest.mark.parametrize(
    "argv, dest, value",
    [
        (["eval", "run", "--episodes", "1e3"], "episodes", 1000),
        (["video", "run", "--out", "v.mp4", "--width", "1e3"], "width", 1000),
        (["plot", "run", "--smooth", "1e9"], "smooth", 10**9),
        (["report", "run", "--smooth", "2.0"], "smooth", 2),
        (["tune", "Hopper-v5", "--heartbeat", "6e1"], "heartbeat", 60),
        (["bench", "--jobs", "2e0"], "jobs", 2),
        (["tune", "Hopper-v5", "--trials", "12"], "trials", 12),
        (["train", "Hopper-v5", "--eval-every", "1e4", "--eval-episodes", "1e1"], "eval_episodes", 10),
    ],
)
def test_an_integer_flag_takes_a_whole_number_written_with_an_exponent(argv, dest, value):
    assert getattr(build_parser().parse_args(argv), dest) == value


@pytest.mark.parametrize(
    "argv, flag, value",
    [
        (["tune", "Hopper-v5", "--heartbeat", "nan"], "--heartbeat", "nan"),
        (["eval", "run", "--episodes", "1.5"], "--episodes", "1.5"),
        (["video", "run", "--out", "v.mp4", "--fps", "inf"], "--fps", "inf"),
        (["plot", "run", "--smooth", "ten"], "--smooth", "ten"),
        (["train", "Hopper-v5", "--eval-every", "1e4", "--eval-episodes", "1.5"], "--eval-episodes", "1.5"),
    ],
)
def test_an_integer_flag_refuses_other_values_naming_the_form(argv, flag, value, capsys):
    assert error_line(capsys, argv) == (
        f"{argv[0]}: argument {flag}: expected a whole number such as 10 or 1e3, got {value!r} (see --help)"
    )


def test_a_whole_number_past_float_precision_needs_its_digits():
    from canter.cli.args import whole_arg

    assert whole_arg(str(2**60)) == 2**60  # written out, exact
    with pytest.raises(argparse.ArgumentTypeError, match="below 2"):
        whole_arg("1e20")
