"""The `canter` command. Every user error is one line on stderr with a non-zero exit and no traceback."""

from __future__ import annotations

import argparse
import difflib
import errno
import importlib
import os
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

from canter.errors import CanterError, error_line
from canter.signals import (
    INTERRUPTED,
    end_of_interrupts,
    end_quietly_without_stdout,
    exit_interrupted,
    ignore_stop_signals,
    interrupt_once,
    stdout_is_gone,
)

# Subcommand modules under canter.cli, in help order. Each defines `register(subparsers)`, which adds its parser
# and sets `func(args) -> exit code`.
COMMANDS = ("train", "eval", "video", "plot", "export", "report", "tune", "bench")


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # argparse would print usage over several lines
        # main() already prefixes "canter: error:", so only a subcommand's name ("train") is worth adding.
        command = self.prog.removeprefix("canter").strip()
        raise CanterError(f"{command}: {message} (see --help)" if command else f"{message} (see --help)")


class _CommandParser(_Parser):
    """A command's parser, which takes its run folders (or env) before, between or after its flags: argparse fills
    a positional from one stretch of words, so `eval A --episodes 1 B` would leave B unrecognized."""

    _intermixing = False

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        # parse_known_intermixed_args parses by calling parse_known_args (twice), which must then parse plainly. It
        # also drops a `--` in its first pass, so the words after one (a run folder named -x) would read as flags.
        if self._intermixing or (args is not None and "--" in args):
            return super().parse_known_args(args, namespace)
        self._intermixing = True
        try:
            return self.parse_known_intermixed_args(args, namespace)
        finally:
            self._intermixing = False


def _unrecognized(parser: argparse.ArgumentParser, command: str | None, extra: list[str]) -> CanterError:
    """argparse's 'unrecognized arguments' error, with the command's flags closest to the unknown ones."""
    commands = _subcommands(parser)
    actions = commands[command]._actions if command in commands else parser._actions
    flags = [flag for action in actions for flag in action.option_strings if flag.startswith("--")]
    given = [word.split("=", 1)[0] for word in extra if word.startswith("--")]
    close = [match for word in given for match in difflib.get_close_matches(word, flags, n=1, cutoff=0.7)]
    hint = f"; did you mean {', '.join(close)}?" if close else ""
    return CanterError(
        f"{command + ': ' if command else ''}unrecognized arguments: {' '.join(extra)}{hint} (see --help)"
    )


def _check_command(parser: argparse.ArgumentParser, argv: list[str]) -> None:
    """A mistyped command gets the closest one, as a mistyped flag does; argparse would only list them all."""
    commands = _subcommands(parser)
    # canter's own options (--help, --version) take no value, so the first other word is the command.
    word = next((word for word in argv if not word.startswith("-")), None)
    if word is None or word in commands:
        return
    close = difflib.get_close_matches(word.lower(), list(commands), n=1, cutoff=0.6)
    hint = f"did you mean {close[0]}?" if close else f"commands are {', '.join(commands)}"
    raise CanterError(f"invalid choice of command: {word!r}; {hint} (see --help)")


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices


def _join_dashed_values(parser: argparse.ArgumentParser, argv: list[str]) -> list[str]:
    """`--seeds -1,2` as `--seeds=-1,2`. argparse takes a word that starts with '-' for an option unless it reads
    as one negative number, so a list or an exponent (-1,2 or -2e2) never reached the option's own check and the
    error was `expected one argument`; joined, the value gets that option's message (its range, say)."""
    commands = _subcommands(parser)
    command = next((word for word in argv if not word.startswith("-")), None)
    if command not in commands:
        return argv
    takes_a_value = {
        flag for action in commands[command]._actions if action.nargs is None for flag in action.option_strings
    }
    joined: list[str] = []
    words = iter(argv)
    for word in words:
        if word == "--":  # what follows is positional
            joined += [word, *words]
            break
        value = next(words, None) if word in takes_a_value else None
        if value is not None and re.match(r"-(\.?\d|inf|nan)", value, re.IGNORECASE):
            joined.append(f"{word}={value}")
        else:
            joined += [word] if value is None else [word, value]
    return joined


# The arguments that name run folders, in every command that reads one: its positional run or runs, and --resume.
_RUN_FOLDER_ARGS = {"run": "as the run folder", "runs": "as a run folder", "resume": "to --resume"}


