"""`{"section.key": value}` overrides: reading them from `--set` and TOML, and applying them to a config with their
names and types checked."""

from __future__ import annotations

import dataclasses
import difflib
import tomllib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from canter.config.peer_names import peer_keys, written_section
from canter.config.schema import Config, field_names, field_types, section_names
from canter.config.values import coerce
from canter.errors import CanterError, joined
from canter.parsing import toml_table


def all_keys() -> list[str]:
    return [f"{s}.{name}" for s in section_names() for name in field_names(s)]


def close_keys(key: str) -> list[str]:
    """The config keys that `key` may be a misspelling of, closest first."""
    return difflib.get_close_matches(key, all_keys(), n=3, cutoff=0.5)


def key_suggestion(key: str) -> str | None:
    """'did you mean ...?' for an unknown config key: canter's name for another library's, else the closest keys;
    None if nothing is close. The one hint of --set, --config, --grid and --space alike."""
    peer = peer_keys(key, all_keys())
    if peer is not None:
        names, keys = peer
        libraries = joined([f"{library}'s" for library in names.libraries])
        return f"did you mean {joined(keys)}? ({libraries} {names.name}{names.note_under(written_section(key)[0])})"
    close = close_keys(key)
    return f"did you mean {', '.join(close)}?" if close else None


def unknown_key_error(key: str, source: str) -> CanterError:
    suggestion = key_suggestion(key)
    hint = f"; {suggestion}" if suggestion else f"; sections are {', '.join(section_names())}"
    return CanterError(f"unknown config key '{key}' in {source}{hint}")


# What --set values are called in a message: build_config takes them from the command line and from Python alike.
SET_SOURCE = "--set (sets= from Python)"
# Sources of overrides that the command line gives; any other is a file or a preset, which a bad value names.
FROM_FLAGS = (SET_SOURCE, "arguments")


def apply_overrides(config: Config, overrides: dict[str, Any], source: str) -> Config:
    """Apply `{"section.key": value}` overrides, checking names and types."""
    sections: dict[str, dict[str, Any]] = {}
    known = section_names()
    for key, value in overrides.items():
        section, _, name = key.partition(".")
        if section not in known or name not in field_names(section):
            raise unknown_key_error(key, source)
        try:
            sections.setdefault(section, {})[name] = coerce(key, field_types(section)[name], value)
        except CanterError as exc:
            if source in FROM_FLAGS:  # the user has the flag in front of them
                raise
            raise CanterError(f"{exc} (in {source})") from None
    return config.replace(**{s: dataclasses.replace(config.section(s), **values) for s, values in sections.items()})


def parse_set_args(items: Iterable[object], flag: str = SET_SOURCE) -> dict[str, str]:
    """`section.key=value` strings as a dict; `flag` is what the errors call them (eval's `--set` has no sets=)."""
    # A lone string would be read a character at a time, so `sets="ppo.clip=0.1"` would be refused for its "p".
    if isinstance(items, (str, bytes)):
        raise CanterError(
            f'sets= takes a list of "section.key=value" strings, got the string {items!r}; pass [{items!r}]'
        )
    if not isinstance(items, Iterable):
        raise CanterError(f'sets= takes a list of "section.key=value" strings, got {type(items).__name__}')
    # A dict would be read by its keys alone, without their values.
    if isinstance(items, Mapping):
        example = f"{next(iter(items))}=..." if items else "ppo.clip=0.1"
        raise CanterError(
            f'sets= takes a list of "section.key=value" strings, got a {type(items).__name__}; pass a string per '
            f"key, such as [{example!r}]"
        )
    overrides: dict[str, str] = {}
    for item in items:
        if not isinstance(item, str):
            raise CanterError(f"{flag} expects section.key=value text, got {item!r} ({type(item).__name__})")
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise CanterError(f"{flag} expects section.key=value, got {item!r}")
        overrides[key.strip()] = value.strip()  # the last wins: a script lays its own --set over a shared list
    return overrides


def repeated_set_note(items: list[str]) -> str | None:
    """A note naming the keys that `items` (`--set` values) give more than once with different values, of which the
    last wins: meant where a script lays one over another, a slip where a key was copied; None if there are none."""
    values: dict[str, list[str]] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if sep and key.strip():
            values.setdefault(key.strip(), []).append(value.strip())
    repeated = [(key, given) for key, given in values.items() if len(set(given)) > 1]
    if not repeated:
        return None
    named = "; ".join(f"{key} ({', then '.join(map(repr, given))})" for key, given in repeated)
    return f"--set gives {named}: the last of each is used"


def flatten_toml(data: dict[str, Any], source: str) -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for section, values in data.items():
        if not isinstance(values, dict):
            raise unknown_key_error(section, source)
        for name, value in values.items():
            if isinstance(value, dict):
                raise unknown_key_error(f"{section}.{name}", source)
            flat[f"{section}.{name}"] = value
    return flat


def load_toml(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    if path.is_dir():
        raise CanterError(
            f"{path} is a folder; --config (config_file= from Python) takes a TOML file, such as a run folder's "
            f"config.toml"
        )
    if path.exists() and not path.is_file():  # a device or a pipe: /dev/zero would be read without end
        raise CanterError(
            f"{path} is not a regular file; --config (config_file= from Python) takes a TOML file, such as a run "
            f"folder's config.toml"
        )
    if not path.is_file():
        raise CanterError(f"config file not found: {path}")
    try:
        return toml_table(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise CanterError(f"malformed TOML in {path}: {exc}") from None
    except UnicodeDecodeError:
        raise CanterError(f"config file {path} is not UTF-8 text") from None
    except PermissionError:
        raise  # the command line names the fix for every unreadable path alike
    except OSError as exc:  # a file that lists as regular but does not read, such as /proc/self/mem
        raise CanterError(f"cannot read {path}: {exc.strerror or exc}; give a TOML file that can be read") from None
