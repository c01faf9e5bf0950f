"""Import MJX without its import-time noise."""

from __future__ import annotations

import contextlib
import io
from typing import Any


def import_mjx() -> Any:
    """`mujoco.mjx`, imported once. Without the optional `warp` package, importing it prints "Failed to import warp"
    to stdout, which would corrupt output such as `canter eval --json -`; MJX's JAX implementation, the one canter
    uses, does not need warp."""
    with contextlib.redirect_stdout(io.StringIO()):
        from mujoco import mjx
    return mjx
