"""Safe file output: whole files appear atomically, and a path that cannot be written gives a one-line error."""

from __future__ import annotations

import contextlib
import errno
import glob
import hashlib
import os
import socket
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

from canter.errors import CanterError
from canter.run_layout import (
    LOCK_FILE,
    RUN_OWN_FILES,
    RUN_OWN_FOLDERS,
    STEP_VIDEO,
    VIDEO_WORK_FILES,
    VIDEOS_FOLDER,
    surely_a_run,
)

# A full disk or quota, where freeing space is the fix; the other write errors need a writable path or device.
_NO_SPACE = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})
_WRITE_ERRORS = _NO_SPACE | {errno.EACCES, errno.EPERM, errno.EROFS, errno.EIO}


def _process_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


# mkstemp makes its file readable by its owner only; a file renamed into place gets the mode a plain open() would
# give it, so outputs are as readable as any other file the user writes.
OUTPUT_FILE_MODE = 0o666 & ~_process_umask()


class WriteError(CanterError):
    """A file could not be written (a full disk, no permission, a read-only or failing device). The message names
    the path, the reason and a fix; `resumable` gives the same error with another last step."""

    def __init__(self, path: str | Path, exc: OSError, then: str = "run the command again") -> None:
        self.path, self.exc = Path(path), exc
        super().__init__(f"cannot write {path}: {exc.strerror or exc}; {self.fix(then)}")

    @property
    def no_space(self) -> bool:
        return self.exc.errno in _NO_SPACE

    def fix(self, then: str) -> str:
        folder = _nearest_existing(self.path.parent)  # where a refused mkdir of missing folders failed
        if self.no_space:
            return f"free space in {folder}, then {then}"
        return f"make {folder} writable (or pick another path), then {then}"

    def resumable(self, then: str) -> WriteError:
        return WriteError(self.path, self.exc, then)


def _nearest_existing(folder: Path) -> Path:
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    return folder


def not_a_regular_file(path: Path) -> CanterError:
    """The error for a file canter reads or appends to (a run's metrics.csv, a log) that is a folder, pipe or device:
    reading a pipe would wait for a writer that never comes, so it is refused before it is opened."""
    what = "a folder, not a file" if path.is_dir() else "not a regular file (a device, pipe or socket)"
    return CanterError(f"{path} is {what}; move it away and restore {path.name} from a copy")


def refuse_not_regular(path: Path) -> None:
    """Refuse `path` where something other than a regular file holds its name (see `not_a_regular_file`); a link is
    judged by what it points to, and a dangling one is a missing file, which an append creates."""
    if path.exists() and not path.is_file():
        raise not_a_regular_file(path)


def _in_the_way(path: Path) -> Path | None:
    """`path` itself or the folder on the way to it that already exists as something other than a folder."""
    for part in (path, *path.parents):
        if part.is_dir():
            return None
        if part.exists() or part.is_symlink():
            return part
    return None


def _not_a_folder(path: Path, itself: str) -> str | None:
    """Why `path` cannot be a folder when it, or a folder on the way to it, already exists as something else;
    `itself` is what the reason calls `path` (`it`, where the message has named it)."""
    part = _in_the_way(path)
    if part is None:
        return None
    what = "is a file, not a folder" if part.is_file() else "is not a folder"
    return f"{itself if part == path else part} {what}"


def make_folder(path: str | Path) -> None:
    """Create a user-named output folder (and its parents), with a one-line error when it cannot be."""
    try:
        Path(path).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        if is_write_error(exc):
            raise WriteError(path, exc) from None
        # mkdir says only `File exists` or `Not a directory`, without naming what is in the way.
        # A path canter derived (a bench cell's run folder) is not the user's to pick: moving the file frees it.
        blocker = _in_the_way(Path(path))
        why = _not_a_folder(Path(path), "it") or exc.strerror or str(exc)
        fix = f"move {blocker} out of the way, or pick another path" if blocker else "pick another path"
        raise CanterError(f"cannot make the folder {path}: {why}; {fix}") from None


def is_write_error(exc: BaseException) -> bool:
    """An OSError that a write can raise because of the disk or its permissions, not because of a bug."""
    return isinstance(exc, OSError) and exc.errno in _WRITE_ERRORS


