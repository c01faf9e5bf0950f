"""Optuna storage and the trial loop shared by `canter tune` and `canter bench --storage`.

The storage is Optuna's RDB storage: a SQLite file by default, or a PostgreSQL server that workers on many machines
share. Heartbeats mark the trial of a worker that died as FAILED once its heartbeat is older than the grace period,
and a copy of it with the same parameters is queued (`queue_copy`), so no trial is lost and none is counted twice. A
worker on the machine of the dead one fails its trial at once (`_fail_dead_workers_trials`), and a trial stopped by
Ctrl-C or SIGTERM is queued again as it stops, so that the next run trains it.

`run_worker` asks for trials until the study holds `target` finished (COMPLETE or PRUNED) trials, counted across
all workers: a worker only asks for a new trial while the finished and running trials are fewer than the target
(or a retry is waiting), and a trial that two workers asked for at the same moment beyond the target is closed as
FAILED with the reason `surplus`, so the number of finished trials ends exactly at the target.
"""

from __future__ import annotations

import contextlib
import copy
import functools
import os
import re
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from canter.errors import CanterError

SURPLUS = "surplus: the study already had its number of trials when this one started"
FAIL_REASON = "fail_reason"
INTERRUPTED = "interrupted"
# The worker running a trial: host:pid, as messages show it, and which process exactly (`_worker_attrs`).
WORKER_ATTR = "worker"
PROCESS_ATTR = "worker_process"
# How long a worker waits for a storage that went away (a restarted server, a full disk) before it stops.
OUTAGE_SECONDS = 300.0
T = TypeVar("T")
# Which canter command a study belongs to: a bench's jobs are no tune's trials, and the other way round.
COMMAND_ATTR = "canter_command"


def claim_study(study: Any, command: str, other_made_it: bool = False) -> None:
    """Mark `study` as `command`'s (bench or tune), or refuse one that the other command made. `other_made_it` tells
    a study from before the mark was kept, which the caller recognises by what it holds."""
    owner = study.user_attrs.get(COMMAND_ATTR)
    if owner is None and other_made_it:
        owner = "bench" if command == "tune" else "tune"
    if owner is not None and owner != command:
        raise CanterError(
            f"study '{study.study_name}' holds a canter {owner}'s {'jobs' if owner == 'bench' else 'trials'}; give "
            f"this {command} another --study (or another --storage)"
        )
    if owner is None:
        study.set_user_attr(COMMAND_ATTR, command)


@dataclass(frozen=True)
class StorageSettings:
    url: str
    heartbeat_seconds: int = 60
    grace_seconds: int = 180
    max_retry: int = 3


def normalize_url(url: str) -> str:
    """`postgresql://` means the psycopg2 driver of the `distributed` extra (SQLAlchemy 2.1 would pick psycopg 3)."""
    if url.startswith(("postgresql://", "postgres://")):
        return "postgresql+psycopg2://" + url.split("://", 1)[1]
    return url


def redacted(url: str) -> str:
    """The URL with its password, if any, replaced by ***: error messages end up in logs and terminals."""
    return re.sub(r"(://[^/@:]*:).*@", r"\1***@", url)


def describe_url(url: str) -> tuple[str, str]:
    """(driver, host) of a storage URL, without the password."""
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError

    try:
        parsed = make_url(url)
    except (ArgumentError, ValueError):  # ValueError: a port that is not a number
        raise CanterError(
            f"--storage {redacted(url)!r} is not a database URL; use sqlite:///path/study.db or "
            f"postgresql://user:password@host:5432/dbname"
        ) from None
    driver = parsed.drivername
    if driver.startswith("sqlite"):
        if parsed.database in (None, "", ":memory:"):  # each worker process would get its own, empty database
            raise CanterError(
                f"--storage {url!r} is an in-memory database, which the worker processes cannot share; name a "
                f"file, such as sqlite:///study.db"
            )
        return driver, parsed.database
    if "@" in (parsed.host or ""):  # SQLAlchemy splits at the first @, so the password's tail would read as the host
        raise CanterError(
            f"--storage {redacted(url)!r}: its password holds an '@'; write it as %40 "
            f"(postgresql://user:p%40ss@host/db), as URLs need"
        )
    host = f"{parsed.host or 'localhost'}:{parsed.port}" if parsed.port else (parsed.host or "localhost")
    return driver, host


