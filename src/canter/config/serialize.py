"""A config as the TOML that a run folder keeps (config.toml and the checkpoint headers), and back.

The TOML holds `env`, `run` and what the run's algorithm reads: whole sections, or the single keys it reads of a
section (as trpo reads four `ppo.*` keys). Keys it does not read take today's defaults when the text is read back.
"""

from __future__ import annotations

import tomllib
from dataclasses import fields
from typing import Any

from canter.config.algorithms import read_sections
from canter.config.overrides import apply_overrides, flatten_toml
from canter.config.schema import Config
from canter.config.validate import validate
from canter.config.values import toml_value
from canter.errors import CanterError


def written_keys(config: Config) -> list[tuple[str, list[str]]]:
    """(section, keys) that a run of this config reads, in config.toml order: env, the algorithm's, run."""

    def names(section: str) -> list[str]:
        return [f.name for f in fields(config.section(section))]

    algorithm = [
        (section, list(only) if only is not None else names(section))
        for section, only in read_sections(config.run.algo)
    ]
    return [("env", names("env")), *algorithm, ("run", names("run"))]


def to_toml(config: Config) -> str:
    """What the run reads of the config; `none` values are written as comments, since TOML has no null."""
    lines: list[str] = []
    for section, keys in written_keys(config):
        lines.append(f"[{section}]")
        table = config.section(section)
        for name in keys:
            value = getattr(table, name)
            lines.append(f"# {name} = none" if value is None else f"{name} = {toml_value(value)}")
        lines.append("")
    return "\n".join(lines)


def from_toml_text(text: str, source: str) -> Config:
    try:
        data: dict[str, Any] = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CanterError(f"malformed TOML in {source}: {exc}") from None
    config = apply_overrides(Config(), flatten_toml(data, source), source)
    validate(config)
    return config