def _host_tag() -> str:
    """This machine and its process-ID namespace (containers that share a host name have their own), in each temp
    file's name: of a folder that several share, only the temp files of this one's processes can be known to be
    orphaned."""
    try:
        namespace = str(os.stat("/proc/self/ns/pid").st_ino)
    except OSError:  # no /proc: the host name alone
        namespace = ""
    return hashlib.sha1(f"{socket.gethostname()}/{namespace}".encode()).hexdigest()[:6]


_HOST_TAG = _host_tag()


def temp_prefix(name: str) -> str:
    """The start of the name of a temp file beside the output named `name`: hidden, and naming the machine and the
    process that writes it, so that a later writer of that output removes it once that process is gone."""
    return f".{name}.{_HOST_TAG}-{os.getpid()}-"


def remove_orphaned_temps(folder: Path, name: str) -> None:
    """Remove the temp files beside the output named `name` whose writer, a process of this machine, is gone: a
    kill (no handler runs) leaves its temp file, which no one else would remove."""
    prefix = f".{name}.{_HOST_TAG}-"
    try:
        temps = list(Path(folder).glob(glob.escape(prefix) + "*.tmp*"))
    except OSError:
        return
    for temp in temps:
        pid = temp.name[len(prefix) :].split("-", 1)[0]
        if pid.isascii() and pid.isdigit() and not _process_exists(int(pid)):
            with contextlib.suppress(OSError):
                temp.unlink()


def _process_exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OSError, OverflowError):  # another user's, say, or no process ID at all: left alone
        return True
    return True


def atomic_write_bytes(path: Path, writer: Callable[[BinaryIO], object]) -> None:
    """Call writer(file_object) on a temp file next to `path`, then rename it into place. A write error leaves
    no temp file and raises `WriteError`; `path` keeps its old content, and the temp files of earlier writers of
    `path` that were killed go."""
    if path.is_dir() and not path.is_symlink():  # before the writer, which may take long, runs in vain
        raise _naming(path, OSError(errno.EISDIR, os.strerror(errno.EISDIR)))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_orphaned_temps(path.parent, path.name)
        fd, tmp = tempfile.mkstemp(prefix=temp_prefix(path.name), suffix=".tmp", dir=path.parent)
    except OSError as exc:
        if is_write_error(exc):
            raise WriteError(path, exc) from None
        raise
    try:
        with os.fdopen(fd, "wb") as f:
            writer(f)
            f.flush()
            with contextlib.suppress(OSError):  # a file system without modes keeps its own
                os.fchmod(f.fileno(), OUTPUT_FILE_MODE)
            os.fsync(f.fileno())
        try:
            os.replace(tmp, path)
        except OSError as exc:
            raise _naming(path, exc) from None
    except BaseException as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if is_write_error(exc):
            assert isinstance(exc, OSError)
            raise WriteError(path, exc) from None
        raise


def _naming(path: Path, exc: OSError) -> OSError:
    """`exc` naming `path`: a failed rename names the temp file, which is removed, not what is in the way."""
    return OSError(exc.errno, exc.strerror, str(path))


def refuse_out_dir_in_a_run(folder: str | Path, flag: str, python: str = "") -> None:
    """Refuse a folder for new run or bench folders that is a run folder, or lies inside a run folder's own folder
    (checkpoints/, tb/): the run's listings would then meet foreign folders among its files, checkpoints or events.
    `python`: the name a Python caller gives the folder by, where one can."""
    resolved = Path(folder).resolve()
    fix = f"give another {flag}" + (f" ({python} from Python)" if python else "")
    if surely_a_run(resolved):
        raise CanterError(f"{flag} {folder} is a run folder, and new folders would be made among its own files; {fix}")
    for inner in (resolved, *resolved.parents):
        if inner.name in RUN_OWN_FOLDERS and surely_a_run(inner.parent):
            raise CanterError(
                f"{flag} {folder} is inside {inner.name}/ of the run folder {inner.parent}, which holds that run's own "
                f"files; {fix}"
            )


