"""Typed values: a TOML value or a `--set` string becomes the field's type, or a one-line error."""

from __future__ import annotations

import dataclasses
import difflib
import math
import numbers
import os
import re
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import fields
from decimal import Decimal
from typing import Any

from canter.errors import CanterError

SEED_LIMIT = 2**32  # run seeds are unsigned 32-bit, as numpy's and JAX's keys take them


def is_optional(tp: Any) -> tuple[bool, Any]:
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(tp)) == 2:
            return True, args[0]
    return False, tp


def is_tuple_field(tp: Any) -> bool:
    """Whether a field of type `tp` (optional or not) holds a tuple of integers."""
    return typing.get_origin(is_optional(tp)[1]) is tuple


def type_name(tp: Any) -> str:
    optional, inner = is_optional(tp)
    if typing.get_origin(inner) is tuple:
        base = "comma-separated integers"
    else:
        base = {int: "an integer", float: "a number", bool: "true or false", str: "a string"}.get(inner, str(inner))
    return f"{base} or none" if optional else base


def coerce(key: str, tp: Any, value: Any) -> Any:
    """Convert a TOML value or a `--set` string to the field's type, or raise a one-line CanterError."""
    optional, inner = is_optional(tp)
    bad = CanterError(f"{key}: expected {type_name(tp)}, got {value!r}")
    if optional and (value is None or (isinstance(value, str) and value.strip().lower() in ("none", "null", ""))):
        return None
    if typing.get_origin(inner) is tuple:
        if isinstance(value, str):
            # "64,64" or "64-64" (the form a plot label and a tune choice take); a minus sign is not a separator
            if not re.fullmatch(r"\s*(\d+(\s*[-,]\s*\d+)*)?\s*", value):
                if re.fullmatch(r"\s*-?\s*\d+(\s*,\s*-?\s*\d+)*\s*", value):  # well formed, but with a negative
                    raise CanterError(f"{key}: {_tuple_entries(key)}, got {value!r}")
                # --grid and tune's choices separate their values by commas, so there the sizes take dashes
                raise CanterError(f"{key}: expected {type_name(tp)} (or joined by dashes, 64-64), got {value!r}")
            return tuple(int(p) for p in re.split(r"[-,]", value) if p.strip())
        if isinstance(value, (list, tuple)) and all(_is_integer(v) for v in value):
            return tuple(int(v) for v in value)
        raise bad
    if inner is bool:
        if isinstance(value, bool):
            return value
        if _is_numpy_bool(value):  # what a comparison of numpy values gives
            return bool(value)
        if isinstance(value, str) and value.strip().lower() in ("true", "1", "yes", "on", "false", "0", "no", "off"):
            return value.strip().lower() in ("true", "1", "yes", "on")
        raise bad
    if inner is int:
        return _within_int_limit(key, _whole_number(value, bad))
    if inner is float:
        if isinstance(value, bool):
            raise bad
        if isinstance(value, numbers.Real):  # numpy's floats and integers too, which are plain numbers here
            try:
                number = float(value)
            except OverflowError:  # an int past float's range
                raise bad from None
        elif isinstance(value, str):
            try:
                number = float(value)
            except ValueError:
                raise bad from None
        else:
            raise bad
        if not math.isfinite(number):  # no setting means anything by nan or inf; they fail deep in training
            unset = " or none" if optional else ""  # none is how an optional key goes unset (a limit: no limit)
            raise CanterError(f"{key} must be a finite number{unset}, got {value}")
        return number
    if inner is str:
        if isinstance(value, str):
            return value
        if isinstance(value, os.PathLike) and isinstance(path := os.fspath(value), str):  # run.out_dir as a Path
            return path
        raise bad
    raise bad


def _is_numpy_bool(value: Any) -> bool:
    """numpy's bool scalar, known by its type's name (the config layer does not import numpy)."""
    kind = type(value)
    return kind.__module__ == "numpy" and kind.__name__ in ("bool", "bool_")


