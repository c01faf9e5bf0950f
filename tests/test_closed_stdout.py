"""A stdout that nobody reads any more (`canter eval RUN | head -1`) ends a command quietly with exit 1, as Python's
own recipe does, and never before the command's files are written and closed."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator

import optuna
import pytest
from optuna.trial import TrialState

from canter import signals
from canter.cli import main as cli
from canter.config.build import build_config
from canter.orchestrate.study import FAIL_REASON, Outcome, StorageSettings, open_storage, run_worker
from canter.orchestrate.tune import announced
from canter.training import loop
from canter.training.progress import Progress
from canter.training.seed_run import SeedRun
from conftest import TINY
from test_tune import tiny_args

CANTER = [sys.executable, "-m", "canter.cli"]
TINY_TRAIN = ["train", "Pendulum-v1", "--total-steps", "2048", "--set", "env.num_envs=4", "--set", "net.hidden=16,16"]


@contextlib.contextmanager
def closed_pipe() -> Iterator[int]:
    """The write end of a pipe whose reader is gone, as `| head -0` leaves one."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        yield write_end
    finally:
        os.close(write_end)


def _canter_to_a_closed_stdout(argv: list[str], buffered: bool) -> subprocess.CompletedProcess:
    """`canter argv` with its stdout a closed pipe: `buffered` as Python buffers a pipe, else line by line (as
    PYTHONUNBUFFERED has it), so that a print itself fails."""
    env = {key: value for key, value in os.environ.items() if key != "PYTHONUNBUFFERED"}
    env |= {} if buffered else {"PYTHONUNBUFFERED": "1"}
    with closed_pipe() as stdout:
        return subprocess.run([*CANTER, *argv], stdout=stdout, stderr=subprocess.PIPE, text=True, env=env, timeout=120)


def test_the_console_entry_ends_quietly_where_nothing_reads_stdout(monkeypatch):
    """Output still buffered when the command returns failed in the interpreter's shutdown, which printed an error
    and exited 120; a broken pipe of canter's own, while stdout is read, is a bug and keeps its traceback."""
    handlers = {sig: signal.getsignal(sig) for sig in signals.STOP_SIGNALS}
    read_end, write_end = os.pipe()
    try:
        with closed_pipe() as closed, open(closed, "w", closefd=False) as stdout:
            monkeypatch.setattr(sys, "stdout", stdout)
            monkeypatch.setattr(cli, "main", lambda: print("a table") or 0)
            with pytest.raises(SystemExit) as exited:
                cli.entry()
            assert exited.value.code == 1

        def broken_pipe():
            raise BrokenPipeError

        with open(write_end, "w", closefd=False) as stdout:
            monkeypatch.setattr(sys, "stdout", stdout)
            monkeypatch.setattr(cli, "main", broken_pipe)
            with pytest.raises(BrokenPipeError):
                cli.entry()
    finally:  # this process goes on to other tests
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
        os.close(read_end)
        os.close(write_end)


@pytest.mark.slow
def test_canter_train_to_a_closed_stdout_ends_quietly_with_its_run_complete(tmp_path):
    done = _canter_to_a_closed_stdout([*TINY_TRAIN, "--out-dir", str(tmp_path / "runs"), "--quiet"], buffered=True)
    assert done.returncode == 1 and done.stderr == "", done.stderr[-2000:]
    (run,) = (tmp_path / "runs").iterdir()
    assert json.loads((run / "summary.json").read_text())["stop_reason"] == "budget"
    assert list((run / "checkpoints").iterdir()) and list((run / "tb").iterdir())


@pytest.mark.slow
def test_eval_to_a_closed_stdout_writes_its_json_then_ends_quietly(archived_run, tmp_path):
    """The table came before --json's file, so a closed stdout lost the file, with a BrokenPipeError traceback."""
    results = tmp_path / "results.json"
    done = _canter_to_a_closed_stdout(
        ["eval", str(archived_run), "--episodes", "1", "--json", str(results)], buffered=False
    )
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert [run["run"] for run in json.loads(results.read_text())["runs"]] == [str(archived_run)]


def _study(tmp_path):
    storage = open_storage(StorageSettings(f"sqlite:///{tmp_path / 'study.db'}", 1, 3))
    return storage, optuna.create_study(storage=storage, study_name="unread", direction="maximize")


