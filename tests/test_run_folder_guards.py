"""A run folder's own files stay its own: user-named outputs never replace its writer lock or its videos, a refused
resume leaves the folder as it was, and a folder where a run file belongs is named as such, before any training."""

import errno
import shutil
from pathlib import Path

import pytest

from canter.config.build import build_config
from canter.files import atomic_write_bytes, check_writable
from canter.run_layout import LOCK_FILE, run_files_in
from canter.training.loop import train
from conftest import error_line

# TensorBoard stays on: a refused resume must not leave an events file behind either.
SETTINGS = [
    "net.hidden=16,16",
    "env.num_envs=4",
    "ppo.n_steps=256",
    "ppo.minibatch_size=256",
    "ppo.epochs=1",
    "run.checkpoint_every=2048",
    "run.eval_every=2048",
    "run.eval_episodes=2",
]


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """A finished Pendulum run with a best.npz and TensorBoard events, never written to by the tests."""
    out = tmp_path_factory.mktemp("guarded_runs")
    config = build_config("Pendulum-v1", preset="fast", total_steps=4096, sets=[*SETTINGS, f"run.out_dir={out}"])
    return train(config).run_dir


@pytest.fixture
def run(trained, tmp_path) -> Path:
    folder = tmp_path / "run"
    shutil.copytree(trained, folder)
    return folder


def contents(folder: Path) -> dict[str, bytes | None]:
    """Every file's bytes and every folder (None) under `folder`, the writer lock aside: each writer records itself
    in it."""
    return {
        str(path.relative_to(folder)): path.read_bytes() if path.is_file() else None
        for path in folder.rglob("*")
        if path.name != LOCK_FILE
    }


# ------------------------------------------------------------------------------------ outputs named by the user


@pytest.mark.parametrize(
    "argv",
    [
        ["export", "{run}", "--format", "npz", "--out", "{run}/.writer.lock"],
        ["eval", "{run}", "--episodes", "1", "--json", "{run}/.writer.lock"],
    ],
)
def test_an_output_never_replaces_the_writer_lock(run, capsys, argv):
    lock = run / LOCK_FILE
    before = lock.read_bytes()
    line = error_line(capsys, [arg.format(run=run) for arg in argv])
    assert f"cannot write {run / LOCK_FILE}" in line and "writer lock" in line and "give another path" in line
    assert lock.read_bytes() == before


def test_the_writer_lock_is_refused_in_any_folder(tmp_path):
    # A bench's or tune's folder holds one too, and neither is a run folder.
    from canter.errors import CanterError

    with pytest.raises(CanterError, match="writer lock"):
        check_writable(tmp_path / "bench" / LOCK_FILE)


def test_a_lock_alone_does_not_make_a_run(tmp_path):
    # A folder whose first run was refused keeps its lock, and takes a new run.
    (tmp_path / LOCK_FILE).write_text("{}")
    assert run_files_in(tmp_path) == frozenset()


@pytest.mark.parametrize("name", ["step_000000001212.mp4", "render.log", ".snapshot_000000001212.npz"])
def test_an_output_never_replaces_a_file_of_the_run_videos(run, capsys, name):
    videos = run / "videos"
    videos.mkdir()
    (videos / name).write_bytes(b"the run's own")
    line = error_line(capsys, ["export", str(run), "--format", "npz", "--out", str(videos / name)])
    assert f"cannot write {videos / name}" in line and "give another path" in line
    assert (videos / name).read_bytes() == b"the run's own"


def test_the_run_videos_take_new_videos(run, capsys):
    from canter.cli.main import main

    videos = run / "videos"
    videos.mkdir()
    # The trainer's own renderer writes each new step video through the same guards.
    check_writable(videos / "step_000000009999.mp4")
    assert main(["export", str(run), "--format", "npz", "--out", str(videos / "mine.npz")]) == 0
    assert main(["export", str(run), "--format", "npz", "--out", str(videos / "mine.npz")]) == 0  # the user's own
    assert (videos / "mine.npz").is_file()


# ------------------------------------------------------------------------------------ refused resumes


def test_a_resume_refused_for_a_corrupt_best_leaves_the_folder_as_it_was(run, capsys):
    best = run / "checkpoints" / "best.npz"
    best.write_bytes(b"not a checkpoint")
    before = contents(run)
    for _ in range(2):
        line = error_line(capsys, ["train", "--resume", str(run), "--total-steps", "8192", "--quiet"])
        assert str(best) in line and "corrupt" in line
        assert contents(run) == before


@pytest.mark.parametrize("name", ["summary.json", "config.toml", "metrics.csv", "versions.json"])
def test_a_resume_refuses_a_folder_where_a_run_file_belongs(run, capsys, name):
    (run / name).unlink()
    (run / name).mkdir()
    before = contents(run)
    line = error_line(capsys, ["train", "--resume", str(run), "--total-steps", "8192", "--quiet"])
    assert line == f"{run / name} is a folder, where the run keeps its {name} file; move it out of the way, then resume"
    assert contents(run) == before  # refused before any training: no new checkpoint or row
    assert "has no config.toml" not in capsys.readouterr().err


@pytest.mark.parametrize("command", [["plot", "{run}", "--out", "c.png"], ["report", "{run}", "--out", "r.html"]])
def test_a_reader_names_a_folder_where_the_config_belongs(run, capsys, tmp_path, monkeypatch, command):
    monkeypatch.chdir(tmp_path)
    (run / "config.toml").unlink()
    (run / "config.toml").mkdir()
    line = error_line(capsys, [arg.format(run=run) for arg in command])
    folder = run / "config.toml"
    assert line == f"{folder} is a folder, where the run keeps its config.toml file; move it out of the way"


@pytest.mark.parametrize("command", [["train", "Pendulum-v1"], ["tune", "Pendulum-v1", "--trials", "1"]])
def test_a_run_folder_is_refused_as_the_folder_for_new_ones(run, capsys, command):
    before = contents(run)
    line = error_line(capsys, [*command, "--out-dir", str(run), "--total-steps", "2048"])
    python = " (run.out_dir from Python)" if command[0] == "train" else ""  # tune is a command only
    assert line == (
        f"--out-dir {run} is a run folder, and new folders would be made among its own files; give another "
        f"--out-dir{python}"
    )
    assert contents(run) == before


# ------------------------------------------------------------------------------------ atomic writes


def test_an_atomic_write_onto_a_folder_names_the_folder(tmp_path):
    target = tmp_path / "summary.json"
    target.mkdir()
    with pytest.raises(IsADirectoryError) as raised:
        atomic_write_bytes(target, lambda f: f.write(b"{}"))
    assert raised.value.filename == str(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]


def test_a_folder_made_during_an_atomic_write_is_named_not_the_temp_file(tmp_path):
    target = tmp_path / "summary.json"

    def write_while_a_folder_appears(f):
        f.write(b"{}")
        target.mkdir()

    with pytest.raises(OSError) as raised:
        atomic_write_bytes(target, write_while_a_folder_appears)
    assert raised.value.errno == errno.EISDIR and raised.value.filename == str(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]  # no temp file is left
