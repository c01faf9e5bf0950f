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
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from canter.errors import CanterError
from canter.signals import StopFlag, stdout_is_gone

SURPLUS = "surplus: the study already had its number of trials when this one started"
FAIL_REASON = "fail_reason"
INTERRUPTED = "interrupted"
# A queued trial dropped as its study restarted under other settings (`restart_study`): it would have run the old ones.
RESTARTED = "restarted: queued under settings that a later command replaced"
# A stop, a surplus or a restart is no fault of the trial's parameters: such trials count toward no limit on failures.
NO_FAULT = (INTERRUPTED, SURPLUS, RESTARTED)
# The trials of a copy's retry_history that a stop failed (system attr), which count toward no retry limit.
STOPPED_ATTR = "canter_stopped"
# The worker running a trial: host:pid, as messages show it, and which process exactly (`_worker_attrs`).
WORKER_ATTR = "worker"
PROCESS_ATTR = "worker_process"
# How long a worker waits for a storage that went away (a restarted server, a full disk) before it stops.
OUTAGE_SECONDS = 300.0
T = TypeVar("T")
# Which canter command a study belongs to: a bench's jobs are no tune's trials, and the other way round.
COMMAND_ATTR = "canter_command"
# The settings a tune study keeps (`canter.orchestrate.tune.check_study_settings`).
SETTINGS_ATTR = "canter_settings"
# What the trials of each command hold, which tells the studies from before COMMAND_ATTR was kept: a bench trial
# its job (`canter.orchestrate.bench_distributed.JOB_ATTR`), a tune trial the preset it trained (`tune.PRESET_ATTR`).
TRIAL_MARKS = {"bench": "job", "tune": "preset"}
GRACE_HEARTBEATS = 3  # a trial whose worker missed this many heartbeats is failed and retried
# A tune study's folder: its SQLite database, unless --storage is given, and its trials' folders.
DB_FILE = "study.db"
TRIALS_FOLDER = "trials"
_TRIAL_FOLDER = re.compile(r"trial_[0-9]{5,}")


def check_at_least(limits: Iterable[tuple[str, float, float]]) -> None:
    """Refuse the first (name, value, least value) below its least value. A name is the flag, followed by the
    settings field where it is spelled otherwise (`--heartbeat (heartbeat_seconds)`), so that the message reads right
    from the command line and from Python."""
    for name, value, low in limits:
        if value < low:
            raise CanterError(f"{name} must be >= {low:g}, got {value:g}")


def _maker(study: Any) -> str | None:
    """The command that made a study without COMMAND_ATTR, by what it holds; None for one that holds neither's."""
    if SETTINGS_ATTR in study.user_attrs:
        return "tune"
    for trial in study.get_trials(deepcopy=False):
        for command, attr in TRIAL_MARKS.items():
            if attr in trial.user_attrs:
                return command
    return None


def claim_study(study: Any, command: str) -> None:
    """Mark `study` as `command`'s (bench or tune), or refuse one that the other command made."""
    marked = study.user_attrs.get(COMMAND_ATTR)
    owner = marked or _maker(study)
    if owner is not None and owner != command:
        raise CanterError(
            f"study '{study.study_name}' holds a canter {owner}'s {'jobs' if owner == 'bench' else 'trials'}; give "
            f"this {command} another --study (or another --storage)"
        )
    if marked is None:
        study.set_user_attr(COMMAND_ATTR, command)


def study_files_in(folder: Path) -> list[str]:
    """What marks `folder` as a study folder of tune: a study.db that holds a tune study, or trials/ with trial
    folders in it; empty for any other folder. A best.toml or summary.md alone may be a copy the user keeps, and a
    bench that shares its grid through a SQLite --storage may keep its database under the same name."""
    folder = Path(folder)
    held = [DB_FILE] * _holds_a_tune_study(folder / DB_FILE)
    trials = folder / TRIALS_FOLDER
    if trials.is_dir() and any(_TRIAL_FOLDER.fullmatch(p.name) and p.is_dir() for p in trials.iterdir()):
        held.append(f"{TRIALS_FOLDER}/")
    return held


