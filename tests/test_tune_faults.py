"""canter tune when its workers stop or die: a trial stopped by Ctrl-C or SIGTERM is queued again with its
parameters and the summary of what completed is still written; a rerun says what the study holds; and a trial whose
worker on this machine is gone is failed and retried at once, not after its heartbeat's grace period."""

import signal
import subprocess
import sys
import textwrap
import threading
import time
from types import SimpleNamespace

import optuna
import pytest
from optuna.storages import RetryHeartbeatStaleTrialCallback
from optuna.trial import TrialState

from canter.cli.main import main
from canter.orchestrate.study import FAIL_REASON, Outcome, StorageSettings, open_storage, run_worker
from canter.orchestrate.tune import PRESET_ATTR
from signals import with_sigint
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


def _signal_in_ask(study, monkeypatch):
    """SIGTERM to the worker inside `study.ask`, once the storage has made the trial RUNNING."""
    ask = study.ask

    def signalled():
        trial = ask()
        signal.raise_signal(signal.SIGTERM)
        return trial

    monkeypatch.setattr(study, "ask", signalled)


def _interrupt_recording_the_worker(study, monkeypatch):
    """Ctrl-C as the worker records itself on its trial."""
    from canter.orchestrate import study as study_module

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(study_module, "_worker_attrs", interrupted)


