"""Safe file output: whole files appear atomically, and a path that cannot be written gives a one-line error."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

from canter.errors import CanterError


def atomic_write_bytes(path: Path, writer: Callable[[BinaryIO], object]) -> None:
    """Call writer(file_object) on a temp file next to `path`, then rename it into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            writer(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_output(path: str | Path, data: bytes) -> None:
    """Write a user-named output atomically, with a one-line error when the path is not writable."""
    try:
        atomic_write_bytes(Path(path), lambda f: f.write(data))
    except OSError as exc:
        raise CanterError(f"cannot write {path}: {exc.strerror or exc}; pick a writable path") from None


def check_writable(path: str | Path) -> None:
    """Fail early, before any long computation, when an output path cannot be written (nothing is left behind)."""
    folder = Path(path).parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".canter-probe-", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise CanterError(f"cannot write {path}: {exc.strerror or exc}; pick a writable path") from None
