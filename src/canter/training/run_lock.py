"""One writer per run folder.

Every process that writes to a run folder (`canter train`, `--resume`, a bench or tune job) holds an exclusive
`flock` on RUN/.writer.lock for as long as it writes; a second writer is refused with one line that names the
holder, whose pid, host, start time and command the file records. The operating system releases a flock when its
process dies, however it dies, so a lock left by a killed process is simply taken over. Where the filesystem has
no flock, the recorded pid decides: a holder on this host that is no longer alive is taken over.

Readers (eval, plot, report, export, video) never take the lock: a run folder's files are written whole
(checkpoints atomically, metrics.csv a whole line at a time), so a reader sees a consistent folder at any moment.

Taking the lock also removes what a killed writer left half-written: the temp files of atomic writes
(`.NAME.*.tmp`, `.NAME.*.tmp.mp4`). No other process writes the folder then, so none of them is being written. A
video snapshot (`videos/.snapshot_*.npz`) is whole: a resume renders the video of one up to its checkpoint and
removes one past it (`canter.training.videos`).

Locks are re-entrant within a process: a bench job holds its folders while it trains and evaluates them, and the
trainer it calls takes them again.

Each lock holds a file open for as long as its run, so a group of thousands of seeds can exceed the process's limit
of open files (`ulimit -n`): the trainer refuses such a group before it makes a folder (`check_open_files`), and
running out of files while locking is one line too, the folders made for the locks removed again.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import resource
import socket
import sys
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from types import TracebackType
from typing import Any

from canter.errors import CanterError
from canter.files import WriteError, is_write_error, make_folder
from canter.parsing import json_value
from canter.run_layout import LOCK_FILE as LOCK_FILE  # re-exported: bench and job code name it through this module

OUT_OF_FILES = (errno.EMFILE, errno.ENFILE)  # the process's or the system's table of open files is full
FILES_PER_RUN = 3  # what a training run keeps open: its writer lock, metrics.csv and TensorBoard's events
SPARE_FILES = 32  # what a process opens beyond its runs': envs, evaluations, a video's encoder, the libraries


@dataclass
class _Held:
    fd: int  # the open lock file, whose flock this process holds
    created: list[Path]  # the folder and the folders above it that this process created, innermost first
    holds: int = 1


# resolved run folder -> this process's hold on it: one flock per folder per process
_HELD: dict[Path, _Held] = {}


def command_line() -> str:
    """This process's command line, as the user would recognise it (`canter train ...`, a job's `jobs.py SPEC`)."""
    if not sys.argv or not sys.argv[0]:
        return "python"
    program = Path(sys.argv[0]).name
    if program in ("canter", "__main__.py"):  # the entry point, or python -m canter.cli
        program = "canter"
    return " ".join([program, *sys.argv[1:]])


def write_holder(fd: int, **fields: str) -> None:
    """Record this process in the lock file `fd` whose flock it holds: pid, host, start time and command, with
    `fields` added or replacing them (a command with a password left out, say)."""
    record = {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "started": datetime.now().isoformat(timespec="seconds"),
        "command": command_line(),
        **fields,
    }
    os.ftruncate(fd, 0)
    os.pwrite(fd, json.dumps(record).encode(), 0)


def read_holder(run_dir: Path) -> dict[str, Any]:
    """What the lock file records of the process that last took it ({} when there is none or it is unreadable)."""
    try:
        found = json_value((Path(run_dir) / LOCK_FILE).read_text())
    except (OSError, ValueError):
        return {}
    return found if isinstance(found, dict) else {}


def alive_here(holder: dict[str, Any]) -> bool:
    """Whether the recorded holder is a live process on this host (one on another host counts as alive)."""
    if holder.get("host") != socket.gethostname():
        return bool(holder)
    if holder.get("pid") == os.getpid():  # this process, which released it
        return False
    try:
        os.kill(int(holder["pid"]), 0)
    except (KeyError, ValueError, TypeError, ProcessLookupError):
        return False
    except PermissionError:
        return True
    return True


class RunFolderBusy(CanterError):
    """Another process writes the run folder: a refusal that a later try meets no more once it has finished."""


# The fix a busy folder's refusal ends with, after the holder; a bench that waits for the folder prints the rest.
BUSY_FIX = "one process writes a run folder at a time: wait for it to finish or stop it, then run the command again"


def _refusal(run_dir: Path, holder: dict[str, Any]) -> CanterError:
    who = "another process"
    if holder:
        who = f"process {holder.get('pid')} on {holder.get('host')}"
        who += f" (since {holder.get('started')}: {holder.get('command')})"
    return RunFolderBusy(f"{run_dir} is being written by {who}; {BUSY_FIX}")


def flock(fd: int, shared: bool = False) -> bool | None:
    """Take the flock, exclusive or `shared`: True, False when another process holds it (exclusively, for a shared
    one), None where the filesystem has no flock."""
    try:
        fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    except OSError as exc:
        if exc.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS):
            return None
        raise
    return True


def open_lock_file(run_dir: Path) -> int:
    """The folder's lock file opened for writing, the folder made first where it is missing; a full or read-only
    disk is a WriteError."""
    path = Path(run_dir) / LOCK_FILE
    make_folder(path.parent)  # a file in the way is named as such
    try:
        return os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as exc:
        if is_write_error(exc):
            raise WriteError(path, exc) from None
        raise


def acquire(run_dir: Path) -> None:
    """Hold the run folder's writer lock, or raise a one-line CanterError naming the process that holds it. A
    folder that does not exist yet is created (with the folders above it), and removed again at `release` if
    nothing but the lock was written to it, or at once if taking the lock fails. Each `acquire` is matched by a
    `release`."""
    run_dir = Path(run_dir)
    key = run_dir.resolve()
    if key in _HELD:
        _HELD[key].holds += 1
        return
    path = run_dir / LOCK_FILE
    created = missing_folders(run_dir)
    try:
        fd = open_lock_file(run_dir)
    except BaseException:
        _remove_created(created)
        raise
    try:
        locked = flock(fd)
        holder = read_holder(run_dir)
        if locked is False or (locked is None and alive_here(holder)):
            raise _refusal(run_dir, holder)
        write_holder(fd)
        _remove_half_written(run_dir)
    except BaseException as exc:
        os.close(fd)
        if isinstance(exc, OSError):  # not a refusal, where another process may have the lock file open
            _remove_created(created)
        if is_write_error(exc):
            assert isinstance(exc, OSError)
            raise WriteError(path, exc) from None
        raise
    _HELD[key] = _Held(fd, created)


def _remove_created(created: list[Path]) -> None:
    """Remove the folders (innermost first) that `acquire` made, with the lock file in them; a folder that something
    else has written to since stays. Neither needs a file descriptor, which a process that ran out of them has none
    of."""
    if not created:
        return
    with contextlib.suppress(OSError):
        (created[0] / LOCK_FILE).unlink(missing_ok=True)
        for folder in created:
            folder.rmdir()


def missing_folders(run_dir: Path) -> list[Path]:
    """`run_dir` and each folder above it that does not exist yet, innermost first: those that making it makes."""
    missing = []
    for folder in (run_dir, *run_dir.absolute().parents):
        if folder.exists() or folder.is_symlink():
            break
        missing.append(folder)
    return missing


# Video snapshots are whole (written atomically): a resume renders those its videos still lack (canter.training.videos).
HALF_WRITTEN = (".*.tmp", ".*.tmp.*", "checkpoints/.*.tmp", "videos/.*.tmp", "videos/.*.tmp.*")


def _remove_half_written(run_dir: Path) -> None:
    for pattern in HALF_WRITTEN:
        for path in run_dir.glob(pattern):
            path.unlink(missing_ok=True)


def release(run_dir: Path) -> None:
    key = Path(run_dir).resolve()
    held = _HELD.get(key)
    if held is None:
        return
    held.holds -= 1
    if held.holds:
        return
    del _HELD[key]
    fd: int | None = held.fd
    try:
        unwritten = bool(held.created) and _holds_only_the_lock(held.created[0])
    except OSError as exc:
        if exc.errno not in OUT_OF_FILES:
            os.close(held.fd)
            raise
        # Listing the folder takes a descriptor, which a process that ran out of them gets by closing this lock's.
        os.close(held.fd)
        fd = None
        unwritten = _holds_only_the_lock(held.created[0])
    if unwritten:  # a run that failed before writing anything leaves no folder behind, nor the --out-dir made for it
        _remove_created(held.created)
    if fd is not None:
        os.close(fd)  # releases the flock; the file stays, so every writer locks the same file


def _holds_only_the_lock(folder: Path) -> bool:
    return [p.name for p in folder.iterdir()] == [LOCK_FILE]


def open_files_refusal(runs: int, per_run: int, open_now: int, limit: int, hard: int) -> CanterError | None:
    """The one-line error when `runs` run folders that keep `per_run` files open each, in a process with `open_now`
    files open already, exceed its limit of open files (`limit`, at most `hard`; RLIM_INFINITY: none), else None."""
    need = open_now + SPARE_FILES + runs * per_run
    if limit == resource.RLIM_INFINITY or need <= limit:
        return None
    fits = (limit - open_now - SPARE_FILES) // per_run
    raised = 1 << (need - 1).bit_length()  # a round number, as ulimit -n values go
    if hard != resource.RLIM_INFINITY:
        raised = min(raised, hard)
    fixes = [f"train at most {fits} seeds at a time" if fits > 1 else "train one seed at a time"] if fits >= 1 else []
    if raised >= need:
        fixes.append(f"raise the limit first, e.g. `ulimit -n {raised}`")
    else:
        fixes.append(f"have the hard limit (ulimit -Hn, now {hard}) raised to {need} or more")
    return CanterError(
        f"{runs} runs at once keep about {runs * per_run} files open ({per_run} each: its lock, metrics.csv, "
        f"TensorBoard's events), but this process may open only {limit} (ulimit -n); {', or '.join(fixes)}"
    )


def check_open_files(runs: int, per_run: int = FILES_PER_RUN) -> None:
    """Refuse, before any run folder is made, a group whose open files the process's limit cannot hold."""
    limit, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    try:
        open_now = len(os.listdir("/proc/self/fd"))
    except OSError:  # no /proc: SPARE_FILES stands in for them
        open_now = 0
    error = open_files_refusal(runs, per_run, open_now, limit, hard)
    if error is not None:
        raise error


def out_of_files(locked: int) -> CanterError:
    limit = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    return CanterError(
        f"this process ran out of open files after locking {locked} run folders (ulimit -n is {limit}); "
        f"use fewer at once (fewer seeds), or raise the limit first, e.g. `ulimit -n {2 * limit}`"
    )


class RunLocks(contextlib.AbstractContextManager["RunLocks"]):
    """The writer locks of several run folders, all released on exit."""

    def __init__(self) -> None:
        self._held: list[Path] = []

    def take(self, run_dir: Path) -> None:
        """Lock `run_dir` too; out of open files, a one-line error, and the folders made for the locks go on exit."""
        try:
            acquire(run_dir)
        except OSError as exc:
            if exc.errno in OUT_OF_FILES:
                raise out_of_files(len(self._held)) from None
            raise
        self._held.append(Path(run_dir))

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        for run_dir in reversed(self._held):
            release(run_dir)
        self._held.clear()