def _reason(exc: BaseException) -> str:
    lines = str(getattr(exc, "orig", None) or exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


# Any constant names the lock; pg_advisory_lock's key is a bigint. This one is "canter" in ASCII.
_SCHEMA_LOCK_KEY = 0x63616E746572
SCHEMA_TRIES = 5


@contextlib.contextmanager
def _schema_lock(engine: Any, driver: str) -> Iterator[None]:
    """Workers started at the same moment on an empty database would all create Optuna's tables and all but one
    fail on PostgreSQL's catalog ("duplicate key value violates unique constraint pg_type_typname_nsp_index").
    On PostgreSQL they take turns under an advisory lock, held by this session until it closes."""
    if not driver.startswith("postgresql"):
        yield
        return
    import sqlalchemy

    with engine.connect() as connection:
        connection.execute(sqlalchemy.text("SELECT pg_advisory_lock(:key)"), {"key": _SCHEMA_LOCK_KEY})
        try:
            yield
        finally:
            connection.execute(sqlalchemy.text("SELECT pg_advisory_unlock(:key)"), {"key": _SCHEMA_LOCK_KEY})


def open_storage(settings: StorageSettings) -> Any:
    """An RDBStorage with heartbeats and failed-trial retry, or a one-line error naming the host and driver that
    says "cannot connect" only when the connection failed. Any number of workers may open an empty database at
    once: its tables are created once (`_schema_lock`), and a clash on another database is retried."""
    import optuna
    import sqlalchemy
    import sqlalchemy.exc

    quiet_optuna()
    url = normalize_url(settings.url)
    driver, host = describe_url(url)
    if driver.startswith("sqlite"):
        engine_kwargs: dict[str, Any] = {"connect_args": {"timeout": 120}}
    elif driver.startswith("postgresql"):
        engine_kwargs = {"connect_args": {"connect_timeout": 10}, "pool_pre_ping": True}
    else:
        engine_kwargs = {"pool_pre_ping": True}
    try:
        engine = sqlalchemy.create_engine(url, **engine_kwargs)
        engine.connect().close()
    except (ImportError, ModuleNotFoundError):
        hint = (
            "pip install 'canter[distributed]'"
            if driver.startswith("postgresql")
            else f"install a Python driver for {driver} (canter[distributed] provides PostgreSQL's psycopg2)"
        )
        raise CanterError(
            f"cannot connect to the {driver} storage at {host}: its database driver is not installed; {hint}"
        ) from None
    except (sqlalchemy.exc.SQLAlchemyError, OSError, ValueError) as exc:
        raise CanterError(f"cannot connect to the {driver} storage at {host}: {_reason(exc)}") from None
    try:
        attempt = 0
        while True:
            try:
                with _schema_lock(engine, driver):
                    return optuna.storages.RDBStorage(
                        url,
                        engine_kwargs=engine_kwargs,
                        heartbeat_interval=settings.heartbeat_seconds,
                        grace_period=settings.grace_seconds,
                        heartbeat_stale_trial_callback=functools.partial(queue_copy, max_retry=settings.max_retry),
                    )
            except RuntimeError as exc:
                if "storage upgrade" not in str(exc):
                    raise
                raise CanterError(
                    f"the study database at {host} was made by another Optuna version than this one "
                    f"({optuna.__version__}); back it up and run `optuna storage upgrade --storage URL`, or give "
                    f"another --storage"
                ) from None
            except (sqlalchemy.exc.SQLAlchemyError, OSError, ValueError) as exc:
                attempt += 1
                if attempt == SCHEMA_TRIES:
                    raise CanterError(
                        f"the {driver} storage at {host} is reachable, but opening Optuna's tables failed "
                        f"{SCHEMA_TRIES} times: {_reason(exc)}; check the database and its user's rights"
                    ) from None
                time.sleep(0.2 * 2**attempt)  # another worker may be creating the tables
    finally:
        engine.dispose()


def quiet_optuna() -> None:
    import warnings

    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    # canter records heartbeats itself (studies.run_worker), which is what this warning asks for.
    warnings.filterwarnings("ignore", message="Heartbeat of storage is supposed to be used with Study.optimize")


# ----------------------------------------------------------------------------------------------- storage outages


def _lost_storage(exc: BaseException) -> bool:
    """Whether an exception means the database went away (Optuna wraps SQLAlchemy's errors of a commit)."""
    import optuna
    import sqlalchemy.exc

    gone = (sqlalchemy.exc.OperationalError, sqlalchemy.exc.InterfaceError, sqlalchemy.exc.DisconnectionError)
    if isinstance(exc, optuna.exceptions.StorageInternalError):
        return isinstance(exc.__cause__, gone)
    return isinstance(exc, gone)


def retrying(call: Callable[[], T], url: str, what: str, patience: float = OUTAGE_SECONDS) -> T:
    """`call()`, retried with backoff while the storage at `url` is away, for up to `patience` seconds; then a
    one-line CanterError. Trials already told are in the database and stay there."""
    started, delay = time.monotonic(), 0.5
    while True:
        try:
            return call()
        except Exception as exc:
            if not _lost_storage(exc):
                raise
            waited = time.monotonic() - started
            if waited >= patience:
                driver, host = describe_url(normalize_url(url))
                raise CanterError(
                    f"lost the {driver} storage at {host} for {waited:.0f} s while {what}: "
                    f"{_reason(exc.__cause__ or exc)}; the finished trials are kept there: run the same command "
                    f"again once it is back (a trial left running is failed and retried)"
                ) from None
            time.sleep(min(delay, patience - waited))
            delay = min(2 * delay, 30.0)


# ------------------------------------------------------------------------------------------------------- the loop


@dataclass(frozen=True)
class Outcome:
    state: str  # "complete", "pruned" or "fail"
    value: float | None = None
    reason: str | None = None


class _Heartbeat:
    """Records the trial's heartbeat every interval while the trial runs (what `study.optimize` does internally)."""

    def __init__(self, storage: Any, trial: Any, interval: float) -> None:
        self._storage, self._stop = storage, threading.Event()
        self._trial_id = trial._trial_id  # Optuna's trial handle has no public id accessor
        self._thread = threading.Thread(target=self._beat, args=(interval,), daemon=True)

    def _beat(self, interval: float) -> None:
        while not self._stop.is_set():
            # A lost connection: the next beat retries, the grace period covers the gap.
            with contextlib.suppress(Exception):
                self._storage.record_heartbeat(self._trial_id)
            self._stop.wait(interval)

    def __enter__(self) -> _Heartbeat:
        self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        self._thread.join()


def counts(study: Any) -> dict[str, int]:
    from optuna.trial import TrialState

    result = {s.name: 0 for s in TrialState}
    for trial in study.get_trials(deepcopy=False):
        result[trial.state.name] += 1
    return result


def _surplus(study: Any, number: int, target: int) -> bool:
    from optuna.trial import TrialState

    alive = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.RUNNING, TrialState.WAITING)
    return sum(1 for t in study.get_trials(deepcopy=False, states=alive) if t.number < number) >= target


