"""User-facing errors.

A `CanterError` carries a one-line message that names the problem and the fix. The CLI prints it without a
traceback and exits non-zero; everything else is a bug and keeps its traceback.
"""


class CanterError(Exception):
    """A problem with the user's input or environment, reported as one line."""


class DiscreteActionsError(CanterError):
    """The env's actions are not a Box. The trainer re-raises it naming the algorithm, which is continuous-only."""

    def __init__(self, env_id: str, space: object) -> None:
        super().__init__(f"{env_id}: action space {space} is not continuous; canter trains Box actions")
        self.env_id, self.space = env_id, space


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message, or its type's name where the message is empty: a library's error
    can run to a page (a traceback from a server, a SQL statement), and a one-line message quotes only its start."""
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__
