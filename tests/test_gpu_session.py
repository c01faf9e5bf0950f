"""benchmarks/gpu/session.sh: the parts of one device call fit the call's time (SESSION_SECONDS), and what a part
left is packed. Tested with a stand-in run.sh, since a call the device kills brings back only its log."""

import json
import shutil
import subprocess
import tarfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Records the limit `timeout` gave it (as the part's argument list cannot), sleeps, and leaves a file to pack.
STAND_IN = """#!/usr/bin/env bash
echo "$1 started" >>"$OUT/parts.txt"
echo "figures of $1" >"$OUT/$1.md"
sleep "${SLEEP:-0}"
"""


def session(tmp_path: Path, *parts: str, **env: str) -> tuple[str, Path]:
    tree = tmp_path / "tree"
    (tree / "benchmarks" / "gpu").mkdir(parents=True)
    shutil.copy(ROOT / "benchmarks" / "gpu" / "session.sh", tree / "benchmarks" / "gpu" / "session.sh")
    (tree / "benchmarks" / "gpu" / "run.sh").write_text(STAND_IN)
    (tree / "benchmarks" / "gpu" / "summarize.py").write_text("")
    out = tmp_path / "out"
    done = subprocess.run(
        ["bash", str(tree / "benchmarks" / "gpu" / "session.sh"), *parts],
        env={"PATH": "/usr/bin:/bin", "OUT": str(out), **env},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    return (out / "session.log").read_text(), out


def test_a_part_that_would_outlast_the_call_is_shortened_and_one_with_no_time_left_is_skipped(tmp_path):
    log, out = session(tmp_path, "smoke:200", "seeds:100", SESSION_SECONDS="150", KILL_AFTER="5")
    # 150 s less KILL_AFTER (5) and the packing (20) leaves 125 s: smoke's 200 is cut; seeds' 100 fits after it.
    assert "== smoke: limit 200 s cut to 125 s to end within SESSION_SECONDS=150" in log
    assert "== seeds  (limit 100 s" in log
    # 88 s leaves smoke 63; smoke takes 4, which leaves seeds 59, less than a minute: skipped, smoke still packed.
    log, out = session(tmp_path / "again", "smoke:30", "seeds:30", SESSION_SECONDS="88", KILL_AFTER="5", SLEEP="4")
    assert "== smoke  (limit 30 s" in log and "== seeds skipped:" in log
    with tarfile.open(out / "session.tgz") as packed:
        assert "./smoke.md" in packed.getnames()
        assert packed.extractfile("./parts.txt").read().decode() == "smoke started\n"


def test_without_session_seconds_every_part_keeps_its_limit(tmp_path):
    log, out = session(tmp_path, "smoke:30", "seeds:40")
    assert "== smoke  (limit 30 s" in log and "== seeds  (limit 40 s" in log and "cut to" not in log
    with tarfile.open(out / "session.tgz") as packed:
        assert {"./smoke.md", "./seeds.md"} <= set(packed.getnames())


@pytest.mark.slow
def test_a_part_stopped_by_its_limit_keeps_the_time_of_the_process_it_cut(tmp_path):
    """session.sh's `timeout` sends SIGTERM to run.sh's whole process group; the part records the process it waited
    for as stopped, with its time, and starts no other."""
    import os
    import signal
    import sys
    import time

    out = tmp_path / "out"
    env = {
        **os.environ,
        "OUT": str(out),
        "CANTER_GPU_SMOKE": "1",
        "CANTER_GPU_INSTALL": "0",
        "PYTHON": sys.executable,
        "PYTHONPATH": os.pathsep.join(sys.path),
    }
    proc = subprocess.Popen(
        ["bash", str(ROOT / "benchmarks" / "gpu" / "run.sh"), "smoke"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 240
        settings = out / "smoke.settings"
        while not (settings.is_file() and "canter train" in settings.read_text()):
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.5)
        time.sleep(3)  # inside the timed `canter train`
        os.killpg(proc.pid, signal.SIGTERM)
        assert proc.wait(timeout=120) == 143
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    [record] = [json.loads(line) for line in (out / "smoke.times").read_text().splitlines()]
    assert record["label"] == "smoke" and record["stopped"] is True and record["seconds"] > 3
    assert "run.sh: stopped by SIGTERM" in (out / "smoke.log").read_text()