def _running(study: Any) -> tuple[tuple[int, str], ...]:
    """(number, worker) of the study's running trials; the worker as `run_worker` records it (host:pid), else '?'."""
    from optuna.trial import TrialState

    trials = study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))
    return tuple((t.number, str(t.user_attrs.get(WORKER_ATTR, "?"))) for t in trials)


def _say_waiting(running: tuple[tuple[int, str], ...], grace: float | None) -> None:
    """One line when a worker starts waiting on trials that run elsewhere: after a kill, a stale trial is failed and
    retried only once its heartbeat is older than the grace period, minutes in which nothing else is printed."""
    if not running:
        return
    shown = ", ".join(f"trial {number}" + (f" ({worker})" if worker != "?" else "") for number, worker in running[:3])
    more = f" and {len(running) - 3} more" if len(running) > 3 else ""
    retried = f"{grace:.0f} s" if grace else "its grace period"
    print(
        f"waiting for {shown}{more}, running elsewhere; a trial whose worker died is failed and retried after "
        f"{retried} without a heartbeat",
        flush=True,
    )


def queue_copy(study: Any, trial: Any, max_retry: int | None) -> None:
    """Queue a copy of `trial` (a FrozenTrial) with its parameters, as Optuna's `RetryHeartbeatStaleTrialCallback`
    does (`retried_trial_number` names the original), up to `max_retry` copies in a row (None: no limit). The copy
    leaves out the original's worker and failure: its own worker records them, and until then a worker on the dead
    one's machine would take it for the dead one's trial (`_fail_dead_workers_trials`)."""
    import optuna

    fresh = copy.copy(trial)
    fresh.user_attrs = {k: v for k, v in trial.user_attrs.items() if k not in (FAIL_REASON, WORKER_ATTR, PROCESS_ATTR)}
    optuna.storages.RetryHeartbeatStaleTrialCallback(max_retry=max_retry)(study, fresh)