def test_a_worker_whose_stdout_nobody_reads_stops_and_queues_its_trial_again(tmp_path, monkeypatch, capsys):
    """A print to a closed stdout (`canter tune | head -c 5`) failed the trial, and the next, until the worker gave
    up: a study of 200 failed trials, each counted as a fault of its settings."""
    storage, study = _study(tmp_path)
    started = []

    def prints_its_start(trial):
        started.append(trial.number)
        print(f"start trial {trial.number}", flush=True)
        return Outcome("complete", value=1.0)

    # Closing the stream flushes the line that failed, which fails again.
    with closed_pipe() as closed, contextlib.suppress(BrokenPipeError), open(closed, "w", closefd=False) as stdout:
        monkeypatch.setattr(sys, "stdout", stdout)
        with pytest.raises(BrokenPipeError):
            run_worker(study, storage, 5, prints_its_start, heartbeat_seconds=1, poll_seconds=0.01)
    trials = study.get_trials()
    assert started == [0]
    assert [t.state for t in trials] == [TrialState.FAIL, TrialState.WAITING]
    assert trials[0].user_attrs[FAIL_REASON] == "interrupted"


def test_a_trial_whose_end_line_nobody_reads_keeps_its_outcome(tmp_path, monkeypatch):
    storage, study = _study(tmp_path)
    with closed_pipe() as closed, contextlib.suppress(BrokenPipeError), open(closed, "w", closefd=False) as stdout:
        monkeypatch.setattr(sys, "stdout", stdout)
        run_worker(
            study,
            storage,
            2,
            lambda trial: announced(trial.number, lambda: Outcome("complete", value=float(trial.number))),
            heartbeat_seconds=1,
            poll_seconds=0.01,
        )
    assert [(t.state, t.value) for t in study.get_trials()] == [(TrialState.COMPLETE, 0.0), (TrialState.COMPLETE, 1.0)]


@pytest.mark.slow
def test_canter_tune_to_a_closed_stdout_ends_quietly_with_no_failed_trial(tmp_path):
    args = ["tune", "Pendulum-v1", *tiny_args(tmp_path), "--trials", "3"]
    done = _canter_to_a_closed_stdout(args, buffered=False)
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]
    (study_dir,) = (tmp_path / "tune").iterdir()
    storage = open_storage(StorageSettings(f"sqlite:///{study_dir / 'study.db'}", 1, 3))
    (summary,) = optuna.study.get_all_study_summaries(storage)
    trials = optuna.load_study(study_name=summary.study_name, storage=storage).get_trials()
    faults = [t.user_attrs.get(FAIL_REASON) for t in trials if t.state == TrialState.FAIL]
    assert faults == ["interrupted"] and (study_dir / "summary.md").is_file(), faults


def _tiny_config(out_dir, total_steps=2048):
    return build_config(
        "Pendulum-v1", total_steps=total_steps, sets=[*TINY, "env.num_envs=4", f"run.out_dir={out_dir}"]
    )


@pytest.mark.slow
def test_training_with_its_progress_bar_on_a_closed_stdout_returns_its_result(tmp_path, monkeypatch):
    """rich's console exits the process (SystemExit(1)) where stdout is closed, which the bar's close raised out of
    `train()`, also from Python."""
    # Closing the stream flushes the bar's last draw, which fails again.
    with closed_pipe() as closed, contextlib.suppress(BrokenPipeError), open(closed, "w", closefd=False) as stdout:
        monkeypatch.setattr(sys, "stdout", stdout)
        result = loop.train(_tiny_config(tmp_path / "runs"), quiet=False)
    assert result.stop_reason == "budget"


@pytest.mark.slow
def test_the_seeds_are_closed_where_the_progress_bar_fails_to_close(tmp_path, monkeypatch):
    """The bar was closed first, and a failure there (a second Ctrl-C landing in it) skipped closing the seeds of a
    run that an error stopped: their TensorBoard events and tracker runs were left open."""
    closed = []
    close = SeedRun.close

    def recorded_close(self):
        close(self)
        closed.append(self.run_dir)

    def an_error(*args):
        raise RuntimeError("an error mid-run")

    def interrupted(self):
        raise KeyboardInterrupt

    monkeypatch.setattr(SeedRun, "close", recorded_close)
    monkeypatch.setattr(loop, "_show_progress", an_error)
    monkeypatch.setattr(Progress, "close", interrupted)
    with pytest.raises(KeyboardInterrupt):
        loop.train(_tiny_config(tmp_path / "runs", total_steps=1_000_000))  # not finished by the first call
    (run,) = (tmp_path / "runs").iterdir()
    assert closed == [run]
