"""JSON and TOML parsing that treats text nested past Python's recursion limit as malformed.

The standard parsers recurse once per nesting level and raise RecursionError at about a thousand levels. Every reader
of a user's or a run's file already handles malformed text (a ValueError), so such text joins that path: a crafted
or damaged file then gets the reader's one-line error, not a traceback.
"""

import json
import tomllib
from typing import Any

TOO_DEEP = "nested too deeply to read"


def json_value(text: str | bytes) -> Any:
    """`json.loads(text)`; a json.JSONDecodeError (a ValueError) where the text nests too deeply."""
    try:
        return json.loads(text)
    except RecursionError:
        raise json.JSONDecodeError(TOO_DEEP, text if isinstance(text, str) else "", 0) from None


def toml_table(text: str) -> dict[str, Any]:
    """`tomllib.loads(text)`; a tomllib.TOMLDecodeError (a ValueError) where the text nests too deeply."""
    try:
        return tomllib.loads(text)
    except RecursionError:
        raise tomllib.TOMLDecodeError(TOO_DEEP) from None