def _is_integer(value: Any) -> bool:
    """An int, or another integer type such as numpy's (registered as numbers.Integral); a bool is not one here."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _tuple_entries(key: str) -> str:
    """What a tuple key's entries must be: its layer sizes (every *hidden key) are positive, its indices
    (sym.negate) are not negative."""
    if key.endswith("hidden"):
        return "layer sizes must be positive integers, such as 64,64"
    return "expected integers of 0 or more, separated by commas"


def _whole_number(value: Any, bad: CanterError) -> int:
    if isinstance(value, bool):
        raise bad
    if _is_integer(value):
        return int(value)
    if isinstance(value, float) and value.is_integer():
        return int(value)
    if isinstance(value, str):
        try:
            number = float(value)
        except ValueError:
            raise bad from None
        if number.is_integer():
            return int(number)
    raise bad


# Counts live in int32 arrays on a JAX-native backend: every whole-number setting stays below 2^31, except the step
# budgets and intervals, counted on the host (int64 there), and run.seed (its own limit, SEED_LIMIT).
INT_LIMIT = 2**31
STEP_LIMIT = 2**53  # a float64 counts every step below it exactly
STEP_KEYS = frozenset({"run.total_steps", "run.checkpoint_every", "run.eval_every", "run.video_every", "run.seed"})


SHORT_FORM_DIGITS = 20  # past this an integer in a message is written as 1e+300, not 301 digits


def short_int(number: int) -> str:
    """`number` with thousands separators, or in e-notation (three significant digits) when it is too long to read."""
    if abs(number) < 10**SHORT_FORM_DIGITS:
        return f"{number:,}"
    mantissa, _, exponent = f"{Decimal(number):.2e}".partition("e")  # Decimal: a float overflows past 1e308
    return f"{mantissa.rstrip('0').rstrip('.')}e{exponent}"


def _within_int_limit(key: str, number: int) -> int:
    limit = STEP_LIMIT if key in STEP_KEYS else INT_LIMIT
    if abs(number) >= limit:
        raise CanterError(f"{key} must be below {limit:,} in size, got {short_int(number)}")
    return number


def _plain_check(tp: Any) -> Callable[[Any], bool]:
    """Whether a value already has the type `coerce` gives a field of type `tp`, so that a section built the usual
    way (every value coerced) is checked without coercing it again."""
    optional, inner = is_optional(tp)
    if typing.get_origin(inner) is tuple:
        return lambda value: type(value) is tuple and all(type(v) is int for v in value)
    if optional:
        return lambda value: value is None or type(value) is inner
    return lambda value: type(value) is inner


SectionFields = tuple[tuple[str, Any, Callable[[Any], bool]], ...]
_FIELDS: dict[type, SectionFields] = {}  # by section class: get_type_hints is too slow for every config built


def _section_fields(section: Any) -> SectionFields:
    """Each field of `section`: its name, its type, and whether a value already has that type."""
    cls = type(section)
    if cls not in _FIELDS:
        hints = typing.get_type_hints(cls)
        _FIELDS[cls] = tuple((f.name, hints[f.name], _plain_check(hints[f.name])) for f in fields(cls))
    return _FIELDS[cls]


def typed_section(name: str, section: Any) -> Any:
    """`section` (section `name` of a config) with each value as `coerce` gives it, or a one-line CanterError naming
    the key: however a section was built, the config trains on and saves the values that its config.toml reads back
    as. The same object when every value already has its type, as every value the TOML and --set paths give does."""
    changes = {
        key: coerce(f"{name}.{key}", tp, getattr(section, key))
        for key, tp, plain in _section_fields(section)
        if not plain(getattr(section, key))
    }
    return dataclasses.replace(section, **changes) if changes else section


def typed_values(name: str, section: Any, values: Mapping[str, Any]) -> dict[str, Any]:
    """`values` for keys of `section` (section `name`), each coerced to its field's type: the keys and values that
    `Config.with_values` is given, checked as a --set of them would be."""
    types_of = {key: tp for key, tp, _ in _section_fields(section)}
    typed: dict[str, Any] = {}
    for key, value in values.items():
        if key not in types_of:
            close = difflib.get_close_matches(key, list(types_of), n=1)
            hint = f"; did you mean {name}.{close[0]}?" if close else f"; its keys are {', '.join(types_of)}"
            raise CanterError(f"config section '{name}' has no key '{key}'{hint}")
        typed[key] = coerce(f"{name}.{key}", types_of[key], value)
    return typed


def _escape_toml_char(match: re.Match[str]) -> str:
    """A basic string's escape: backslash and quote as themselves, control characters (a folder name may hold one)
    as \\uXXXX, which TOML refuses unescaped."""
    char = match.group()
    return "\\" + char if char in '\\"' else f"\\u{ord(char):04x}"


def toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return (
            repr(value)
            if math.isfinite(value)
            else ("inf" if value > 0 else "-inf")
            if not math.isnan(value)
            else "nan"
        )
    if isinstance(value, tuple):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, str):
        escaped = re.sub(r'[\\"\x00-\x1f\x7f]', _escape_toml_char, value)
        return f'"{escaped}"'
    raise TypeError(value)


def unlimited_as_none(value: float) -> float | None:
    """A limit given as a number (--max-minutes, --stop-at-return) as its config key holds it: +inf is no limit,
    which the config holds as none (TOML has no way to write it but to leave the key out)."""
    return None if value == math.inf else value


def set_text(value: Any) -> str:
    """A config value as `--set` text, the form `coerce` reads back and the README's key table shows: a tuple's
    entries joined by commas, None as none, a bool as true or false."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple):
        return ",".join(map(str, value))
    return str(value)
