"""A named pipe or a folder where canter reads or appends a file (a run's metrics.csv, a log) is refused at once:
opening a pipe would wait for a process at its other end that never comes, and the run would hang unstoppably."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest

from canter.errors import CanterError
from canter.files import AppendFile
from canter.training.logger import read_rows

PIPE_REFUSED = "is not a regular file (a device, pipe or socket); move it away and restore"


@pytest.fixture
def pipe(tmp_path):
    path = tmp_path / "metrics.csv"
    os.mkfifo(path)
    return path


def test_appending_to_a_pipe_nobody_reads_is_refused_without_waiting(pipe):
    with pytest.raises(CanterError, match="not a regular file") as error:
        AppendFile(pipe)
    assert str(error.value) == f"{pipe} {PIPE_REFUSED} metrics.csv from a copy"


def test_appending_to_a_pipe_that_a_process_reads_is_refused_too(pipe):
    reader = os.open(pipe, os.O_RDONLY | os.O_NONBLOCK)  # with a reader, the open itself succeeds
    try:
        with pytest.raises(CanterError, match="not a regular file"):
            AppendFile(pipe)
    finally:
        os.close(reader)


def test_appending_to_a_folder_names_it_a_folder(tmp_path):
    (tmp_path / "log.txt").mkdir()
    with pytest.raises(CanterError, match=r"log.txt is a folder, not a file; move it away"):
        AppendFile(tmp_path / "log.txt")


def test_a_regular_file_is_appended_to_as_before(tmp_path):
    log = AppendFile(tmp_path / "log.txt")
    log.append(b"a\n")
    log.append(b"b\n")
    log.close()
    assert (tmp_path / "log.txt").read_bytes() == b"a\nb\n"


def test_reading_the_rows_of_a_pipe_is_refused(pipe):
    with pytest.raises(CanterError, match="not a regular file"):
        read_rows(pipe)
    assert read_rows(pipe.parent / "missing.csv") == ([], [])


def test_a_dangling_link_reads_as_a_missing_file_and_an_append_creates_its_target(tmp_path):
    (tmp_path / "metrics.csv").symlink_to(tmp_path / "target.csv")
    assert read_rows(tmp_path / "metrics.csv") == ([], [])
    log = AppendFile(tmp_path / "metrics.csv")
    log.append(b"global_step\n")
    log.close()
    assert (tmp_path / "target.csv").read_bytes() == b"global_step\n"


def test_a_resume_whose_metrics_csv_is_a_pipe_stops_with_one_line(tiny_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(tiny_run.run_dir, run)
    (run / "metrics.csv").unlink()
    os.mkfifo(run / "metrics.csv")
    argv = [sys.executable, "-m", "canter.cli", "train", "--resume", str(run), "--total-steps", "16384"]
    # A subprocess with a deadline: the fault this guards against is a process that never ends.
    done = subprocess.run(argv, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert done.stderr == f"canter: error: {run / 'metrics.csv'} {PIPE_REFUSED} metrics.csv from a copy\n"