@pytest.mark.parametrize("stop", [_signal_in_ask, _interrupt_recording_the_worker], ids=["in-ask", "recording"])
@pytest.mark.parametrize("ask_new", [True, False], ids=["tune", "bench"])
def test_a_trial_stopped_as_its_worker_takes_it_is_failed_at_once(tmp_path, monkeypatch, capsys, stop, ask_new):
    """Ctrl-C or SIGTERM between the storage making a queued trial RUNNING and the start of its heartbeat left the
    trial running with no heartbeat, which no worker failed: every rerun waited for it. Stopped there, a trial is
    failed as one stopped while training is: tune queues it again with its parameters; a bench, whose queue of
    fixed work queues its failed jobs itself when run again, leaves it failed."""
    from canter.orchestrate.jobs import sigterm_interrupts

    storage = open_storage(_sqlite(tmp_path, heartbeat_seconds=60))
    study = optuna.create_study(storage=storage, study_name="taken", direction="maximize")
    study.enqueue_trial({"x": 0.25})  # a stopped trial's copy, or a bench's job
    trained = []

    def completes(trial):
        trained.append(trial.suggest_float("x", 0.0, 1.0))
        return Outcome("complete", value=trained[-1])

    with monkeypatch.context() as patched:
        stop(study, patched)
        with pytest.raises(KeyboardInterrupt), sigterm_interrupts():  # as canter tune and bench run their workers
            run_worker(study, storage, 1, completes, heartbeat_seconds=60, poll_seconds=0.01, ask_new=ask_new)
    assert trained == []
    trials = study.get_trials()
    assert trials[0].state == TrialState.FAIL and trials[0].user_attrs[FAIL_REASON] == "interrupted"
    if not ask_new:
        assert len(trials) == 1
        return
    assert [t.state for t in trials] == [TrialState.FAIL, TrialState.WAITING]
    assert capsys.readouterr().out == "trial 0 is queued again with its parameters; the same command trains it\n"
    # The rerun trains the copy at once, rather than wait for a trial running nowhere.
    run_worker(study, storage, 1, completes, heartbeat_seconds=60, poll_seconds=0.01, deadline=time.time() + 60)
    assert trained == [0.25]
    assert [t.state for t in study.get_trials()] == [TrialState.FAIL, TrialState.COMPLETE]


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
    see was gone, and said another worker ran the trial."""
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
    assert "which another worker runs" not in out


def _stopped(trial):
    trial.suggest_float("x", 0.0, 1.0)
    raise KeyboardInterrupt


def _dead_worker_record():
    """A PROCESS_ATTR as a worker of this machine records it, of a process that has ended."""
    from canter.orchestrate import study as study_module

    ended = subprocess.Popen([sys.executable, "-c", "pass"])
    ended.wait()
    return f"{study_module._this_machine()} {ended.pid} 1"


def test_stopped_trials_count_toward_no_limit_and_the_rerun_trains_the_queued_copy(tmp_path, capsys):
    """Stops counted toward the failures in a row after which a worker gives up (10 of them with --trials 2): the rerun
    refused at once, and the queued copy was never trained."""
    storage = open_storage(_sqlite(tmp_path))
    study = optuna.create_study(storage=storage, study_name="stops", direction="maximize")
    for _ in range(10):
        with pytest.raises(KeyboardInterrupt):
            run_worker(study, storage, 2, _stopped, heartbeat_seconds=1, poll_seconds=0.01)
    stopped_params = study.get_trials()[0].params
    trained = []

    def completes(trial):
        trained.append(trial.suggest_float("x", 0.0, 1.0))
        return Outcome("complete", value=trained[-1])

    run_worker(study, storage, 2, completes, heartbeat_seconds=1, poll_seconds=0.01)
    assert trained[0] == stopped_params["x"]
    assert [t.state for t in study.get_trials()].count(TrialState.COMPLETE) == 2


def test_a_trial_stopped_three_times_is_still_retried_when_its_worker_dies(tmp_path, capsys):
    """The copies queued by stops used up the 3 retries of a dead worker's trial, so a trial stopped 3 times and then
    killed was not retried, and the study went on with new parameters."""
    storage = open_storage(_sqlite(tmp_path, heartbeat_seconds=60))
    study = optuna.create_study(storage=storage, study_name="stops", direction="maximize")
    for _ in range(3):
        with pytest.raises(KeyboardInterrupt):
            run_worker(study, storage, 1, _stopped, heartbeat_seconds=60, poll_seconds=0.01)
    killed = study.ask()  # the queued copy, taken by a worker that is then killed
    killed.set_user_attr(PROCESS_ATTR, _dead_worker_record())
    trained = []

    def completes(trial):
        trained.append(trial.suggest_float("x", 0.0, 1.0))
        return Outcome("complete", value=trained[-1])

    run_worker(study, storage, 1, completes, heartbeat_seconds=60, poll_seconds=0.01, deadline=time.time() + 60)
    assert trained == [study.get_trials()[0].params["x"]]


def test_a_trial_stopped_once_the_study_has_its_trials_is_not_queued_again(tmp_path, capsys, monkeypatch):
    """The stopped trial's copy was queued even when the other workers had finished the study meanwhile: it never ran,
    the stop said the same command would train it, and every rerun reported it as queued."""
    import canter.orchestrate.tune as tune_module

    settings = tiny_settings(tmp_path, trials=1)
    monkeypatch.setattr(tune_module, "write_results", lambda *args: None)
    monkeypatch.setattr(tune_module, "worker", lambda *args: None)
    tune_module.tune(settings)  # the study, with its settings
    storage = open_storage(settings.storage)
    study = optuna.load_study(study_name=STUDY, storage=storage)

    def finished_elsewhere_then_stopped(trial):
        trial.suggest_float("x", 0.0, 1.0)
        study.add_trial(optuna.trial.create_trial(value=1.0))  # another worker's trial completes the study
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_worker(study, storage, 1, finished_elsewhere_then_stopped, heartbeat_seconds=1, poll_seconds=0.01)
    assert capsys.readouterr().out == "trial 0 is not queued again: the study has its number of trials\n"
    assert TrialState.WAITING not in [t.state for t in study.get_trials()]

    study.enqueue_trial({"x": 0.5})  # a copy that an earlier version queued all the same
    tune_module.tune(settings)
    assert capsys.readouterr().out.splitlines()[0] == (
        f"resuming study '{STUDY}': 1 of 1 trials done (1 complete, 0 pruned), 1 failed"
    )


def test_a_worker_whose_process_another_user_runs_is_alive_though_proc_hides_it(monkeypatch):
    """Under a /proc mounted with hidepid, a worker could not read another user's /proc/PID/stat and took that
    user's live worker for dead, failing its trials."""
    import os

    from canter.orchestrate import study as study_module

    machine = study_module._this_machine()
    where, pid, start = study_module._worker_attrs()[PROCESS_ATTR].rsplit(" ", 2)
    ended = _dead_worker_record().rsplit(" ", 2)[1]
    monkeypatch.setattr(study_module, "_process_of", lambda pid: None)  # hidepid: no stat of another user's process

    def gone(pid):
        return study_module._worker_gone(SimpleNamespace(user_attrs={PROCESS_ATTR: f"{where} {pid} {start}"}), machine)

    assert not gone(pid)
    assert gone(ended)

    def not_permitted(pid, signal):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "kill", not_permitted)  # another user's process
    assert not gone(pid)