def _process_of(pid: int) -> tuple[str, str] | None:
    """(state, start time in clock ticks since boot) of process `pid`, from /proc; None where it has none."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return fields[0], fields[19]


def _this_machine() -> str | None:
    """This boot of this machine and this pid namespace: a recorded pid names the same process only where both
    match (a container with the same host name has pids of its own; a rebooted machine, new ones). None off Linux,
    where a dead worker's trial waits out its grace period."""
    try:
        boot = Path("/proc/sys/kernel/random/boot_id").read_text().strip()
        return f"{boot} {os.readlink('/proc/self/ns/pid')}"
    except OSError:
        return None


def _worker_attrs() -> dict[str, str]:
    attrs = {WORKER_ATTR: f"{socket.gethostname()}:{os.getpid()}"}
    machine, me = _this_machine(), _process_of(os.getpid())
    if machine is not None and me is not None:
        # The start time tells this process from a later one that reuses its pid.
        attrs[PROCESS_ATTR] = f"{machine} {os.getpid()} {me[1]}"
    return attrs


def _worker_gone(trial: Any, machine: str) -> bool:
    """Whether the recorded worker of a running trial was a process of this machine that has ended."""
    recorded = trial.user_attrs.get(PROCESS_ATTR)
    if not isinstance(recorded, str) or recorded.count(" ") < 3:
        return False
    where, pid, start = recorded.rsplit(" ", 2)
    if where != machine or not pid.isdigit():
        return False
    found = _process_of(int(pid))
    return found is None or found[1] != start or found[0] in ("Z", "X")  # a zombie has ended, unreaped


def _fail_dead_workers_trials(study: Any, storage: Any) -> None:
    """Fail the running trials whose worker was a process of this machine that has ended (kill -9, the OOM killer),
    and queue their copies as a stale heartbeat would: their heartbeat would keep this worker waiting 3 intervals."""
    import optuna
    from optuna.trial import TrialState

    machine = _this_machine()
    if machine is None:
        return
    for trial in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        if not _worker_gone(trial, machine):
            continue
        snapshot = copy.deepcopy(trial)
        try:
            study._storage.set_trial_user_attr(trial._trial_id, FAIL_REASON, "worker died (its process is gone)")
            study._storage.set_trial_state_values(trial._trial_id, TrialState.FAIL)
        except optuna.exceptions.UpdateFinishedTrialError:
            continue  # another worker failed it first, and queued its copy
        print(
            f"trial {trial.number}: its worker {trial.user_attrs.get(WORKER_ATTR, '?')} on this machine is gone, so "
            f"the trial is failed now rather than after the heartbeat grace period, and retried as a stale one is",
            flush=True,
        )
        callback = storage.get_heartbeat_stale_trial_callback()
        if callback is not None:
            callback(study, snapshot)


def _fail_gone_then_count(study: Any, storage: Any) -> dict[str, int]:
    """The study's trials by state, once the trials of workers known to be gone are failed and retried."""
    import optuna

    _fail_dead_workers_trials(study, storage)
    optuna.storages.fail_stale_trials(study)
    return counts(study)


def _stop_interrupted(study: Any, trial: Any, requeue: bool) -> None:
    """Fail a trial that Ctrl-C or SIGTERM stopped, so that nobody waits for its heartbeat, and with `requeue`
    queue a copy with its parameters for the next run. A stop is no fault of the trial, so its copies are not
    limited in number; a trial failed meanwhile by another worker has its copy already."""
    import optuna
    from optuna.trial import TrialState

    snapshot = copy.deepcopy(study._storage.get_trial(trial._trial_id))
    try:
        trial.set_user_attr(FAIL_REASON, INTERRUPTED)
        study.tell(trial, state=TrialState.FAIL)
    except (ValueError, optuna.exceptions.UpdateFinishedTrialError):  # ValueError: study.tell of a finished trial
        return
    if requeue:
        queue_copy(study, snapshot, max_retry=None)
        print(f"trial {trial.number} is queued again with its parameters; the same command trains it", flush=True)


