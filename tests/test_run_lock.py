"""One writer per run folder: a second writer is refused naming the holder, a killed holder's lock is taken over,
and readers never need the lock."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from canter.cli.main import main
from canter.errors import CanterError
from canter.training import run_lock

FIXTURE = Path(__file__).parent / "fixtures" / "runs-v1" / "ppo"


def _wait_for_holder(run_dir: Path, pid: int, proc: subprocess.Popen, seconds: float = 120) -> None:
    deadline = time.monotonic() + seconds
    while run_lock.read_holder(run_dir).get("pid") != pid:
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else "the holder exited"
        assert time.monotonic() < deadline, "the holder never took the lock"
        time.sleep(0.05)


def _wait_for_training_past(run_dir: Path, step: int, proc: subprocess.Popen, seconds: float = 180) -> None:
    """Until the holder has logged a row beyond `step`: by then it has cut metrics.csv back to its checkpoint and
    rewritten an older header to its own columns, so what the file holds changes only by appended rows."""
    deadline = time.monotonic() + seconds
    while True:
        last = (run_dir / "metrics.csv").read_text().strip().rsplit("\n", 1)[-1].split(",", 1)[0]
        if last.isdigit() and int(last) > step:
            return
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else "the holder exited"
        assert time.monotonic() < deadline, f"the holder logged nothing beyond step {step}"
        time.sleep(0.1)


def _hold_in_child(run_dir: Path) -> subprocess.Popen:
    program = f"from canter.training import run_lock; run_lock.acquire({str(run_dir)!r}); import time; time.sleep(600)"
    proc = subprocess.Popen([sys.executable, "-c", program], stderr=subprocess.PIPE, text=True)
    _wait_for_holder(run_dir, proc.pid, proc)
    return proc


def test_the_lock_is_reentrant_and_a_folder_left_empty_is_removed(tmp_path):
    run = tmp_path / "run"
    with run_lock.RunLocks() as locks:
        locks.take(run)
        locks.take(run)  # a job holds its folder, and the trainer it calls takes it again
        assert run_lock.read_holder(run)["pid"] == os.getpid()
    assert not run.exists(), "a run that wrote nothing leaves no folder"
    with run_lock.RunLocks() as locks:
        locks.take(run)
        (run / "config.toml").write_text("")
    assert sorted(p.name for p in run.iterdir()) == [run_lock.LOCK_FILE, "config.toml"]
    run_lock.acquire(run)  # released: this process takes it again
    run_lock.release(run)


def test_taking_a_folder_over_removes_every_half_written_file_and_nothing_whole(tmp_path):
    """A killed writer leaves the temp files of its atomic writes: of a run file, a checkpoint, the best state, a
    video snapshot and a video. A whole snapshot stays, for the resume to render its video."""
    import tempfile

    run = tmp_path / "run"
    whole = ["config.toml", "checkpoints/ckpt_000000001000.npz", "videos/.snapshot_000000001000.npz", "videos/a.mp4"]
    for name in whole:
        (run / name).parent.mkdir(parents=True, exist_ok=True)
        (run / name).write_text("")
    # The names canter.files.atomic_write_bytes and canter.use.video_file's temp videos give their temp files.
    targets = ["config.toml", "checkpoints/ckpt_000000002000.npz", "checkpoints/best.npz", "videos/.snapshot_2.npz"]
    halves = [tempfile.mkstemp(prefix=f".{Path(t).name}.", suffix=".tmp", dir=run / Path(t).parent) for t in targets]
    halves.append(tempfile.mkstemp(prefix=".step_000000002000.", suffix=".tmp.mp4", dir=run / "videos"))
    for fd, _ in halves:
        os.close(fd)
    run_lock.acquire(run)
    run_lock.release(run)
    left = sorted(str(p.relative_to(run)) for p in run.rglob("*") if p.is_file() and p.name != run_lock.LOCK_FILE)
    assert left == sorted(whole)


def test_a_run_that_wrote_nothing_also_removes_the_out_dir_made_for_it_and_keeps_what_was_there(tmp_path):
    out = tmp_path / "made" / "runs"
    run_a, run_b = out / "a", out / "b"
    with run_lock.RunLocks() as locks:
        locks.take(run_a)  # makes made/ and made/runs/
        locks.take(run_b)
    assert not (tmp_path / "made").exists()

    with run_lock.RunLocks() as locks:
        locks.take(run_a)
        locks.take(run_b)
        (run_b / "config.toml").write_text("")
    assert sorted(p.name for p in out.iterdir()) == ["b"], "a sibling that was written keeps the folders above"


def test_the_cli_leaves_no_folder_behind_for_a_run_refused_at_setup(tmp_path):
    out = tmp_path / "new" / "runs"
    code = main(["train", "CartPole-v1", "--algo", "trpo", "--total-steps", "2048", "--out-dir", str(out)])
    assert code == 2
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_a_second_writer_is_refused_and_a_killed_holder_is_taken_over(tmp_path):
    run = tmp_path / "run"
    holder = _hold_in_child(run)
    try:
        with pytest.raises(CanterError, match=rf"{run} is being written by process {holder.pid} on "):
            run_lock.acquire(run)
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    run_lock.acquire(run)  # the OS released the dead process's lock
    assert run_lock.read_holder(run)["pid"] == os.getpid()
    run_lock.release(run)


@pytest.mark.slow
def test_a_second_resume_is_refused_with_one_line_while_readers_go_on(tmp_path, capsys):
    """The issue's case: two `canter train --resume RUN` at once. The second is refused naming the first; export
    and eval read the folder meanwhile."""
    run = tmp_path / "run"
    shutil.copytree(FIXTURE, run)
    first = subprocess.Popen(
        [sys.executable, "-m", "canter.cli", "train", "--resume", str(run), "--total-steps", "10000000", "--quiet"],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        _wait_for_holder(run, first.pid, first)
        fixture_rows = (FIXTURE / "metrics.csv").read_text().strip().split("\n")
        _wait_for_training_past(run, int(fixture_rows[-1].split(",", 1)[0]), first)
        rows_before = (run / "metrics.csv").read_text()
        assert main(["train", "--resume", str(run), "--total-steps", "20000000", "--quiet"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"is being written by process {first.pid} on " in err
        assert ": canter train --resume " in err, "the message names the command that holds the folder"
        assert (run / "metrics.csv").read_text().startswith(rows_before), "the refused resume left the rows alone"

        assert main(["export", str(run), "--out", str(tmp_path / "policy.onnx")]) == 0
        assert main(["eval", str(run), "--episodes", "1", "--json", str(tmp_path / "eval.json")]) == 0
        assert json.loads((tmp_path / "eval.json").read_text())["runs"]
    finally:
        first.send_signal(signal.SIGTERM)
        first.wait(120)
    # Stopped while training (a checkpoint and exit 0) or still setting up (SIGTERM's default action).
    assert first.returncode in (0, -signal.SIGTERM), first.stderr.read() if first.stderr else ""


OUT_OF_FILES = """
import os, resource, sys
from pathlib import Path
from canter.errors import CanterError
from canter.training import run_lock

