"""One module per `canter` subcommand. Each defines `register(subparsers)`, which adds its parser and sets
`func` to the function that runs it: `func(args) -> exit code`. `canter.cli.COMMANDS` lists them in help order."""

from __future__ import annotations

import argparse
from pathlib import Path

from canter.errors import CanterError


def steps_arg(text: str) -> int:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a step count such as 1000000 or 1e6, got {text!r}") from None
    if not value.is_integer() or value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole step count, got {text!r}")
    return int(value)


def add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seed", type=int, default=None, help="run seed")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def write_output(path: str | Path, data: bytes) -> None:
    """Write a user-named output atomically, with a one-line error when the path is not writable."""
    from canter.checkpoint import atomic_write_bytes

    try:
        atomic_write_bytes(Path(path), lambda f: f.write(data))
    except OSError as exc:
        raise CanterError(f"cannot write {path}: {exc.strerror or exc}; pick a writable path") from None


def check_writable(path: str | Path) -> None:
    """Fail early, before any long computation, when an output path cannot be written (nothing is left behind)."""
    import os
    import tempfile

    folder = Path(path).parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".canter-probe-", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise CanterError(f"cannot write {path}: {exc.strerror or exc}; pick a writable path") from None
