"""The Optuna storage under faults, with the real PostgreSQL server of tests/pg_server.py: workers that start at
the same moment on an empty database all join, and "cannot connect" means the connection failed."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

import pg_server
from canter.errors import CanterError
from canter.orchestrate.study import StorageSettings, open_storage
from pg_server import postgres_url  # noqa: F401  (session fixture)

pytestmark = pytest.mark.slow

# A tune worker and a bench worker open their study exactly as `canter tune` and `canter bench --storage` do,
# once the file `go` exists, so that they all reach the empty database at the same moment.
WORKER = """
import sys, time
from pathlib import Path
kind, url, go = sys.argv[1], sys.argv[2], Path(sys.argv[3])
from canter.orchestrate.study import open_storage
if kind == "tune":
    from canter.orchestrate.tune import TuneSettings, make_study
    settings = TuneSettings("InvertedPendulum-v4", storage_url=url, study_name="tuned")
    open_study = lambda: make_study(settings, open_storage(settings.storage))
else:
    from canter.orchestrate.bench_distributed import open_grid_study
    from canter.orchestrate.bench_grid import BenchSettings
    settings = BenchSettings(("ppo",), ("InvertedPendulum-v4",), (0,), 512, storage_url=url, study_name="benched")
    open_study = lambda: open_grid_study(settings, Path("x"))[1]
print("ready", flush=True)
while not go.exists():
    time.sleep(0.01)
study = open_study()
print(study.study_name, study._study_id)
"""


def _new_database(server_url: str, name: str) -> str:
    import psycopg2

    connection = psycopg2.connect(server_url)
    connection.autocommit = True
    with connection.cursor() as cursor:
        cursor.execute(f"DROP DATABASE IF EXISTS {name}")
        cursor.execute(f"CREATE DATABASE {name}")
    connection.close()
    return server_url.rsplit("/", 1)[0] + f"/{name}"


def test_eight_tune_and_bench_workers_started_at_once_on_an_empty_database_all_join(
    tmp_path,
    postgres_url,  # noqa: F811
):
    url = _new_database(postgres_url, "empty_at_start")
    go = tmp_path / "go"
    workers = [
        subprocess.Popen(
            [sys.executable, "-c", WORKER, kind, url, str(go)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for kind in ["tune", "bench"] * 4
    ]
    for worker in workers:  # every worker has imported what it needs and waits for `go`
        assert worker.stdout is not None and worker.stdout.readline() == "ready\n"
    go.touch()
    outputs = [worker.communicate(timeout=120) for worker in workers]
    for worker, (_, err) in zip(workers, outputs):
        assert worker.returncode == 0, err
    studies = {tuple(out.split()) for out, _ in outputs}
    assert len(studies) == 2 and {name for name, _ in studies} == {"tuned", "benched"}


def test_cannot_connect_only_when_the_connection_fails(postgres_url):  # noqa: F811
    host_port = postgres_url.split("@", 1)[1].rsplit("/", 1)[0]
    port = int(host_port.rsplit(":", 1)[1])
    closed = postgres_url.replace(f":{port}/", f":{port + 1 if port < 65535 else port - 1}/")
    with pytest.raises(CanterError, match=r"^cannot connect to the postgresql\+psycopg2 storage at .*refused"):
        open_storage(StorageSettings(closed))
    with pytest.raises(CanterError, match=r'^cannot connect to .*database "no_such_db" does not exist'):
        open_storage(StorageSettings(postgres_url.rsplit("/", 1)[0] + "/no_such_db"))
    storage = open_storage(StorageSettings(_new_database(postgres_url, "opened_twice")))
    assert open_storage(StorageSettings(storage.url)).get_all_studies() == []


def test_a_sqlite_folder_that_does_not_exist_cannot_connect(tmp_path):
    with pytest.raises(CanterError, match=r"^cannot connect to the sqlite storage at .*missing"):
        open_storage(StorageSettings(f"sqlite:///{tmp_path / 'missing' / 'study.db'}"))
    assert not (tmp_path / "missing").exists()


def test_a_sqlite_path_meant_absolute_names_the_fourth_slash(tmp_path, monkeypatch):
    """sqlite:///tmp/x.db is tmp/x.db under the current folder, a slip for /tmp/x.db that SQLite words as 'unable to
    open database file'."""
    monkeypatch.chdir(tmp_path)
    meant = tmp_path / "study.db"
    url = f"sqlite://{meant}"  # three slashes before a path without its leading one
    with pytest.raises(CanterError) as refused:
        open_storage(StorageSettings(url))
    relative = str(meant).lstrip("/")
    assert str(refused.value).endswith(
        f"; sqlite:///{relative} is relative to the current folder: for /{relative}, write sqlite:////{relative}"
    ), refused.value
    assert list(tmp_path.iterdir()) == []