def _holds_a_tune_study(db: Path) -> bool:
    """Whether the SQLite file `db` holds a study that tune made, read without writing to it (a worker may be using
    it); False for anything that cannot be read as an Optuna database."""
    import json
    import sqlite3

    if not db.is_file():
        return False
    try:
        uri = f"{db.resolve().as_uri()}?mode=ro"
        with contextlib.closing(sqlite3.connect(uri, uri=True, timeout=5)) as connection:
            rows = connection.execute(
                "SELECT key, value_json FROM study_user_attributes WHERE key IN (?, ?)", (COMMAND_ATTR, SETTINGS_ATTR)
            ).fetchall()
        # A study from before COMMAND_ATTR was kept is tune's by its settings (`_maker`).
        return any(key == SETTINGS_ATTR or json.loads(value) == "tune" for key, value in rows)
    except (sqlite3.Error, ValueError, OSError):
        return False


@dataclass(frozen=True)
class StorageSettings:
    url: str
    heartbeat_seconds: int = 60
    grace_seconds: int = 180
    max_retry: int = 3


def study_storage(url: str, heartbeat_seconds: int) -> StorageSettings:
    """The storage settings of a study whose workers beat every `heartbeat_seconds` (tune's, and bench's with
    --storage)."""
    return StorageSettings(url, heartbeat_seconds, GRACE_HEARTBEATS * heartbeat_seconds)


def normalize_url(url: str) -> str:
    """`postgresql://` means the psycopg2 driver of the `distributed` extra (SQLAlchemy 2.1 would pick psycopg 3)."""
    if url.startswith(("postgresql://", "postgres://")):
        return "postgresql+psycopg2://" + url.split("://", 1)[1]
    return url


def driver_hint(driver: str) -> str:
    """How to get the driver a storage URL names: the `distributed` extra brings psycopg2 only, so another
    PostgreSQL driver (postgresql+psycopg, +asyncpg) is the user's to install, or plain postgresql:// to use it."""
    if driver == "postgresql+psycopg2":
        return "pip install 'canter[distributed]'"
    if driver.startswith("postgresql+"):
        other = driver.split("+", 1)[1]
        return f"install the {other} driver, or use postgresql:// (psycopg2, from pip install 'canter[distributed]')"
    return f"install a Python driver for {driver} (pip install 'canter[distributed]' provides PostgreSQL's psycopg2)"


def redacted(url: str) -> str:
    """The URL with its password, if any, replaced by ***: error messages end up in logs and terminals."""
    return re.sub(r"(://[^/@:]*:).*@", r"\1***@", url)


_URL_FORMS = "sqlite:///path/study.db or postgresql://user:password@host:5432/dbname"


def describe_url(url: str) -> tuple[str, str]:
    """(driver, host) of a storage URL, without the password."""
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError, NoSuchModuleError

    try:
        parsed = make_url(url)
    except (ArgumentError, ValueError):  # ValueError: a port that is not a number
        raise CanterError(f"--storage {redacted(url)!r} is not a database URL; use {_URL_FORMS}") from None
    driver = parsed.drivername
    try:
        parsed.get_dialect()  # only SQLAlchemy's module for the scheme, not the database driver it will import
    except NoSuchModuleError:  # SQLAlchemy would say only "Can't load plugin: sqlalchemy.dialects:foo"
        raise CanterError(
            f"--storage {redacted(url)!r}: unknown database scheme {driver!r}; use {_URL_FORMS}"
        ) from None
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


