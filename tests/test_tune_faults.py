"""canter tune when its workers stop or die: a trial stopped by Ctrl-C or SIGTERM is queued again with its
parameters and the summary of what completed is still written; a rerun says what the study holds; and a trial whose
worker on this machine is gone is failed and retried at once, not after its heartbeat's grace period."""

import subprocess
import sys
import textwrap
import time
from types import SimpleNamespace

import optuna
import pytest
from optuna.storages import RetryHeartbeatStaleTrialCallback
from optuna.trial import TrialState

from canter.cli.main import main
from canter.orchestrate.study import FAIL_REASON, Outcome, StorageSettings, open_storage, run_worker
from canter.orchestrate.tune import PRESET_ATTR
from test_tune import tiny_args, tiny_settings

STUDY = "Pendulum-v1__ppo"
# What a worker records of itself on its trial (canter.orchestrate.study's WORKER_ATTR, PROCESS_ATTR).
WORKER_ATTR, PROCESS_ATTR = "worker", "worker_process"


def _sqlite(tmp_path, heartbeat_seconds=1, grace_seconds=None):
    url = f"sqlite:///{tmp_path / 'study.db'}"
    return StorageSettings(url, heartbeat_seconds, grace_seconds or 3 * heartbeat_seconds)


def test_an_interrupted_trial_is_queued_again_with_its_parameters_and_counted_once(tmp_path, capsys):
    """Ctrl-C or SIGTERM failed the running trial as `interrupted` and nothing queued it again: the rerun sampled new
    parameters, while a killed worker's trial was retried with its own."""
    storage = open_storage(_sqlite(tmp_path))
    study = optuna.create_study(storage=storage, study_name="stopped", direction="maximize")
    trained = []

    def stopped(trial):
        trained.append(trial.suggest_float("x", 0.0, 1.0))
        raise KeyboardInterrupt

    def completes(trial):
        trained.append(trial.suggest_float("x", 0.0, 1.0))
        return Outcome("complete", value=trained[-1])

    for _ in range(2):  # the first run is stopped, and so is the rerun, in the copy of its trial
        with pytest.raises(KeyboardInterrupt):
            run_worker(study, storage, 2, stopped, heartbeat_seconds=1, poll_seconds=0.01)
    assert capsys.readouterr().out.splitlines() == [
        "trial 0 is queued again with its parameters; the same command trains it",
        "trial 1 is queued again with its parameters; the same command trains it",
    ]
    trials = study.get_trials()
    assert [t.state for t in trials] == [TrialState.FAIL, TrialState.FAIL, TrialState.WAITING]
    assert [t.user_attrs[FAIL_REASON] for t in trials[:2]] == ["interrupted", "interrupted"]
    queued = trials[2]  # one copy, however often it was stopped
    assert RetryHeartbeatStaleTrialCallback.retry_history(queued) == [0, 1] and queued.params == trials[0].params
    assert not {FAIL_REASON, WORKER_ATTR, PROCESS_ATTR} & set(queued.user_attrs)

    run_worker(study, storage, 2, completes, heartbeat_seconds=1, poll_seconds=0.01)
    assert trained[0] == trained[1] == trained[2] != trained[3]  # the stopped parameters trained, then a new trial
    trials = study.get_trials()
    assert [t.state for t in trials] == [TrialState.FAIL, TrialState.FAIL, TrialState.COMPLETE, TrialState.COMPLETE]


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_stopped_tune_writes_the_summary_and_best_preset_of_its_complete_trials(tmp_path, monkeypatch, capsys, jobs):
    """Only a worker's one-line error wrote summary.md and best.toml before stopping; Ctrl-C or SIGTERM left the
    study's complete trials without them."""
    import canter.orchestrate.jobs as jobs_module
    import canter.orchestrate.tune as tune_module

    def one_complete_then_stopped(settings, *rest):
        study = optuna.load_study(study_name=STUDY, storage=settings.storage.url)
        distribution = optuna.distributions.FloatDistribution(1e-4, 1e-2, log=True)
        trial = optuna.trial.create_trial(
            value=-150.0,
            params={"ppo.lr": 1e-3},
            distributions={"ppo.lr": distribution},
            user_attrs={PRESET_ATTR: "[run]\ntotal_steps = 1024\n"},
        )
        study.add_trial(trial)
        raise KeyboardInterrupt

    if jobs == 1:
        monkeypatch.setattr(tune_module, "worker", one_complete_then_stopped)
    else:
        monkeypatch.setattr(jobs_module, "run_workers", lambda work, args, name: one_complete_then_stopped(args[0][0]))
    code = main(["tune", "Pendulum-v1", "--trials", "3", "--jobs", str(jobs), *tiny_args(tmp_path)])
    out, err = capsys.readouterr()
    assert code == 130 and err.strip().splitlines()[-1] == "canter: interrupted", err
    study_dir = tmp_path / "tune" / STUDY
    assert "| 0 | -150.0 |" in (study_dir / "summary.md").read_text()
    assert (study_dir / "best.toml").read_text().endswith("[run]\ntotal_steps = 1024\n")
    assert f"preset written to {study_dir / 'best.toml'}, summary to {study_dir / 'summary.md'}" in out