def run_worker(
    study: Any,
    storage: Any,
    target: int,
    run_trial: Callable[[Any], Outcome],
    *,
    heartbeat_seconds: float,
    poll_seconds: float = 1.0,
    deadline: float | None = None,
    ask_new: bool = True,
    outage_seconds: float = OUTAGE_SECONDS,
) -> None:
    """Run trials until the study has `target` COMPLETE+PRUNED trials (or `deadline`, a time.time(), passes).
    With `ask_new=False` only queued (WAITING) trials are run, whatever the study held before, and the worker
    returns once none is queued or running: a queue of fixed work such as a bench grid, where a failed item is not
    retried by a new trial, and `target` is not used.

    A worker gives up with a one-line error once `max(10, 2 * target)` trials in a row have failed since the study
    last finished one (a space or a command that cannot work, such as a space edited under a resumed study).

    Every storage call waits out an outage of up to `outage_seconds` (`retrying`). A trial that ran through one is
    told when the storage is back; if another worker failed it meanwhile (its heartbeat went stale), that worker
    retries it and this outcome is dropped, so no trial counts twice."""
    import optuna
    from optuna.trial import TrialState

    def call(what: str, fn: Callable[[], T]) -> T:
        return retrying(fn, storage.url, what, outage_seconds)

    states = {"complete": TrialState.COMPLETE, "pruned": TrialState.PRUNED, "fail": TrialState.FAIL}
    give_up = max(10, 2 * target)
    progress: tuple[int, int] | None = None  # (finished, failed) when the finished count last grew
    waited_for: tuple[tuple[int, str], ...] = ()  # the running trials this worker last said it waits for
    while True:
        n = call("reading the study", functools.partial(_fail_gone_then_count, study, storage))
        finished = n["COMPLETE"] + n["PRUNED"]
        if (ask_new and finished >= target) or (deadline is not None and time.time() >= deadline):
            return
        if progress is None or finished > progress[0]:
            # A study with nothing finished counts every failure; a resumed one, those since this worker started.
            progress = (finished, n["FAIL"] if finished else 0)
        if ask_new and n["FAIL"] - progress[1] >= give_up:
            done = f"since the last of its {finished} finished trials" if finished else "and none finished"
            failed = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.FAIL,))
            last = next((t.user_attrs[FAIL_REASON] for t in reversed(failed) if FAIL_REASON in t.user_attrs), None)
            raise CanterError(
                f"study '{study.study_name}': {n['FAIL'] - progress[1]} trials failed in a row {done}; the last "
                f"one: {last or 'no reason recorded'} (each failed trial keeps its '{FAIL_REASON}' in the study)"
            )
        if n["WAITING"] == 0:
            if not ask_new and n["RUNNING"] == 0:
                return
            if not ask_new or finished + n["RUNNING"] >= target:
                running = call("reading the study", functools.partial(_running, study))
                if running != waited_for:
                    waited_for = running
                    _say_waiting(running, getattr(storage, "grace_period", None))
                time.sleep(poll_seconds)  # the last trials run elsewhere; wait in case their worker dies
                continue
        trial = call("asking for a trial", study.ask)
        if ask_new and call("reading the study", functools.partial(_surplus, study, trial.number, target)):
            _tell(study, trial, Outcome("fail", reason=SURPLUS), TrialState.FAIL, call)
            continue
        for attr, value in _worker_attrs().items():
            call("recording a trial", functools.partial(trial.set_user_attr, attr, value))
        try:
            with _Heartbeat(storage, trial, heartbeat_seconds):
                outcome = run_trial(trial)
        except Exception as exc:  # the trial fails with the reason; the study goes on
            outcome = Outcome("fail", reason=f"{type(exc).__name__}: {exc}"[:500])
        except BaseException:
            # A queue of fixed work queues its failed items itself when run again.
            with contextlib.suppress(Exception):  # a trial left running is failed by heartbeat and retried
                _stop_interrupted(study, trial, requeue=ask_new)
            raise
        _tell(study, trial, outcome, states[outcome.state], call)


def _tell(study: Any, trial: Any, outcome: Outcome, state: Any, call: Callable[[str, Callable[[], Any]], Any]) -> None:
    """Record a trial's outcome once: a retried tell whose first try got through, or a trial that another worker
    failed by heartbeat during an outage, is left as the storage has it."""
    import optuna
    from optuna.trial import TrialState

    def record() -> None:
        if outcome.reason:
            trial.set_user_attr(FAIL_REASON if outcome.state == "fail" else "note", outcome.reason)
        values = outcome.value if state == TrialState.COMPLETE else None
        study.tell(trial, values, state=state, skip_if_finished=True)

    with contextlib.suppress(optuna.exceptions.UpdateFinishedTrialError):  # finished already: see below
        call(f"recording trial {trial.number}", record)
    stored = call("reading the study", lambda: study._storage.get_trial(trial._trial_id).state)
    if stored != state:
        print(
            f"canter: note: trial {trial.number} was marked {stored.name} while the storage was away; "
            f"its {state.name.lower()} outcome is dropped and the trial is retried",
            file=sys.stderr,
        )
