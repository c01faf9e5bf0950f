"""What a folder that is no run folder gets from every command and `--checkpoint` form, and the defaults of the
commands that play a policy."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from canter.cli.main import build_parser, main
from canter.errors import CanterError
from canter.training import checkpoint, run_folder

FIXTURE = Path(__file__).parent / "fixtures" / "runs-v1" / "ppo"
NOT_A_RUN = "has no config.toml and no checkpoint; is it a canter run folder?"


def _commands(folder: Path, out: Path) -> list[list[str]]:
    return [
        ["eval", str(folder)],
        ["video", str(folder), "--out", str(out / "a.gif")],
        ["export", str(folder), "--out", str(out / "a.npz")],
        ["report", str(folder), "--out", str(out / "a.html")],
    ]


@pytest.mark.parametrize("which", ["last", "best", "file"])
def test_every_checkpoint_form_on_a_folder_that_is_no_run_says_so(tmp_path, capsys, which):
    """`--checkpoint best` once said the folder "never evaluated during training", and a checkpoint file was read
    as if the folder were its run, where `last` asked whether it is a run folder at all."""
    folder = tmp_path / "not-a-run"
    folder.mkdir()
    kept = tmp_path / "kept.npz"
    shutil.copy(run_folder.list_checkpoints(FIXTURE)[-1], kept)
    picked = str(kept) if which == "file" else which
    for argv in _commands(folder, tmp_path):
        code = main([*argv, "--checkpoint", picked])
        err = capsys.readouterr().err
        assert code == 2 and NOT_A_RUN in err and err.count("\n") == 1, (argv, err)
    with pytest.raises(CanterError, match="is it a canter run folder"):
        checkpoint.resolve(folder, kept if which == "file" else which)


def test_a_run_s_checkpoints_folder_names_its_run_folder(tmp_path, capsys):
    shutil.copytree(FIXTURE, tmp_path / "run")
    given = tmp_path / "run" / "checkpoints"
    for argv in _commands(given, tmp_path):
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1, (argv, err)
        assert err == (
            f"canter: error: {given} is a run's checkpoints/ folder, not the run folder; pass {tmp_path / 'run'}, "
            "and --checkpoint FILE (checkpoint= from Python) to pick one of its checkpoints\n"
        )


def test_best_of_a_bench_folder_names_the_runs_inside(tmp_path, capsys):
    shutil.copytree(FIXTURE, tmp_path / "bench" / "ppo")
    code = main(["eval", str(tmp_path / "bench"), "--checkpoint", "best"])
    err = capsys.readouterr().err
    assert code == 2 and "is not a run folder but holds 1 run folder (a bench's?)" in err, err


def test_a_run_folder_that_lost_its_config_still_gives_its_checkpoints(tmp_path):
    """Each checkpoint holds the config, so a run folder is one by its checkpoints too."""
    run = tmp_path / "run"
    shutil.copytree(FIXTURE, run)
    (run / "config.toml").unlink()
    newest = run_folder.list_checkpoints(run)[-1]
    assert checkpoint.resolve(run, "last") == newest
    assert checkpoint.resolve(run, newest) == newest
    with pytest.raises(CanterError, match="never evaluated during training"):
        checkpoint.resolve(run, "best")


@pytest.mark.parametrize("argv", [["eval", "run"], ["video", "run", "--out", "a.gif"]])
def test_the_env_seed_of_eval_and_video_defaults_to_0(argv):
    assert build_parser().parse_args(argv).seed == 0
