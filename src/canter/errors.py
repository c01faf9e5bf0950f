"""User-facing errors.

A `CanterError` carries a one-line message that names the problem and the fix. The CLI prints it without a
traceback and exits non-zero; everything else is a bug and keeps its traceback.
"""


class CanterError(Exception):
    """A problem with the user's input or environment, reported as one line."""