def _refuse_empty_run_folders(args: argparse.Namespace) -> None:
    """An empty run folder path: Path("") is the working folder, which would be read, or refused, in its place."""
    for name, what in _RUN_FOLDER_ARGS.items():
        value = getattr(args, name, None)
        given = [value] if isinstance(value, str) else value or []
        if any(not path.strip() for path in given):
            raise CanterError(f"{args.command}: an empty path was given {what}; give the run folder's path")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="canter", description="Fast, correct continuous-control RL for MuJoCo robots.")
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="command", parser_class=_CommandParser, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"canter.cli.{name}").register(sub)
    return parser


def _version() -> str:
    from canter import __version__

    return f"canter {__version__}"


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    try:
        argv = list(sys.argv[1:] if argv is None else argv)
        _check_command(parser, argv)
        argv = _join_dashed_values(parser, argv)
        args, extra = parser.parse_known_args(argv)
        if extra:
            raise _unrecognized(parser, args.command, extra)
        if args.command is None:
            parser.print_help()
            return 2
        _refuse_empty_run_folders(args)
        from canter.config.overrides import repeated_set_note

        note = repeated_set_note(getattr(args, "set", None) or [])
        if note:
            print(f"canter: note: {note}", file=sys.stderr)
        return args.func(args)
    except CanterError as exc:
        print(error_line(exc), file=sys.stderr)
        return 2
    except PermissionError as exc:  # reading a run folder's file this user may not read; writes are WriteErrors
        print(error_line(f"{exc.filename}: permission denied; give this user access to it"), file=sys.stderr)
        return 2
    except (IsADirectoryError, NotADirectoryError, FileExistsError) as exc:  # a hand-edited or damaged run folder
        wanted = "a file" if isinstance(exc, IsADirectoryError) else "a folder"
        print(
            error_line(f"{exc.filename}: {exc.strerror}, where canter needs {wanted}; move it out of the way"),
            file=sys.stderr,
        )
        return 2
    except OSError as exc:
        if exc.filename is None or exc.errno not in _PATH_ERRORS or _in_package(exc.filename):
            raise  # not a path the user gave: a bug, which keeps its traceback
        print(error_line(f"{_shown(exc.filename)}: {_PATH_ERRORS[exc.errno]}"), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        end_of_interrupts()
        print("canter: interrupted", file=sys.stderr)
        return INTERRUPTED


# Errors of a path the user gave, not of canter: one line each, with the fix.
_PATH_ERRORS = {
    errno.ENAMETOOLONG: "file name too long for this file system (at most 255 bytes a name); choose a shorter path",
    errno.ENOENT: "no such file or folder (or a folder on the way to it is missing); check the path",
    errno.ELOOP: "too many symbolic links; choose a path without a link loop",
}


def _in_package(path: str | bytes) -> bool:
    package = Path(__file__).resolve().parent.parent
    try:
        return Path(os.fsdecode(path)).resolve().is_relative_to(package)
    except (OSError, ValueError, TypeError):
        return False


def _shown(path: object, limit: int = 80) -> str:
    text = os.fsdecode(path) if isinstance(path, (str, bytes)) else str(path)
    text = text.encode("utf-8", "backslashreplace").decode()
    return text if len(text) <= limit else f"{text[: limit // 2]}...{text[-limit // 2 :]} ({len(text)} characters)"


def entry() -> None:
    interrupt_once()
    try:
        code = main()
        # The command's code is the process's: a stop signal in the interpreter's shutdown (JAX's teardown takes a
        # while) would end a finished run as a killed one.
        ignore_stop_signals()
        sys.stdout.flush()  # a closed stdout shows here at the latest, rather than as an error the shutdown prints
    except KeyboardInterrupt:  # a second Ctrl-C after the command stopped on the first one
        ignore_stop_signals()
        print("canter: interrupted", file=sys.stderr)
        code = INTERRUPTED
    except OSError:  # a closed pipe (EPIPE) or a terminal that hung up (EIO); main passes on those with no path
        if not stdout_is_gone():
            raise  # a bug, which keeps its traceback
        code = end_quietly_without_stdout()
    if code == INTERRUPTED:
        exit_interrupted()
    sys.exit(code)


if __name__ == "__main__":
    entry()