def _absolute_path_hint(driver: str, path: str) -> str:
    """sqlite:///tmp/x.db names tmp/x.db under the current folder; an absolute path takes a fourth slash. Said where
    the relative path's folder is missing and the absolute one's is there, as when the user meant /tmp/x.db."""
    if not driver.startswith("sqlite") or not path or Path(path).is_absolute() or Path(path).parent.is_dir():
        return ""
    if not Path("/", path).parent.is_dir():
        return ""
    return f"; sqlite:///{path} is relative to the current folder: for /{path}, write sqlite:////{path}"


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
        raise CanterError(
            f"cannot use the {driver} storage at {host}: its database driver is not installed; {driver_hint(driver)}"
        ) from None
    except (sqlalchemy.exc.SQLAlchemyError, OSError, ValueError) as exc:
        raise CanterError(
            f"cannot connect to the {driver} storage at {host}: {_reason(exc)}{_absolute_path_hint(driver, host)}"
        ) from None
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
                # Optuna names the upgrade of a schema it knows, and `pip install -U optuna` for one it does not.
                if "compatible with the table schema" not in str(exc):
                    raise
                if "storage upgrade" in str(exc):
                    raise CanterError(
                        f"the study database at {host} was made by an older Optuna than this one "
                        f"({optuna.__version__}); back it up and run `optuna storage upgrade --storage URL`, or "
                        f"give another --storage"
                    ) from None
                raise CanterError(
                    f"the study database at {host} was made by a newer Optuna than this one "
                    f"({optuna.__version__}); run the command from a canter with the Optuna version that made it "
                    f"(upgrade canter here), or give another --storage"
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
    started, delay, said = time.monotonic(), 0.5, False
    while True:
        try:
            return call()
        except Exception as exc:
            if not _lost_storage(exc):
                raise
            waited = time.monotonic() - started
            if not said:  # a worker waiting on its storage says so, rather than look hung
                driver, host = describe_url(normalize_url(url))
                print(
                    f"canter: note: lost the {driver} storage at {host} while {what}; retrying for up to "
                    f"{patience / 60:.0f} min",
                    file=sys.stderr,
                    flush=True,
                )
                said = True
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
    """One line when a worker starts waiting on trials that other workers run (of this command or another): after a
    kill, a stale trial is failed and retried only once its heartbeat is older than the grace period, minutes in which
    nothing else is printed."""
    if not running:
        return
    shown = ", ".join(f"trial {number}" + (f" ({worker})" if worker != "?" else "") for number, worker in running[:3])
    more = f" and {len(running) - 3} more" if len(running) > 3 else ""
    retried = f"{grace:.0f} s" if grace else "its grace period"
    print(
        f"waiting for {shown}{more}, which another worker runs; a trial whose worker died is failed and retried "
        f"after {retried} without a heartbeat",
        flush=True,
    )


def queue_copy(study: Any, trial: Any, max_retry: int | None, stopped: bool = False) -> None:
    """Queue a copy of `trial` (a FrozenTrial) with its parameters, with the system attrs of Optuna's
    `RetryHeartbeatStaleTrialCallback` (`retried_trial_number` names the original, `retry_history` every failed
    copy), up to `max_retry` copies in a row (None: no limit). The copies of trials that a stop failed (`stopped`)
    count toward no limit. The copy leaves out the original's worker and failure: its own worker records them, and
    until then a worker on the dead one's machine would take it for the dead one's trial (`_fail_dead_workers_trials`).
    """
    import optuna

    history = [*trial.system_attrs.get("retry_history", []), trial.number]
    stops = [*trial.system_attrs.get(STOPPED_ATTR, []), *([trial.number] if stopped else [])]
    if max_retry is not None and len(history) - len(stops) > max_retry:
        return
    study.add_trial(
        optuna.trial.create_trial(
            state=optuna.trial.TrialState.WAITING,
            params=trial.params,
            distributions=trial.distributions,
            user_attrs={k: v for k, v in trial.user_attrs.items() if k not in (FAIL_REASON, WORKER_ATTR, PROCESS_ATTR)},
            system_attrs={
                "failed_trial": trial.number,
                **trial.system_attrs,
                "retry_history": history,
                STOPPED_ATTR: stops,
            },
        )
    )


def _process_of(pid: int) -> tuple[str, str] | None:
    """(state, start time in clock ticks since boot) of process `pid`, from /proc; None where it cannot be read (no
    such process, or another user's under a /proc mounted with hidepid)."""
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
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # another user's live process
        pass
    found = _process_of(int(pid))
    if found is None:  # alive, but /proc hides it: the heartbeat tells whether the pid still is the worker
        return False
    return found[1] != start or found[0] in ("Z", "X")  # a zombie has ended, unreaped


def _fail_if_running(storage: Any, trial_id: int, reason: str | None) -> bool:
    """Fail a running trial, with `reason` as its FAIL_REASON, in one UPDATE that changes only a RUNNING trial; False
    where another worker failed or finished it first. Of the workers that sweep at once, only the one that failed
    the trial queues its copy: Optuna's read-then-write let several through on SQLite, where FOR UPDATE is a no-op."""
    import json
    from datetime import datetime

    import sqlalchemy
    from optuna.storages._rdb import models
    from optuna.trial import TrialState

    trials, attrs = models.TrialModel, models.TrialUserAttributeModel
    with storage.engine.begin() as connection:
        failed = connection.execute(
            sqlalchemy.update(trials)
            .where(trials.trial_id == trial_id, trials.state == TrialState.RUNNING)
            .values(state=TrialState.FAIL, datetime_complete=datetime.now())
        ).rowcount
        if failed and reason is not None:
            connection.execute(sqlalchemy.delete(attrs).where(attrs.trial_id == trial_id, attrs.key == FAIL_REASON))
            connection.execute(
                sqlalchemy.insert(attrs).values(trial_id=trial_id, key=FAIL_REASON, value_json=json.dumps(reason))
            )
    return bool(failed)


def _fail_stale_trials(study: Any, storage: Any) -> None:
    """Optuna's `fail_stale_trials`, failing each trial with `_fail_if_running`, so that one copy is queued however
    many workers find the trial stale at once."""
    callback = storage.get_heartbeat_stale_trial_callback()
    for trial_id in storage._get_stale_trial_ids(study._study_id):
        if _fail_if_running(storage, trial_id, None) and callback is not None:
            callback(study, copy.deepcopy(storage.get_trial(trial_id)))


def _fail_dead_workers_trials(study: Any, storage: Any) -> None:
    """Fail the running trials whose worker was a process of this machine that has ended (kill -9, the OOM killer),
    and queue their copies as a stale heartbeat would: their heartbeat would keep this worker waiting 3 intervals."""
    from optuna.trial import TrialState

    machine = _this_machine()
    if machine is None:
        return
    for trial in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        if not _worker_gone(trial, machine):
            continue
        snapshot = copy.deepcopy(trial)
        if not _fail_if_running(storage, trial._trial_id, "worker died (its process is gone)"):
            continue  # another worker failed it first, and queued its copy
        print(
            f"trial {trial.number}: its worker {trial.user_attrs.get(WORKER_ATTR, '?')} on this machine is gone, so "
            f"the trial is failed now rather than after the heartbeat grace period, and retried as a stale one is",
            flush=True,
        )
        callback = storage.get_heartbeat_stale_trial_callback()
        if callback is not None:
            callback(study, snapshot)


def _faults(study: Any) -> tuple[int, str | None]:
    """The failed trials that count toward a worker's limit on failures (not those of a stop or a surplus), and the
    reason of the last of them."""
    from optuna.trial import TrialState

    reasons = [t.user_attrs.get(FAIL_REASON) for t in study.get_trials(deepcopy=False, states=(TrialState.FAIL,))]
    faults = [reason for reason in reasons if reason not in NO_FAULT]
    return len(faults), next((reason for reason in reversed(faults) if reason is not None), None)


def _fail_gone_then_count(study: Any, storage: Any) -> tuple[dict[str, int], int]:
    """The study's trials by state and its number of faults (`_faults`), once the trials of workers known to be gone
    are failed and retried."""
    _fail_dead_workers_trials(study, storage)
    _fail_stale_trials(study, storage)
    return counts(study), _faults(study)[0]


def _stop_interrupted(study: Any, trial: Any, target: int | None) -> None:
    """Fail a trial that Ctrl-C or SIGTERM stopped, so that nobody waits for its heartbeat, and queue a copy with its
    parameters for the next run, unless the study has its `target` finished trials already (or `target` is None: a
    queue of fixed work queues its items itself). A stop is no fault of the trial, so its copies are not limited in
    number; a trial failed meanwhile by another worker has its copy already."""
    import optuna
    from optuna.trial import TrialState

    snapshot = copy.deepcopy(study._storage.get_trial(trial._trial_id))
    try:
        trial.set_user_attr(FAIL_REASON, INTERRUPTED)
        study.tell(trial, state=TrialState.FAIL)
    except (ValueError, optuna.exceptions.UpdateFinishedTrialError):  # ValueError: study.tell of a finished trial
        return
    if target is None:
        return
    n = counts(study)
    if n["COMPLETE"] + n["PRUNED"] >= target:
        print(f"trial {trial.number} is not queued again: the study has its number of trials", flush=True)
        return
    queue_copy(study, snapshot, max_retry=None, stopped=True)
    print(f"trial {trial.number} is queued again with its parameters; the same command trains it", flush=True)


def restart_study(study: Any) -> Any:
    """`study` made again under its name, with its attrs, for other settings: only a study with no finished or
    running trial, which the caller checks. Optuna keeps each parameter's first distribution for the whole study and
    refuses another (other choices, or a log range made linear), so the old trials come back as failed trials
    without their parameters; they keep their numbers, which their trial folders bear, and their failure reasons."""
    import optuna

    storage, name = study._storage, study.study_name
    trials = study.get_trials(deepcopy=True)
    user_attrs, system_attrs = dict(study.user_attrs), storage.get_study_system_attrs(study._study_id)
    optuna.delete_study(study_name=name, storage=storage)
    fresh = optuna.create_study(
        storage=storage, study_name=name, direction=study.direction, sampler=study.sampler, pruner=study.pruner
    )
    for key, value in user_attrs.items():
        fresh.set_user_attr(key, value)
    for key, value in system_attrs.items():
        storage.set_study_system_attr(fresh._study_id, key, value)
    fresh.add_trials([_without_params(trial) for trial in trials])
    return fresh


def _without_params(trial: Any) -> Any:
    """A failed trial as `restart_study` keeps it; a queued one fails as RESTARTED, since it would run old settings."""
    import optuna
    from optuna.trial import TrialState

    user_attrs = dict(trial.user_attrs)
    if trial.state != TrialState.FAIL:
        user_attrs[FAIL_REASON] = RESTARTED
    return optuna.trial.create_trial(state=TrialState.FAIL, user_attrs=user_attrs, system_attrs=trial.system_attrs)


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

    A worker gives up with a one-line error once `max(10, 2 * target)` trials in a row have failed since it started
    or the study last finished one (a space or a command that cannot work, such as a space edited under a resumed
    study); trials failed by a stop or as surplus (`NO_FAULT`) do not count.

    Every storage call waits out an outage of up to `outage_seconds` (`retrying`). A trial that ran through one is
    told when the storage is back; if another worker failed it meanwhile (its heartbeat went stale), that worker
    retries it and this outcome is dropped, so no trial counts twice."""
    from optuna.trial import TrialState

    def call(what: str, fn: Callable[[], T]) -> T:
        return retrying(fn, storage.url, what, outage_seconds)

    states = {"complete": TrialState.COMPLETE, "pruned": TrialState.PRUNED, "fail": TrialState.FAIL}
    give_up = max(10, 2 * target)
    progress: tuple[int, int] | None = None  # (finished, faults) as this worker started or the finished count grew
    waited_for: tuple[tuple[int, str], ...] = ()  # the running trials this worker last said it waits for
    while True:
        n, faults = call("reading the study", functools.partial(_fail_gone_then_count, study, storage))
        finished = n["COMPLETE"] + n["PRUNED"]
        if (ask_new and finished >= target) or (deadline is not None and time.time() >= deadline):
            return
        if progress is None or finished > progress[0]:
            # A rerun counts its own failures: the one before may have stopped on a cause fixed since.
            progress = (finished, faults)
        if ask_new and faults - progress[1] >= give_up:
            done = f"since the last of its {finished} finished trials" if finished else "and none finished"
            last = call("reading the study", functools.partial(_faults, study))[1]
            raise CanterError(
                f"study '{study.study_name}': {faults - progress[1]} trials failed in a row {done}; the last one: "
                f"{last or 'no reason recorded'}; fix that and run the same command again (each failed trial keeps "
                f"its '{FAIL_REASON}' in the study)"
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
        asked: list[Any] = []  # the trial, from the moment the storage hands it out
        try:
            stop = call("asking for a trial", functools.partial(_ask, study, asked))
            trial = asked[0]
            with _Heartbeat(storage, trial, heartbeat_seconds):
                stop.deliver()  # from here a stop fails the trial and queues it again (below)
                if ask_new and call("reading the study", functools.partial(_surplus, study, trial.number, target)):
                    _tell(study, trial, Outcome("fail", reason=SURPLUS), TrialState.FAIL, call)
                    continue
                for attr, value in _worker_attrs().items():
                    call("recording a trial", functools.partial(trial.set_user_attr, attr, value))
                try:
                    outcome = run_trial(trial)
                except Exception as exc:  # the trial fails with the reason; the study goes on
                    if unread_stdout(exc):
                        raise
                    outcome = Outcome("fail", reason=f"{type(exc).__name__}: {exc}"[:500])
        except BaseException as exc:
            # A stop, or a stdout nobody reads any more, fails the trial and queues it again (a queue of fixed work
            # queues its failed items itself when run again); after an error, such as a storage gone for good, the
            # trial is left to its heartbeat.
            if asked and (not isinstance(exc, Exception) or unread_stdout(exc)):
                with contextlib.suppress(Exception):  # a trial left running is failed by heartbeat and retried
                    stopped = functools.partial(_stop_interrupted, study, asked[0], target if ask_new else None)
                    call("recording the stopped trial", stopped)
            raise
        _tell(study, trial, outcome, states[outcome.state], call)


def unread_stdout(exc: BaseException) -> bool:
    """Whether `exc` is a print that failed because nothing reads stdout any more (`canter tune | head -1`, a
    terminal that hung up): no fault of the trial, so the worker stops as a stop signal stops it and the trial is
    queued again, rather than fail trial after trial until it gives up."""
    return isinstance(exc, OSError) and stdout_is_gone()


def say(line: str) -> None:
    """Print a line of a worker's progress. Where nothing reads stdout any more the line is dropped, so that the
    outcome it reports is still recorded; the worker stops at the next print, when its next trial starts."""
    try:
        print(line, flush=True)
    except OSError as exc:
        if not unread_stdout(exc):
            raise


def _ask(study: Any, asked: list[Any]) -> StopFlag:
    """Ask `study` for a trial, appended to `asked` as soon as the storage hands it out, with Ctrl-C and SIGTERM held
    back meanwhile in the StopFlag returned, for the caller to deliver once a stop fails the trial and queues it again:
    raised inside `study.ask`, after the storage has made the trial RUNNING, a stop would leave it running with no
    heartbeat and no worker recorded, which no worker fails and every rerun waits for. A stop during a try that
    failed acts at once, rather than once an outage of the storage is over."""
    stop = StopFlag()
    try:
        with stop:
            asked.append(study.ask())
    except Exception:
        stop.deliver()
        raise
    return stop


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
