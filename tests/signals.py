"""Send this process SIGTERM from a watcher thread once training is under way, to test graceful stops."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from pathlib import Path


def logged_rows(run_dir: Path) -> int:
    metrics = run_dir / "metrics.csv"
    return len(metrics.read_text().splitlines()) if metrics.is_file() else 0


@contextlib.contextmanager
def sigterm_once_logging(out_dir: Path, runs: int):
    """SIGTERM once `runs` run folders under `out_dir` each have two logged iterations, so the signal lands inside
    the training loop rather than during setup or compilation."""
    finished = threading.Event()

    def watch():
        while not finished.is_set():
            folders = [p for p in out_dir.iterdir() if p.is_dir()]
            if len(folders) == runs and all(logged_rows(p) >= 3 for p in folders):
                os.kill(os.getpid(), signal.SIGTERM)
                return
            time.sleep(0.05)

    threading.Thread(target=watch, daemon=True).start()
    try:
        yield
    finally:
        finished.set()


class SignalNotHeld(Exception):
    """Raised by the SIGTERM handler that `sigterm_during_setup` puts in place of the default action, which would end
    pytest itself: the signal reached it rather than canter's StopFlag."""


@contextlib.contextmanager
def sigterm_during_setup():
    """SIGTERM this process each time a run has made its env, after its folder exists and before its compile."""
    from canter.training import loop

    make_env = loop._make_env

    def make_env_then_sigterm(*args):
        env = make_env(*args)
        os.kill(os.getpid(), signal.SIGTERM)
        return env

    def not_held(signum, frame):
        raise SignalNotHeld

    loop._make_env = make_env_then_sigterm
    previous = signal.signal(signal.SIGTERM, not_held)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
        loop._make_env = make_env


# Runs a command with SIGINT ignored or not (SIG_IGN or SIG_DFL, as a number), whatever this process has: exec keeps
# both. A preexec_fn would do it too, but JAX warns of the fork. (A test run from a script's background job starts
# with SIGINT ignored, and so would every process it starts.)
WITH_SIGINT = (
    "import os, signal, sys; signal.signal(signal.SIGINT, signal.Handlers(int(sys.argv[1]))); "
    "os.execv(sys.argv[2], sys.argv[2:])"
)


def with_sigint(argv: list[str], sigint: signal.Handlers = signal.SIG_DFL) -> list[str]:
    """`argv` (its first item an executable's path) started with SIGINT handled as `sigint`."""
    return [sys.executable, "-c", WITH_SIGINT, str(int(sigint)), *argv]