def test_workers_that_find_a_dead_workers_trial_at_once_queue_one_copy(tmp_path):
    """On SQLite, Optuna's fail-then-queue is a read and then a write: workers sweeping at the same moment each
    failed the dead worker's trial and each queued a copy of it."""
    from canter.orchestrate import study as study_module

    settings = _sqlite(tmp_path, heartbeat_seconds=60)
    for round in range(5):
        storage = open_storage(settings)
        study = optuna.create_study(storage=storage, study_name=f"race{round}", direction="maximize")
        dead = study.ask()
        dead.suggest_float("x", 0.0, 1.0)
        dead.set_user_attr(PROCESS_ATTR, _dead_worker_record())
        workers = [open_storage(settings) for _ in range(4)]
        studies = [optuna.load_study(study_name=study.study_name, storage=s) for s in workers]
        for s in studies:
            s.get_trials()  # each worker has read the study before they sweep
        barrier = threading.Barrier(len(workers))

        def sweep(s, storage, barrier):
            barrier.wait()
            study_module._fail_dead_workers_trials(s, storage)

        threads = [threading.Thread(target=sweep, args=(*pair, barrier)) for pair in zip(studies, workers)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        assert [t.state for t in study.get_trials()] == [TrialState.FAIL, TrialState.WAITING], f"round {round}"


def test_seeds_per_trial_below_one_is_refused_with_the_value_given(tmp_path, capsys):
    """`--seeds-per-trial -3` said "got 0": the settings only saw the empty range of seeds it made."""
    code = main(["tune", "Pendulum-v1", "--seeds-per-trial", "-3", *tiny_args(tmp_path)])
    assert code == 2 and capsys.readouterr().err.strip() == "canter: error: --seeds-per-trial must be >= 1, got -3"


def test_two_stop_signals_landing_together_interrupt_once_without_a_race_error():
    """Ctrl-C to the process group and the parent's SIGTERM reach a worker together: the first interrupts, and the
    second, already pending, must find a handler, not SIG_IGN (Python then raises "Signal 15 ignored due to race
    condition" out of the cleanup)."""
    program = (
        "import os, signal\n"
        "from canter.orchestrate.jobs import sigterm_interrupts\n"
        "both = {signal.SIGINT, signal.SIGTERM}\n"
        "try:\n"
        "    with sigterm_interrupts():\n"
        "        signal.pthread_sigmask(signal.SIG_BLOCK, both)\n"
        "        os.kill(os.getpid(), signal.SIGINT)\n"
        "        os.kill(os.getpid(), signal.SIGTERM)\n"
        "        signal.pthread_sigmask(signal.SIG_UNBLOCK, both)\n"
        "        for _ in range(10000):\n"
        "            pass\n"
        "except KeyboardInterrupt:\n"
        "    total = sum(range(10000))  # Python runs the pending handler here, in the cleanup\n"
        "    print('interrupted once')\n"
    )
    done = subprocess.run(with_sigint([sys.executable, "-c", program]), capture_output=True, text=True, timeout=60)
    assert done.stdout == "interrupted once\n" and done.stderr == "", done.stderr
    # The kernel may deliver the second signal only after the block has put the default handler back, which ends
    # the process by it: that is a stop, not the error.
    assert done.returncode in (0, -signal.SIGTERM), done.returncode
