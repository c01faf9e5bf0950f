"""SIGHUP (a dropped ssh session, a closed terminal) stops a command as SIGTERM does, and a stop signal that lands
once a run has finished leaves it finished. The training tests run `canter train` with a hook that signals the process
from inside, so the moment is exact rather than a matter of timing."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from canter.orchestrate.jobs import sigterm_interrupts
from canter.signals import StopFlag
from canter.training.restore import load_state
from signals import SignalNotHeld

TINY_TRAIN = ["train", "Pendulum-v1", "--set", "env.num_envs=4", "--set", "net.hidden=16,16", "--out-dir", "runs"]
# As a command starts from a terminal, whatever this test process ignores: SIGINT and SIGHUP act.
AS_FROM_A_TERMINAL = """
import os, signal, sys
signal.signal(signal.SIGINT, signal.default_int_handler)
signal.signal(signal.SIGHUP, signal.SIG_DFL)
"""
# Once the first iteration is logged.
AFTER_THE_FIRST_ROW = """
from canter.training.seed_run import SeedRun
record = SeedRun.record
done = []
def record_then(self, *args, **kwargs):
    row = record(self, *args, **kwargs)
    if not done:
        done.append(True)
        {action}
    return row
SeedRun.record = record_then
"""
CANTER_ENTRY = """
sys.argv = ["canter", *sys.argv[1:]]
from canter.cli.main import entry
entry()
"""


def _canter(hook: str, argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """The console command `canter argv`, with `hook` (Python) run before it."""
    script = AS_FROM_A_TERMINAL + hook + CANTER_ENTRY
    return subprocess.run([sys.executable, "-c", script, *argv], cwd=cwd, capture_output=True, text=True, timeout=120)


def _summary(cwd: Path) -> dict:
    (run,) = (cwd / "runs").iterdir()
    return json.loads((run / "summary.json").read_text())


def _not_held(signum, frame):
    raise SignalNotHeld


def test_sighup_is_held_as_sigterm_is_and_left_ignored_under_nohup():
    """SIGHUP ended canter at once: a run lost everything since its last checkpoint, and a bench or tune worker left
    its trial running in the study."""
    previous = signal.signal(signal.SIGHUP, _not_held)  # the default action would end pytest
    try:
        with StopFlag() as stop:
            os.kill(os.getpid(), signal.SIGHUP)
        assert stop.signal == signal.SIGHUP
        assert signal.getsignal(signal.SIGHUP) is _not_held
        with pytest.raises(KeyboardInterrupt), sigterm_interrupts():
            os.kill(os.getpid(), signal.SIGHUP)
        signal.signal(signal.SIGHUP, signal.SIG_IGN)  # `nohup canter ...`: the hangup is not meant to stop it
        with StopFlag() as kept_on:
            os.kill(os.getpid(), signal.SIGHUP)
        assert kept_on.signal is None
    finally:
        signal.signal(signal.SIGHUP, previous)


@pytest.mark.slow
def test_sighup_stops_canter_train_with_a_checkpoint_and_exit_0(tmp_path):
    hook = AFTER_THE_FIRST_ROW.format(action="os.kill(os.getpid(), signal.SIGHUP)")
    done = _canter(hook, [*TINY_TRAIN, "--total-steps", "2000000", "--quiet"], tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "canter: SIGHUP: stopping at the next safe point" in done.stderr
    assert "stopped: signal" in done.stdout
    summary = _summary(tmp_path)
    assert summary["stop_reason"] == "signal" and summary["global_step"] < 2_000_000
    _, _, _, header = load_state(Path(summary["run_dir"]))
    assert int(header["global_step"]) == summary["global_step"]


@pytest.mark.slow
def test_a_terminal_that_hangs_up_stops_training_with_a_checkpoint_and_ends_quietly(tmp_path):
    """A closed terminal sends SIGHUP, and every write to it fails from then on (EIO): the progress bar's last draw
    read as a write error of the run folder, and the report's line as a crash."""
    terminal = """
import select, threading
master, terminal = os.openpty()
os.dup2(terminal, 1)  # stdout is the terminal, with its progress bar; stderr stays the test's
reading = threading.Event()
reading.set()
def read_the_terminal():
    while reading.is_set():
        if select.select([master], [], [], 0.05)[0]:
            os.read(master, 65536)
reader = threading.Thread(target=read_the_terminal, daemon=True)
reader.start()
def hang_up():
    reading.clear()
    reader.join()
    os.close(master)
    os.kill(os.getpid(), signal.SIGHUP)
"""
    hook = terminal + AFTER_THE_FIRST_ROW.format(action="hang_up()")
    done = _canter(hook, [*TINY_TRAIN, "--total-steps", "2000000"], tmp_path)
    assert done.returncode == 1, done.stderr[-2000:]  # as any command whose stdout is gone
    assert done.stderr == "canter: SIGHUP: stopping at the next safe point, with a checkpoint to resume from\n"
    summary = _summary(tmp_path)
    assert summary["stop_reason"] == "signal"
    _, _, _, header = load_state(Path(summary["run_dir"]))
    assert int(header["global_step"]) == summary["global_step"]


@pytest.mark.slow
def test_a_stop_signal_once_the_run_finished_leaves_it_finished(tmp_path, monkeypatch, capsys):
    """A signal that landed after training's StopFlag ended, as the run closed, ended a finished run as a killed
    (143) or interrupted (130) one, although its summary.json said it finished."""
    from canter.cli import train as train_command
    from canter.cli.main import main

    report = train_command._report

    def signalled_then_report(results):
        for sig in (signal.SIGHUP, signal.SIGTERM, signal.SIGINT):
            os.kill(os.getpid(), sig)
        report(results)

    monkeypatch.setattr(train_command, "_report", signalled_then_report)
    # Handlers of this process's own, which the command puts back as it returns; SIG_DFL would end pytest.
    own = {signal.SIGHUP: _not_held, signal.SIGTERM: _not_held, signal.SIGINT: signal.default_int_handler}
    before = {sig: signal.signal(sig, handler) for sig, handler in own.items()}
    try:
        code = main([*TINY_TRAIN, "--total-steps", "2048", "--quiet"])
        handlers = {sig: signal.getsignal(sig) for sig in own}
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)
    assert code == 0 and "stopped: budget" in capsys.readouterr().out
    assert handlers == own


@pytest.mark.slow
def test_a_stop_signal_as_the_process_ends_leaves_the_commands_exit_code(tmp_path):
    """The interpreter's shutdown after a finished run (JAX's teardown) took long enough for a SIGTERM to end the
    process as killed (143)."""
    hook = """
import atexit
def stop_signals():
    for sig in (signal.SIGHUP, signal.SIGTERM, signal.SIGINT):
        os.kill(os.getpid(), sig)
atexit.register(stop_signals)
"""
    done = _canter(hook, [*TINY_TRAIN, "--total-steps", "2048", "--quiet"], tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    assert _summary(tmp_path)["stop_reason"] == "budget"
