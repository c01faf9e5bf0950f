"""Stopping a bench's or a tune's jobs: every job gets SIGTERM at once and the time to write its checkpoint, and only
one still running when the shared grace period ends is killed."""

import subprocess
import sys
import time

from canter.orchestrate.jobs import stop_jobs

# A job that, on SIGTERM, takes `delay` seconds to "write its checkpoint", writes it and exits 0.
GRACEFUL = """
import pathlib, signal, sys, time
def stop(*_):
    time.sleep(float(sys.argv[2]))
    pathlib.Path(sys.argv[1]).write_text("checkpoint")
    sys.exit(0)
signal.signal(signal.SIGTERM, stop)
print("ready", flush=True)
time.sleep(60)
"""
STUBBORN = """
import signal, time
signal.signal(signal.SIGTERM, signal.SIG_IGN)
print("ready", flush=True)
time.sleep(60)
"""


def _start(code: str, *args: str) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"  # its handler is installed
    return proc


def test_jobs_stop_together_and_keep_their_checkpoints(tmp_path):
    checkpoints = [tmp_path / f"job{i}" for i in range(3)]
    jobs = [_start(GRACEFUL, str(path), "1.5") for path in checkpoints]
    started = time.monotonic()
    stop_jobs(jobs, grace_seconds=10)
    took = time.monotonic() - started
    assert [job.returncode for job in jobs] == [0, 0, 0]
    assert all(path.read_text() == "checkpoint" for path in checkpoints)
    assert took < 4.5  # signalled together: about one job's 1.5 s, not three after one another


def test_a_job_that_does_not_stop_is_killed_when_the_shared_grace_ends(tmp_path):
    stubborn = _start(STUBBORN)
    slow = _start(GRACEFUL, str(tmp_path / "slow"), "30")
    quick = _start(GRACEFUL, str(tmp_path / "quick"), "0.2")
    started = time.monotonic()
    stop_jobs([stubborn, slow, quick], grace_seconds=2)
    took = time.monotonic() - started
    assert stubborn.returncode == -9 and slow.returncode == -9  # killed
    assert quick.returncode == 0 and (tmp_path / "quick").read_text() == "checkpoint"
    assert not (tmp_path / "slow").exists()
    assert 2 <= took < 5  # one grace period for all of them, not one each


def test_finished_jobs_are_left_alone():
    done = subprocess.Popen([sys.executable, "-c", "pass"])
    done.wait()
    stop_jobs([done], grace_seconds=1)
    assert done.returncode == 0