def refuse_protected_target(path: str | Path) -> None:
    """A user-named output that is not a plain file (a symlink, pipe or device, which the atomic rename would
    replace), or that is one of a run folder's own files, is refused in one line."""
    target = Path(path)
    if target.is_symlink() or (target.exists() and not target.is_file()):
        raise CanterError(f"cannot write {path}: it is not a plain file (a link, pipe or device); give a file path")
    resolved = target.resolve()
    if resolved.name in RUN_OWN_FILES and surely_a_run(resolved.parent):
        raise CanterError(f"cannot write {path}: it is a file of the run folder {resolved.parent}; give another path")
    if resolved.parent.name in RUN_OWN_FOLDERS and surely_a_run(resolved.parent.parent):
        raise CanterError(
            f"cannot write {path}: {resolved.parent.name}/ belongs to the run folder {resolved.parent.parent}; "
            f"give another path"
        )
    if resolved.name == LOCK_FILE:
        raise CanterError(
            f"cannot write {path}: {LOCK_FILE} is the writer lock that keeps two processes from training into one "
            f"folder; give another path"
        )
    if resolved.parent.name == VIDEOS_FOLDER and _a_video_file_of_the_run(resolved):
        raise CanterError(
            f"cannot write {path}: it is a file of the videos the run folder {resolved.parent.parent} renders as it "
            f"trains; give another path (a new name in {resolved.parent} will do)"
        )


def _a_video_file_of_the_run(path: Path) -> bool:
    """A saved step video or a renderer's file in a run's videos/ folder. A new step video stays writable: the
    trainer's own renderer writes it through these guards; other names there are the user's own videos."""
    if not surely_a_run(path.parent.parent):
        return False
    own = path.match(STEP_VIDEO) and (path.exists() or path.is_symlink())
    return own or any(path.match(pattern) for pattern in VIDEO_WORK_FILES)


def write_output(path: str | Path, data: bytes) -> None:
    """Write a user-named output atomically, with a one-line error when the path is not writable."""
    refuse_protected_target(path)
    try:
        atomic_write_bytes(Path(path), lambda f: f.write(data))
    except OSError as exc:  # not a write error (a folder where the file should be, ...): still the path's fault
        raise CanterError(f"cannot write {path}: {exc.strerror or exc}; pick a writable path") from None


def check_writable(path: str | Path) -> None:
    """Fail early, before any long computation, when an output path cannot be written (nothing is left behind)."""
    if Path(path).is_dir() and not Path(path).is_symlink():
        raise CanterError(f"cannot write {path}: it is a folder; give a file name (inside it, or elsewhere)")
    refuse_protected_target(path)
    folder = Path(path).parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".canter-probe-", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        if is_write_error(exc):
            raise WriteError(path, exc) from None
        why = _not_a_folder(folder, str(folder))
        raise CanterError(f"cannot write {path}: {why or exc.strerror or exc}; pick a writable path") from None


class AppendFile:
    """A file that grows by whole records (a metrics.csv line, a TensorBoard event): each `append` is written in
    full or cut back off, so a write error leaves the file as it was before it, and raises `WriteError`."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        # O_NONBLOCK: a named pipe in the file's place would block the open until a reader came; it fails at once
        # (ENXIO) or opens, and either way is refused. On a regular file the flag changes nothing.
        try:
            self._fd: int | None = os.open(
                self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NONBLOCK", 0), 0o666
            )
        except OSError as exc:
            if is_write_error(exc):
                raise WriteError(self.path, exc) from None
            if exc.errno in (errno.ENXIO, errno.EISDIR):
                raise not_a_regular_file(self.path) from None
            raise
        if not stat.S_ISREG(os.fstat(self._fd).st_mode):
            self.close()
            raise not_a_regular_file(self.path)

    def append(self, data: bytes) -> None:
        assert self._fd is not None, f"{self.path} is closed"
        size = os.fstat(self._fd).st_size
        view = memoryview(data)
        try:
            while view:
                view = view[os.write(self._fd, view) :]
        except OSError as exc:
            with contextlib.suppress(OSError):  # else readers skip the half record (training.logger.read_rows)
                os.ftruncate(self._fd, size)
            if is_write_error(exc):
                raise WriteError(self.path, exc) from None
            raise

    def sync(self) -> None:
        """Make what was appended durable (a machine that crashes after this keeps it)."""
        assert self._fd is not None, f"{self.path} is closed"
        try:
            os.fsync(self._fd)
        except OSError as exc:
            if is_write_error(exc):
                raise WriteError(self.path, exc) from None
            raise

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