out, case = Path(sys.argv[1]), sys.argv[2]
resource.setrlimit(resource.RLIMIT_NOFILE, (64, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))
spare = []
try:
    with run_lock.RunLocks() as locks:
        for i in range(200 if case == "take" else 3):
            locks.take(out / f"run{i}")
        while case == "release":  # the locks are released with no descriptor free
            spare.append(os.open(os.devnull, os.O_RDONLY))
except CanterError as exc:
    print(exc)
except OSError:
    for fd in spare:
        os.close(fd)
print("left:", sorted(p.name for p in out.parent.iterdir()))
"""


@pytest.mark.slow
def test_running_out_of_open_files_while_locking_is_one_line_and_removes_the_folders_made(tmp_path):
    done = subprocess.run(
        [sys.executable, "-c", OUT_OF_FILES, str(tmp_path / "runs"), "take"], capture_output=True, text=True
    )
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    error, left = done.stdout.strip().splitlines()
    assert error.startswith("this process ran out of open files after locking ")
    assert error.endswith(
        "(ulimit -n is 64); use fewer at once (fewer seeds), or raise the limit first, e.g. `ulimit -n 128`"
    )
    assert left == "left: []", "no run folder, nor the runs/ folder made for them, is left"


@pytest.mark.slow
def test_locks_released_with_no_descriptor_free_still_remove_the_folders_they_made(tmp_path):
    done = subprocess.run(
        [sys.executable, "-c", OUT_OF_FILES, str(tmp_path / "runs"), "release"], capture_output=True, text=True
    )
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert done.stdout.strip() == "left: []"