def test_a_resumed_tune_says_what_its_study_holds(tmp_path, monkeypatch, capsys):
    """A rerun started without a word on the trials it goes on from."""
    import canter.orchestrate.tune as tune_module

    monkeypatch.setattr(tune_module, "worker", lambda *args: None)
    monkeypatch.setattr(tune_module, "write_results", lambda *args: None)
    settings = tiny_settings(tmp_path, trials=5)
    tune_module.tune(settings)
    assert "resuming" not in capsys.readouterr().out  # a new study has nothing to resume

    study = optuna.load_study(study_name=STUDY, storage=settings.storage.url)
    study.ask()  # running, elsewhere or left by a dead worker
    study.add_trial(optuna.trial.create_trial(value=1.0))
    study.add_trial(optuna.trial.create_trial(state=TrialState.PRUNED))
    study.add_trial(optuna.trial.create_trial(state=TrialState.FAIL))
    study.enqueue_trial({})  # a stopped trial's copy
    tune_module.tune(settings)
    assert capsys.readouterr().out.splitlines()[0] == (
        f"resuming study '{STUDY}': 2 of 5 trials done (1 complete, 1 pruned), 1 failed, 1 queued, 1 running"
    )


def test_a_recorded_worker_counts_as_dead_only_when_its_process_on_this_machine_has_ended():
    from canter.orchestrate import study

    assert (study.WORKER_ATTR, study.PROCESS_ATTR) == (WORKER_ATTR, PROCESS_ATTR)
    _this_machine, _worker_attrs, _worker_gone = study._this_machine, study._worker_attrs, study._worker_gone
    machine = _this_machine()
    assert machine is not None  # Linux: /proc tells
    me = _worker_attrs()[PROCESS_ATTR]
    where, pid, start = me.rsplit(" ", 2)

    def gone(recorded):
        return _worker_gone(SimpleNamespace(user_attrs={PROCESS_ATTR: recorded}), machine)

    ended = subprocess.Popen([sys.executable, "-c", "pass"])
    ended.wait()
    assert not gone(me)  # alive
    assert gone(f"{where} {ended.pid} {start}")
    assert gone(f"{where} {pid} {int(start) + 1}")  # its pid taken by a later process
    # Another machine, or another container with the same host name: its heartbeat tells, as before.
    assert not gone(f"another-boot pid:[1] {ended.pid} {start}")
    assert not _worker_gone(SimpleNamespace(user_attrs={WORKER_ATTR: f"host:{ended.pid}"}), machine)


HANGING_WORKER = """
import sys, time
import optuna
from canter.orchestrate.study import StorageSettings, open_storage, run_worker

storage = open_storage(StorageSettings(sys.argv[1], heartbeat_seconds=60, grace_seconds=180))
study = optuna.create_study(storage=storage, study_name="killed", direction="maximize", load_if_exists=True)

def hangs(trial):
    trial.suggest_float("x", 0.0, 1.0)
    print("started", flush=True)
    time.sleep(600)

run_worker(study, storage, 1, hangs, heartbeat_seconds=60)
"""


@pytest.mark.slow
def test_a_trial_whose_worker_on_this_machine_was_killed_is_retried_at_once(tmp_path, capsys):
    """After kill -9 with the default --heartbeat 60, the rerun waited 180 s for the trial of a process that it could
    see was gone, and said the trial was running elsewhere."""
    settings = _sqlite(tmp_path, heartbeat_seconds=60)
    killed = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(HANGING_WORKER), settings.url], stdout=subprocess.PIPE, text=True
    )
    try:
        assert killed.stdout.readline() == "started\n"
    finally:
        killed.kill()
        killed.wait()
    storage = open_storage(settings)
    study = optuna.load_study(study_name="killed", storage=storage)

    def completes(trial):
        return Outcome("complete", value=trial.suggest_float("x", 0.0, 1.0))

    started = time.monotonic()
    run_worker(study, storage, 1, completes, heartbeat_seconds=60, poll_seconds=0.1, deadline=time.time() + 60)
    assert time.monotonic() - started < 30
    trials = study.get_trials()
    assert [t.state for t in trials] == [TrialState.FAIL, TrialState.COMPLETE]
    assert trials[0].user_attrs[FAIL_REASON] == "worker died (its process is gone)"
    assert RetryHeartbeatStaleTrialCallback.retried_trial_number(trials[1]) == 0
    assert trials[1].params == trials[0].params
    out = capsys.readouterr().out
    assert (
        f"trial 0: its worker {trials[0].user_attrs[WORKER_ATTR]} on this machine is gone, so the trial is failed now"
        in out
    )
    assert "running elsewhere" not in out
