"""The two fixed points of a normalized score, both shipped as package data:

- random: the return of uniformly random actions on the env id, measured by canter (`canter/data/random.toml`,
  written by `canter.use.random_score` with its command recorded in the file);
- reference: the published 1M-step figure of the same algorithm on the same env (`canter/data/published.toml`):
  Tianshou's where it has one, else CleanRL's.

normalized score = (return - random) / (reference - random): 0 is random play, 1 the published figure.
"""

from __future__ import annotations

import functools
import tomllib
from dataclasses import dataclass
from importlib import resources
from typing import Any

REFERENCE_STEPS = 1_000_000
# Sources of the reference, in order of preference (keys of published.toml's [sources]).
REFERENCE_SOURCES = ("TS", "CR")


@dataclass(frozen=True)
class Normalizer:
    env_id: str
    algo: str
    random: float
    reference: float
    source: str  # the reference's source, by name ("Tianshou")
    reference_env: str  # the env id the source measured, whose version may differ from env_id's ("Hopper-v3")

    def describe(self) -> str:
        return (
            f"{self.env_id} {self.algo}: random {self.random:,.1f}, reference {self.reference:,.1f} "
            f"({self.source} {self.algo} on {self.reference_env}, 1M steps)"
        )

    def as_dict(self) -> dict[str, Any]:
        return {
            "env": self.env_id,
            "algo": self.algo,
            "random": self.random,
            "reference": self.reference,
            "reference_source": self.source,
            "reference_env": self.reference_env,
        }


def _data(name: str) -> dict[str, Any]:
    return tomllib.loads(resources.files("canter.data").joinpath(name).read_text())


@functools.cache
def published_scores() -> dict[str, Any]:
    """The shipped table of published scores (canter/data/published.toml)."""
    return _data("published.toml")


@functools.cache
def random_scores() -> dict[str, Any]:
    """The shipped random-policy returns (canter/data/random.toml): `command`, and `env` by env id."""
    return _data("random.toml")


def env_base(env_id: str) -> str:
    """The env's name without module prefix and version, as published.toml names envs: Hopper-v5 -> Hopper."""
    return env_id.split(":")[-1].rsplit("-v", 1)[0]


def measured_env(source: dict[str, Any], env: str) -> str:
    """The env id a published source measured for the env named without its version: Hopper -> Hopper-v3."""
    return f"{env}-{source.get('older', {}).get(env, source['version'])}"


def reference_score(algo: str, env_id: str) -> tuple[float, str, str] | None:
    """(the published 1M-step mean of `algo` on the env, its source's name, the env id it measured), or None when
    none is published."""
    data = published_scores()
    base = env_base(env_id)
    rows = [s for s in data["score"] if s["algo"] == algo and s["env"] == base and s["steps"] == REFERENCE_STEPS]
    for key in REFERENCE_SOURCES:
        for row in rows:
            if row["source"] == key:
                source = data["sources"][key]
                return float(row["mean"]), source["name"], measured_env(source, base)
    return None


def random_score(env_id: str) -> float | None:
    entry = random_scores()["env"].get(env_id)
    return float(entry["mean"]) if entry else None


def normalizer_for(algo: str, env_id: str) -> Normalizer | None:
    """None when the env id has no measured random score or the algorithm no published figure on the env."""
    random = random_score(env_id)
    reference = reference_score(algo, env_id)
    if random is None or reference is None or reference[0] <= random:
        return None
    return Normalizer(env_id, algo, random, *reference)


def random_command() -> str:
    """The command that measured the shipped random scores."""
    return str(random_scores()["command"])
