"""User-facing errors.

A `CanterError` carries a one-line message that names the problem and the fix. The CLI prints it without a
traceback and exits non-zero; everything else is a bug and keeps its traceback.
"""

import re
import unicodedata


class CanterError(Exception):
    """A problem with the user's input or environment, reported as one line."""


class DiscreteActionsError(CanterError):
    """The env's actions are not a Box. The trainer re-raises it naming the algorithm, which is continuous-only."""

    def __init__(self, env_id: str, space: object) -> None:
        super().__init__(f"{env_id}: action space {space} is not continuous; canter trains Box actions")
        self.env_id, self.space = env_id, space


class DoesNotFitError(CanterError):
    """A run too large for the memory it goes to. Its fix is `change`, settings to lower, or where one seed's part
    fits, `seeds_at_once` seeds at a time. A resume keeps the run's settings, so it is told the fix that it can take
    (`for_a_resume`)."""

    def __init__(self, problem: str, change: str | None = None, seeds_at_once: int | None = None) -> None:
        fix = _fewer_seeds("train", seeds_at_once) if seeds_at_once else change
        super().__init__(f"{problem}; {fix}" if fix else problem)
        self.problem, self.change, self.seeds_at_once = problem, change, seeds_at_once

    def for_a_resume(self, config_file: object) -> CanterError:
        """The same refusal of a resumed run, whose settings `--resume` refuses to change (`config_file`: its
        config.toml, from which a new run can change them)."""
        if self.seeds_at_once:
            return CanterError(f"{self.problem}; {_fewer_seeds('resume', self.seeds_at_once)}")
        elsewhere = "a resume keeps the run's settings: resume it where more memory is free"
        if self.change is None:
            return CanterError(f"{self.problem}; {elsewhere}")
        return CanterError(
            f"{self.problem}; {elsewhere}, or {self.change} in a new run from its config: {new_run(config_file)}"
        )


def _fewer_seeds(verb: str, fits: int) -> str:
    return f"{verb} one seed at a time" if fits == 1 else f"{verb} at most {fits} seeds at a time"


def with_python(cli: str, python: str) -> str:
    """A fix as the command line takes it, then as the Python API does: a refusal that reaches both gives each
    caller a fix it can apply, the command line's first."""
    return f"{cli} ({python} from Python)"


def resume_run(run_dir: object) -> str:
    """The command that resumes a run folder, and its Python form: `resume_seeds` reads the run's own config as the
    command does, where `train(config, resume=)` needs one built (from a config.toml the fix may be about)."""
    return with_python(f"canter train --resume {run_dir}", f"canter.resume_seeds([{str(run_dir)!r}])")


def new_run(config_file: object) -> str:
    """The command that starts a new run from a config file (a run folder's config.toml), and its Python form."""
    return with_python(
        f"canter train --config {config_file}",
        f"canter.train(canter.build_config(None, config_file={str(config_file)!r}))",
    )


def joined(words: list[str]) -> str:
    """'a', 'a and b', 'a, b and c': a list as a one-line message names it."""
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} and {words[-1]}"


def error_line(exc: BaseException | str) -> str:
    """`canter: error: MESSAGE` on one line: a line break inside a value the user gave (an env id, a path) is
    written escaped, as repr writes it, so the error stays one line that scripts and logs read as one. Only control
    characters and the two Unicode line separators are escaped: any other character (a CJK space, a joiner) is part
    of a name that a fix quotes to be pasted back."""
    text = "".join(repr(c)[1:-1] if unicodedata.category(c) == "Cc" or c in "\u2028\u2029" else c for c in str(exc))
    return f"canter: error: {text}"


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message, or its type's name where the message is empty: a library's error
    can run to a page (a traceback from a server, a SQL statement), and a one-line message quotes only its start."""
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


def first_sentence(exc: BaseException) -> str:
    """The first sentence of an exception's first line: some libraries put a paragraph of advice on that line,
    which a one-line message that gives its own fix need not quote."""
    line = first_line(exc)
    end = re.search(r"[.!?] (?=[A-Z`'\"])", line)
    return line[: end.start() + 1] if end else line
