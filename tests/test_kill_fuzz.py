"""SIGKILL at random points of the trainer's writes loses nothing: after each kill every checkpoint that is listed
loads and passes its hash check, metrics.csv parses, and the run resumes.

A writer process does nothing but what the trainer writes, as fast as it can: metrics rows (metrics.csv and
TensorBoard), a checkpoint every two rows, pruning, and on start the rewrite of metrics.csv that a resume does. So
a kill at a random moment lands inside one of those writes; every other kill is aimed at a checkpoint write, so
that some land inside one however fast the machine is. Writers are forked from a process that has imported
JAX and loaded the state once, so that a trial costs milliseconds, not a JAX start.
"""

from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from canter.training import checkpoint, run_folder, run_lock
from canter.training.logger import read_rows

pytestmark = pytest.mark.slow

FIXTURE = Path(__file__).parent / "fixtures" / "runs-v1" / "ppo"
FIXTURE_STEP = 1190  # the fixture's newest checkpoint
TRIALS = 24

# Reads "fork" lines on stdin; for each, forks a writer of RUN and prints its pid; "reap PID" waits for it.
ZYGOTE = r"""
import os, sys, warnings
from pathlib import Path
warnings.simplefilter("ignore")
from canter.training import checkpoint, run_folder, run_lock
from canter.training.logger import MetricsLogger
from canter.algos import get_algorithm
from canter.training.restore import load_state

run = Path(sys.argv[1])
config, _, state, header = load_state(run)
header = {k: v for k, v in header.items() if k not in ("sha256", "leaves", "format_version")}
columns = (get_algorithm(config.run.algo).metric_names, tuple(header["env"]["info_keys"]))


def write_forever():
    run_lock.acquire(run)
    step = int(checkpoint.read_header(checkpoint.latest(run))["global_step"])
    logger = MetricsLogger(run, *columns, tensorboard=True, resume_step=step)
    while True:
        for _ in range(2):
            step += 100
            logger.log(dict(global_step=step, iteration=step // 100, wall_time=step / 1000, sps=1000.0,
                            episodes=1, episodic_return=step / 100, episodic_length=100.0))
        totals = dict(wall_seconds=step / 1000, train_seconds=step / 1000, episodes=step // 100)
        checkpoint.save(run_folder.checkpoint_path(run, step), state, dict(header, global_step=step, totals=totals))
        checkpoint.prune(run, 2)


print("ready", flush=True)
for line in sys.stdin:
    command = line.split()
    if command[0] == "fork":
        pid = os.fork()
        if pid == 0:
            try:
                write_forever()
            finally:
                os._exit(1)
        print(pid, flush=True)
    elif command[0] == "reap":
        os.waitpid(int(command[1]), 0)
        print("reaped", flush=True)
"""


def _wait_for_a_checkpoint_write(run: Path, after_one_lands: bool) -> None:
    """Returns as soon as a checkpoint's temp file exists. How many random kills land inside a write depends on the
    machine's speed, so half the kills are aimed at one. With `after_one_lands`, only once the writer has finished
    a checkpoint of its own: on a loaded machine the random kills can all come before a writer's first checkpoint,
    and the aimed ones all inside it, so that no writer would go on from the last one."""
    folder = run / "checkpoints"
    newest = run_folder.list_checkpoints(run)[-1].name
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        names = os.listdir(folder)
        if after_one_lands and max(n for n in names if n.startswith("ckpt_")) > newest:
            after_one_lands = False
        if not after_one_lands and any(name.startswith(".") and name.endswith(".tmp") for name in names):
            return
    raise AssertionError("the writer wrote no checkpoint for 30 s")


def _check_after_a_kill(run: Path) -> tuple[int, bool]:
    """The newest checkpoint's step, and whether the kill left a half-written file, after checking the folder."""
    half_written = any(run.glob("checkpoints/.*.tmp")) or any(run.glob(".*.tmp"))
    listed = run_folder.list_checkpoints(run)
    assert listed, "the first checkpoint is never lost"
    for path in listed:
        checkpoint.read(path)  # loads and passes its hash check
    _, rows = read_rows(run / "metrics.csv")
    steps = [int(r["global_step"]) for r in rows]
    assert steps == sorted(set(steps)), "each step once"
    written = [r for r in rows if int(r["global_step"]) > FIXTURE_STEP]  # the writers' rows, whole
    assert all(float(r["episodic_return"]) == int(r["global_step"]) / 100 for r in written)
    # What a resume does first: take the lock (the killed writer's is released by the OS; its half-written files
    # go), and read the newest checkpoint.
    run_lock.acquire(run)
    run_lock.release(run)
    assert not any(run.glob("checkpoints/.*.tmp")) and not any(run.glob(".*.tmp"))
    step = int(checkpoint.read_header(listed[-1])["global_step"])
    return step, half_written


def test_sigkill_during_checkpoint_and_metrics_writes_loses_nothing(tmp_path):
    from canter.training.loop import train
    from canter.training.restore import load_state
    from canter.training.resume import resume_config

    run = tmp_path / "run"
    shutil.copytree(FIXTURE, run)
    zygote = subprocess.Popen(
        [sys.executable, "-c", ZYGOTE, str(run)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    assert zygote.stdin is not None and zygote.stdout is not None
    rng = random.Random(28)
    steps, half_written = [], 0
    try:
        assert zygote.stdout.readline() == "ready\n"
        for trial in range(TRIALS):
            zygote.stdin.write("fork\n")
            zygote.stdin.flush()
            pid = int(zygote.stdout.readline())
            if trial % 2:
                _wait_for_a_checkpoint_write(run, after_one_lands=trial % 4 == 3)
            else:
                time.sleep(rng.uniform(0.03, 0.25))
            os.kill(pid, signal.SIGKILL)
            zygote.stdin.write(f"reap {pid}\n")
            zygote.stdin.flush()
            assert zygote.stdout.readline() == "reaped\n"
            step, half = _check_after_a_kill(run)
            steps.append(step)
            half_written += half
    finally:
        zygote.kill()
        zygote.wait()
    assert steps == sorted(steps) and steps[-1] > steps[0], "each writer went on from the last checkpoint"
    assert half_written >= 3, f"only {half_written} of {TRIALS} kills landed inside a checkpoint write"

    # The folder after the last kill resumes for real, and its metrics.csv then holds each step once.
    _, _, _, header = load_state(run)
    total = int(header["global_step"]) + 512
    result = train(resume_config(run, total), resume=run)
    assert result.global_step >= total
    _, rows = read_rows(run / "metrics.csv")
    logged = [int(r["global_step"]) for r in rows]
    assert logged == sorted(set(logged))
