"""A config as the TOML that a run folder keeps (config.toml and the checkpoint headers), and back.

The TOML holds `env`, `run` and what the run's algorithm reads: whole sections, or the single keys it reads of a
section (as trpo reads four `ppo.*` keys). Keys it does not read take today's defaults when the text is read back.
A none is written as the string "none" (`written_value`). Older files hold it as a comment, `# key = none`: read as a
run's config, that key takes its default, which is none for every optional key, so they read back the same.
"""

from __future__ import annotations

import tomllib
from collections.abc import Iterable
from dataclasses import fields
from typing import Any

from canter.config.algorithms import read_sections
from canter.config.overrides import apply_overrides, flatten_toml
from canter.config.schema import Config
from canter.config.validate import validate
from canter.config.values import toml_value
from canter.errors import CanterError
from canter.parsing import toml_table


def written_keys(config: Config) -> list[tuple[str, list[str]]]:
    """(section, keys) that a run of this config reads, in config.toml order: env, the algorithm's, run."""

    def names(section: str) -> list[str]:
        return [f.name for f in fields(config.section(section))]

    algorithm = [
        (section, list(only) if only is not None else names(section))
        for section, only in read_sections(config.run.algo)
    ]
    return [("env", names("env")), *algorithm, ("run", names("run"))]


def written_value(value: Any) -> str:
    """A config value as TOML. TOML has no null, so none is the string "none", which every reader of a config takes
    as none (`coerce`); a key left out instead would take the value beneath it, a preset's under `--config`."""
    return '"none"' if value is None else toml_value(value)


def toml_tables(tables: Iterable[tuple[str, Iterable[tuple[str, Any]]]]) -> str:
    """`[section]` tables of `name = value` lines, each followed by an empty line."""
    lines: list[str] = []
    for section, items in tables:
        lines += [f"[{section}]", *(f"{name} = {written_value(value)}" for name, value in items), ""]
    return "\n".join(lines)


def to_toml(config: Config) -> str:
    """What the run reads of the config."""
    return toml_tables(
        (section, [(name, getattr(config.section(section), name)) for name in keys])
        for section, keys in written_keys(config)
    )


def from_toml_text(text: str, source: str) -> Config:
    try:
        data: dict[str, Any] = toml_table(text)
    except tomllib.TOMLDecodeError as exc:
        raise CanterError(f"malformed TOML in {source}: {exc}") from None
    config = apply_overrides(Config(), flatten_toml(data, source), source)
    validate(config)
    return config
