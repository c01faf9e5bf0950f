"""Bad arguments to the Python API's train and train_seeds: one CanterError line that names the argument and the
fix, refused before anything is written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import canter
from canter.errors import CanterError
from canter.training.loop import _checked_seeds, train_seeds


@pytest.fixture(scope="module")
def config() -> canter.Config:
    return canter.build_config("Pendulum-v1", total_steps=2048)


def contents(folder: Path) -> list[Path]:
    return sorted(folder.rglob("*"))


def refused(call, *args, **kwargs) -> str:
    with pytest.raises(CanterError) as error:
        call(*args, **kwargs)
    line = str(error.value)
    assert "\n" not in line, line
    return line


@pytest.mark.parametrize("given", [None, {"env": {"id": "Pendulum-v1"}}, "Pendulum-v1"])
def test_a_config_that_is_not_a_config_is_refused(given):
    line = refused(canter.train, given)
    assert line.startswith(f"config must be a canter Config, got {type(given).__name__}; build one with canter.")
    assert refused(canter.train_seeds, given, [0, 1]) == line


def test_an_env_id_given_as_the_config_is_shown_built():
    assert "canter.build_config('Pendulum-v1')" in refused(canter.train, "Pendulum-v1")


def test_an_empty_run_dir_or_resume_is_refused_and_writes_nothing_to_the_working_folder(config, tmp_path):
    before = contents(tmp_path)
    for name in ("run_dir", "resume"):
        line = refused(canter.train, config, **{name: ""})
        assert line.startswith(f"{name}= is empty, which would be the working folder")
    assert refused(train_seeds, config, [0, 1], run_dirs=["", "b"]).startswith("run_dirs= is empty")
    assert contents(tmp_path) == before


def refused_new_run(config: canter.Config, run_dir: Path, watched: Path) -> str:
    """The refusal of a new run in `run_dir`, which leaves `watched` as it was."""
    before = contents(watched)
    line = refused(canter.train, config, run_dir=run_dir)
    assert contents(watched) == before
    return line


def test_a_new_run_in_a_folder_of_runs_is_refused(config, archived_run):
    bench = archived_run.parent  # a folder that holds a run folder, as a bench's does
    (bench / "results.md").write_text("| env | return |\n")
    assert refused_new_run(config, bench, bench) == (
        f"{bench} holds 1 run folder (a bench's?), such as {archived_run}; give run_dir= a new folder, or leave it "
        "out for one under run.out_dir"
    )


def test_a_new_run_in_the_checkpoints_folder_of_a_run_is_refused(config, archived_run):
    folder = archived_run / "checkpoints"
    assert refused_new_run(config, folder, archived_run) == (
        f"{folder} is the checkpoints folder of the run {archived_run}; give run_dir= a new folder, or leave it out "
        "for one under run.out_dir"
    )


@pytest.mark.parametrize("run_dir", [5, b"runs/a", ["runs/a"]])
def test_a_run_dir_that_is_no_path_is_refused(config, run_dir):
    assert refused(canter.train, config, run_dir=run_dir) == (
        f"run_dir= must be a folder path (str or Path), got {type(run_dir).__name__}"
    )


@pytest.mark.parametrize(
    ("kind", "marker", "held"),
    [
        ("a bench's --out folder", ".cells/InvertedPendulum-v4__ppo__s0", ".cells/"),
        ("a study folder of canter tune", "trials/trial_00000", "trials/"),
    ],
)
def test_a_new_run_in_a_bench_or_study_folder_that_holds_no_run_yet_is_refused(config, tmp_path, kind, marker, held):
    folder = tmp_path / "out"
    (folder / marker).mkdir(parents=True)
    assert refused_new_run(config, folder, folder) == (
        f"{folder} is {kind} (it holds {held}); give run_dir= a new folder, or leave it out for one under run.out_dir"
    )


@pytest.mark.parametrize("which", ["empty", "folder of runs", "checkpoints"])
def test_a_refused_resume_of_a_folder_that_is_no_run_leaves_no_file(config, archived_run, which):
    folder = {
        "empty": archived_run.parent / "empty",
        "folder of runs": archived_run.parent,
        "checkpoints": archived_run / "checkpoints",
    }[which]
    folder.mkdir(exist_ok=True)
    before = contents(archived_run.parent)
    line = refused(canter.train, config, resume=folder)
    assert str(folder) in line
    if which == "checkpoints":
        assert line == f"{folder} is the checkpoints folder of a run, not a run folder; pass {archived_run}"
    assert contents(archived_run.parent) == before


def test_a_resume_with_a_run_dir_is_refused(config, archived_run, tmp_path):
    elsewhere = tmp_path / "elsewhere"
    line = refused(canter.train, config, resume=archived_run, run_dir=elsewhere)
    assert line.startswith("resume= goes on in the run's own folder, so run_dir= cannot be given with it")
    assert not elsewhere.exists()


@pytest.mark.parametrize("name", ["checkpoints/ckpt_000000001190.npz", "config.toml"])
def test_a_file_given_to_resume_is_named_as_no_run_folder(config, archived_run, name):
    given = archived_run / name
    before = contents(archived_run)
    line = refused(canter.train, config, resume=given)
    assert line == f"{given} is a file, not a run folder; pass the run folder that holds it"
    assert contents(archived_run) == before


@pytest.mark.parametrize("seeds", [3, {0: 1, 1: 2}, {0, 1}, None, b"01"])
def test_seeds_that_are_not_a_list_of_whole_numbers_are_refused(config, seeds):
    line = refused(canter.train_seeds, config, seeds)
    assert line.startswith(f"seeds must be a list of whole numbers, e.g. [0, 1, 2], got {seeds!r}")
    if seeds == 3:
        assert line.endswith("; for 3 seeds pass range(3)")


def test_seeds_may_be_a_list_tuple_range_or_array():
    for seeds in ([0, 1], (0, 1), range(2), np.arange(2)):
        assert _checked_seeds(seeds) == [0, 1]


def test_run_dirs_given_as_one_path_is_refused(config):
    assert refused(train_seeds, config, [0, 1], run_dirs="ab").startswith("run_dirs= must be a list of folders")


@pytest.mark.parametrize(
    ("run_dirs", "start"),
    [
        ([], "run_dirs= is empty; pass the run folders to resume"),
        (None, "run_dirs= must be a list of folders, one per seed, got None"),
        ("runs/a", "run_dirs= must be a list of folders, one per seed, got 'runs/a'"),
        ([5], "run_dirs= must be a folder path (str or Path), got int"),
    ],
)
def test_resume_seeds_refuses_run_dirs_that_are_no_list_of_folders(run_dirs, start):
    assert refused(canter.resume_seeds, run_dirs).startswith(start)


@pytest.mark.parametrize(
    ("budget", "line"),
    [
        ({"total_steps": "abc"}, "run.total_steps: expected an integer, got 'abc'"),
        ({"total_steps": 4096.9}, "run.total_steps: expected an integer, got 4096.9"),
        ({"total_steps": float("nan")}, "run.total_steps: expected an integer, got nan"),
        ({"max_minutes": "x"}, "run.max_minutes: expected a number or none, got 'x'"),
    ],
)
def test_resume_seeds_checks_its_budget_as_the_config_does(archived_run, budget, line):
    before = contents(archived_run)
    assert refused(canter.resume_seeds, [archived_run], **budget) == line
    assert contents(archived_run) == before


def test_runs_that_differ_in_their_budget_alone_are_told_the_python_argument_that_gives_them_one(archived_run):
    import shutil

    other = archived_run.parent / "other"
    shutil.copytree(archived_run, other)
    config = other / "config.toml"
    config.write_text(config.read_text().replace("total_steps = 1024", "total_steps = 2048", 1))
    line = refused(canter.resume_seeds, [archived_run, other])
    assert "(run.total_steps); pass --total-steps (total_steps= from Python) to give them one budget" in line
    # A seed resumed alone with a time limit or a target differs in that budget key: the resume's own flags give one.
    config.write_text(
        config.read_text()
        .replace("total_steps = 2048", "total_steps = 1024", 1)
        .replace("[run]\n", "[run]\nmax_minutes = 5.0\n", 1)
    )
    line = refused(canter.resume_seeds, [archived_run, other])
    assert "(run.max_minutes); pass --max-minutes (max_minutes= from Python) to give them one budget" in line


def test_a_config_that_differs_from_the_resumed_runs_is_told_the_public_call_that_reads_the_runs_own(archived_run):
    line = refused(canter.train, canter.build_config("InvertedPendulum-v4", seed=3), resume=archived_run)
    assert line.endswith(
        f"resume it with canter.resume_seeds([{str(archived_run)!r}], total_steps=...), which reads the run's own "
        "config"
    )


def test_train_seeds_without_seeds_names_the_python_argument(config):
    assert refused(canter.train_seeds, config, []).endswith("(seeds=[0, 1, 2] from Python)")


@pytest.mark.parametrize(
    ("run_dir", "line"),
    [
        (None, "run_dir= must be a folder path (str or Path), got NoneType"),
        (5, "run_dir= must be a folder path (str or Path), got int"),
        (" ", "run_dir= is empty, which would be the working folder; give a run folder"),
    ],
)
def test_load_refuses_a_run_dir_that_is_no_path(run_dir, line):
    assert refused(canter.load, run_dir) == line


def test_a_run_folder_whose_lock_names_a_bench_is_refused_as_a_run(config, archived_run):
    (archived_run / ".writer.lock").write_text('{"pid": 1, "host": "h", "command": "canter bench --envs x"}')
    assert refused_new_run(config, archived_run, archived_run).startswith(f"{archived_run} already holds a run (")


@pytest.mark.parametrize("sets", [5, {}, {"ppo.clip": 0.1}])
def test_build_config_refuses_sets_that_are_no_list(sets):
    assert refused(canter.build_config, "Pendulum-v1", sets=sets).startswith(
        'sets= takes a list of "section.key=value" strings, got '
    )


def test_a_damaged_only_checkpoint_of_a_newer_format_says_so_first(archived_run):
    (archived_run / "versions.json").write_text('{"run_format": 9}')
    for path in sorted((archived_run / "checkpoints").glob("ckpt_*.npz"))[:-1]:
        path.unlink()
    [only] = (archived_run / "checkpoints").glob("ckpt_*.npz")
    only.write_bytes(only.read_bytes()[:100])
    assert refused(canter.load, archived_run).endswith("this canter reads up to 2; use a newer canter")


def test_a_resume_limit_of_inf_lifts_the_saved_one_from_a_numpy_number_too():
    from canter.training.resume import _lifts_the_limit

    assert _lifts_the_limit(np.float32("inf")) and _lifts_the_limit(float("inf"))
    assert not _lifts_the_limit(np.float64(5.0)) and not _lifts_the_limit("inf") and not _lifts_the_limit(None)