def test_workers_wait_out_a_database_restart_and_no_trial_is_lost_or_counted_twice(postgres_url):  # noqa: F811
    """The server stops while a trial runs. A worker that waits long enough records the trial once the server is
    back; one whose patience runs out stops with one line, leaving its trial running, which the next worker fails by
    heartbeat and retries with the same parameters."""
    import threading

    import optuna
    from optuna.trial import TrialState

    from canter.orchestrate.study import Outcome, run_worker

    url = _new_database(postgres_url, "outage")
    settings = StorageSettings(url, heartbeat_seconds=1, grace_seconds=3)
    storage = open_storage(settings)
    study = optuna.create_study(storage=storage, study_name="outage", direction="maximize")
    plan = {1: "restart", 4: "stay down"}  # trial number -> what happens to the server while it runs

    def run_trial(trial):
        x = trial.suggest_float("x", 0.0, 1.0)
        what = plan.pop(trial.number, None)
        if what is not None:
            pg_server.stop_server()
            if what == "restart":
                threading.Timer(3.0, pg_server.start_server).start()
        return Outcome("complete", value=x)

    def work(target, outage_seconds):
        run_worker(
            study, storage, target, run_trial, heartbeat_seconds=1, poll_seconds=0.1, outage_seconds=outage_seconds
        )

    work(4, outage_seconds=60)  # waits out the restart during trial 1
    started = time.monotonic()
    with pytest.raises(CanterError) as stopped:
        work(8, outage_seconds=2)  # gives up while the server is down after trial 4
    assert 2 <= time.monotonic() - started < 30
    message = str(stopped.value)
    assert message.startswith("lost the postgresql+psycopg2 storage at ") and "\n" not in message
    assert "run the same command again" in message
    pg_server.start_server()
    work(8, outage_seconds=60)

    trials = study.get_trials(deepcopy=False)
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    assert len(complete) == 8 and len({t.params["x"] for t in complete}) == 8  # none recorded twice
    assert [t.number for t in trials if t.state == TrialState.FAIL] == [4]
    retry = [t for t in complete if optuna.storages.RetryHeartbeatStaleTrialCallback.retried_trial_number(t) == 4]
    assert len(retry) == 1 and retry[0].params == trials[4].params
    assert not [t for t in trials if t.state in (TrialState.RUNNING, TrialState.WAITING)]


def test_a_worker_gives_up_when_trials_keep_failing_after_some_finished(tmp_path):
    """A resumed study whose trials now fail every time (an edited search space, say) stops with one line instead
    of asking forever; the failures before the last finished trial do not count."""
    import optuna

    from canter.orchestrate.study import Outcome, run_worker

    storage = open_storage(StorageSettings(f"sqlite:///{tmp_path / 'study.db'}", heartbeat_seconds=1))
    study = optuna.create_study(storage=storage, study_name="breaks", direction="maximize")

    def run_trial(trial):
        x = trial.suggest_float("x", 0.0, 1.0)
        # trials 0 and 2 finish; 1 fails before progress, so it is forgiven; from 3 on all fail
        return Outcome("complete", value=x) if trial.number in (0, 2) else Outcome("fail", reason="broken")

    with pytest.raises(CanterError) as stopped:
        run_worker(study, storage, 5, run_trial, heartbeat_seconds=1, poll_seconds=0.01, deadline=time.time() + 60)
    assert str(stopped.value) == (
        "study 'breaks': 10 trials failed in a row since the last of its 2 finished trials; the last one: broken; "
        "fix that and run the same command again (each failed trial keeps its 'fail_reason' in the study)"
    )
    assert len(study.trials) == 13


def test_a_worker_says_what_it_waits_for_when_a_trial_runs_elsewhere(tmp_path, capsys):
    """After a kill, the next run waits out the dead worker's trial for minutes: it says so, rather than seem hung."""
    import optuna

    from canter.orchestrate.study import Outcome, run_worker

    storage = open_storage(StorageSettings(f"sqlite:///{tmp_path / 'study.db'}", heartbeat_seconds=1, grace_seconds=2))
    study = optuna.create_study(storage=storage, study_name="left", direction="maximize")
    left = study.ask()  # a trial of a worker that was killed: running, and its heartbeat stops
    left.set_user_attr("worker", "node7:4242")
    storage.record_heartbeat(left._trial_id)

    def run_trial(trial):
        return Outcome("complete", value=1.0)

    run_worker(study, storage, 1, run_trial, heartbeat_seconds=1, poll_seconds=0.2, deadline=time.time() + 60)
    out = capsys.readouterr().out
    assert out.count("waiting for") == 1, out
    assert (
        "waiting for trial 0 (node7:4242), which another worker runs; a trial whose worker died is failed and retried "
        "after 2 s" in out
    )
    states = [t.state for t in study.trials]
    assert states[0] == optuna.trial.TrialState.FAIL and optuna.trial.TrialState.COMPLETE in states


def test_a_stop_while_the_storage_is_away_is_recorded_once_it_is_back(postgres_url, capsys):  # noqa: F811
    """Ctrl-C or SIGTERM during an outage: the worker says it waits, and once the server is back fails the trial and
    queues its copy. Giving up at once would leave the trial running, which every worker would then wait for."""
    import threading

    import optuna
    from optuna.trial import TrialState

    from canter.orchestrate.study import FAIL_REASON, run_worker

    url = _new_database(postgres_url, "stopaway")
    storage = open_storage(StorageSettings(url, heartbeat_seconds=1, grace_seconds=3))
    study = optuna.create_study(storage=storage, study_name="stopaway", direction="maximize")

    def stopped_during_an_outage(trial):
        trial.suggest_float("x", 0.0, 1.0)
        pg_server.stop_server()
        threading.Timer(3.0, pg_server.start_server).start()
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_worker(study, storage, 2, stopped_during_an_outage, heartbeat_seconds=1, poll_seconds=0.1)
    trials = study.get_trials(deepcopy=False)
    assert [t.state for t in trials] == [TrialState.FAIL, TrialState.WAITING]
    assert trials[0].user_attrs[FAIL_REASON] == "interrupted" and trials[1].params == trials[0].params
    err = capsys.readouterr().err
    assert "canter: note: lost the postgresql+psycopg2 storage at " in err
    assert "while recording the stopped trial; retrying for up to 5 min" in err
