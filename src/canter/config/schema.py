"""The configuration tree: the `env` and `run` sections every run has, and the sections algorithms register.

Every key is addressable as `section.key`. `env` and `run` are defined here; each algorithm declares its own
sections in its folder (`canter/algos/<name>/sections.py`) and registers them with `register_section`, so this
package never imports an algorithm.
"""

from __future__ import annotations

import dataclasses
import difflib
import typing
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any

from canter.config.fields import BUDGET, OUTPUT, SEED, setting
from canter.config.values import typed_section, typed_values
from canter.envs.registry import AUTO, MODEL_OWN_PHYSICS, backend_doc
from canter.errors import CanterError


@dataclass(frozen=True)
class EnvConfig:
    id: str = setting("Environment id, e.g. Hopper-v5, or `module:EnvId` for a custom Gymnasium env.", default="")
    backend: str = setting(backend_doc(), default=AUTO)
    num_envs: int = setting("Parallel environments stepped per rollout step.", default=1)
    envpool_shards: int = setting(
        "EnvPool only: split the envs over this many single-threaded pools that step "
        "concurrently, as evenly as the count allows; 0 means one per CPU core the process may use.",
        default=0,
        role=OUTPUT,
    )
    solver_iterations: int = setting(
        "The MJX ports of the Gymnasium tasks only (not Brax's envs): constraint-solver iterations per physics step "
        "instead of the XML's own (0: the XML's, 100 or 50). Fewer are much faster on a GPU and change the physics "
        "slightly.",
        default=MODEL_OWN_PHYSICS["solver_iterations"],
    )
    solver_ls_iterations: int = setting(
        "The MJX ports of the Gymnasium tasks only (not Brax's envs): line-search iterations per solver iteration "
        "instead of the XML's own (0: the XML's, 50). MJX runs all of them for every env, so they dominate a step's "
        "cost on a GPU.",
        default=MODEL_OWN_PHYSICS["solver_ls_iterations"],
    )
    contacts: str = setting(
        "The MJX ports of the Gymnasium tasks only (not Brax's envs): `all` keeps the XML's collisions; `floor` lets "
        "body parts collide with the floor and not with each other, as Brax and MuJoCo Playground limit their models' "
        "contacts: far fewer to solve (Humanoid: 29 instead of 138; 1.8x the physics steps/s on a 2-core CPU), "
        "slightly different physics.",
        default=MODEL_OWN_PHYSICS["contacts"],
    )
    normalize_obs: bool = setting("Running observation normalization (stats saved with the policy).", default=True)
    clip_obs: float = setting("Clip normalized observations to +-clip_obs.", default=10.0)
    normalize_reward: bool = setting("Divide rewards by the running std of the discounted return.", default=True)
    clip_reward: float = setting("Clip scaled rewards to +-clip_reward.", default=10.0)
    reward_scale: float = setting(
        "Multiply the rewards the learner sees by this fixed factor, as Brax's reward_scaling does (returns are "
        "logged unscaled); an alternative to env.normalize_reward, so it needs that off.",
        default=1.0,
    )


@dataclass(frozen=True)
class RunConfig:
    algo: str = setting("Algorithm.", default="ppo")
    preset: str = setting(
        "Name of the preset this config was built from (recorded, not applied).", default="none", role=OUTPUT
    )
    seed: int = setting("Run seed: network init, sampling and the derived per-env seeds.", default=0, role=SEED)
    total_steps: int = setting(
        "Environment steps to train for (reset steps of EnvPool are not counted), spent in whole iterations: the "
        "run stops after the iteration that reaches it.",
        default=1_000_000,
        role=BUDGET,
    )
    out_dir: str = setting("Folder that receives run folders.", default="runs", role=OUTPUT)
    checkpoint_every: int = setting(
        "Write a checkpoint every this many env steps (0: only at the end).", default=200_000, role=OUTPUT
    )
    keep_checkpoints: int = setting("Keep the newest K checkpoints.", default=3, role=OUTPUT)
    compress_checkpoints: bool = setting(
        "Deflate checkpoint arrays (smaller, slower; a replay buffer of observations shrinks little).",
        default=False,
        role=OUTPUT,
    )
    stop_at_return: float | None = setting(
        "Stop once the mean return of the last 20 training episodes reaches this.", default=None, role=BUDGET
    )
    max_minutes: float | None = setting(
        "Stop cleanly, with a checkpoint, after this many wall minutes.", default=None, role=BUDGET
    )
    tensorboard: bool = setting("Write TensorBoard event files.", default=True, role=OUTPUT)
    video_every: int = setting(
        "Render one episode to videos/step_<step>.mp4 in the run folder every this many env "
        "steps, in a separate process (0: never).",
        default=0,
        role=OUTPUT,
    )
    eval_every: int = setting(
        "Evaluate as `canter eval` does every this many env steps and at the end (metrics.csv's eval/* columns; "
        "the best state is kept as checkpoints/best.npz; 0: never).",
        default=0,
        role=OUTPUT,
    )
    eval_episodes: int = setting("Episodes of each evaluation during training.", default=10, role=OUTPUT)
    eval_backend: str = setting(
        "Backend that plays the evaluations during training: empty for the run's own, else `auto` or a backend "
        "name. `auto` plays them on C MuJoCo from the host, as env.backend's `auto` would: for a run on a "
        "JAX-native MuJoCo backend, the XML's own model without env.solver_* or env.contacts, as `canter eval "
        "--backend` does, and on a GPU far quicker than an episode's 1000 simulated steps one after another.",
        default="",
        role=OUTPUT,
    )


# A section's own checks: `check(section, name)` raises CanterError for a value that makes no sense on its own.
SectionCheck = Callable[[Any, str], None]


@dataclass(frozen=True)
class _Registered:
    type: type
    check: SectionCheck


_REGISTERED: dict[str, _Registered] = {}
CORE_SECTIONS = ("env", "run")


def register_section(name: str, section_type: type, check: SectionCheck) -> None:
    """Add an algorithm's section to every config. Registering the same type again is a no-op."""
    known = _REGISTERED.get(name)
    if name in CORE_SECTIONS or (known is not None and known.type is not section_type):
        raise ValueError(f"config section '{name}' is already defined")
    _REGISTERED[name] = _Registered(section_type, check)


def section_names() -> tuple[str, ...]:
    """Every section, in the order of the docs and of config.toml: env, the algorithms' sections, run."""
    return ("env", *_REGISTERED, "run")


def section_type(name: str) -> type:
    if name == "env":
        return EnvConfig
    if name == "run":
        return RunConfig
    return _REGISTERED[name].type


def check_section(name: str, value: Any) -> None:
    if name in _REGISTERED:
        _REGISTERED[name].check(value, name)


def _default_sections() -> tuple[tuple[str, Any], ...]:
    return tuple((name, entry.type()) for name, entry in _REGISTERED.items())


@dataclass(frozen=True)
class Config:
    """A resolved configuration: `config.env`, `config.run` and every registered section as `config.<name>`."""

    env: EnvConfig = field(default_factory=EnvConfig)
    run: RunConfig = field(default_factory=RunConfig)
    sections: tuple[tuple[str, Any], ...] = field(default_factory=_default_sections)

    def __post_init__(self) -> None:
        # Every way of building a config (the constructor, replace, with_values, dataclasses.replace) ends here, so
        # that a wrong kind of section or a wrongly typed value is refused by name before it trains, not deep in JAX.
        # A value of a harmless other type (numpy's int, a Path, "no" for false) is converted as TOML's would be,
        # so that the config trains on what its config.toml reads back as.
        object.__setattr__(self, "env", _typed("env", self.env))
        object.__setattr__(self, "run", _typed("run", self.run))
        typed = tuple((name, _typed(name, value)) for name, value in self.sections)
        if any(new is not old for (_, new), (_, old) in zip(typed, self.sections)):
            object.__setattr__(self, "sections", typed)

    def __getattr__(self, name: str) -> Any:
        # Only called when normal lookup fails, i.e. for the registered sections.
        if not name.startswith("__"):
            for key, value in self.__dict__.get("sections", ()):
                if key == name:
                    return value
        raise AttributeError(f"config has no section '{name}'")

    def section(self, name: str) -> Any:
        return getattr(self, name)

    def replace(self, **changes: Any) -> Config:
        """A copy with whole sections replaced: `config.replace(run=..., ppo=...)`."""
        names = {name for name, _ in self.sections}
        for name in changes:
            if name not in names and name not in CORE_SECTIONS:
                raise _unknown_section(name)
        sections = tuple((name, changes.get(name, value)) for name, value in self.sections)
        core = {k: v for k, v in changes.items() if k in CORE_SECTIONS}
        return dataclasses.replace(self, sections=sections, **core)

    def with_values(self, section: str, **values: Any) -> Config:
        """A copy with some keys of one section changed: `config.with_values("run", seed=3)`. Each value is checked
        and converted as a `--set` of it would be."""
        if section not in section_names():
            raise _unknown_section(section)
        current = self.section(section)
        return self.replace(**{section: dataclasses.replace(current, **typed_values(section, current, values))})


def _unknown_section(name: str) -> CanterError:
    close = difflib.get_close_matches(name, list(section_names()), n=1)
    return CanterError(f"config has no section '{name}'" + (f"; did you mean {close[0]}?" if close else ""))


def _typed(name: str, section: Any) -> Any:
    """Section `name` with each value of its field's type; a one-line CanterError for another kind of section."""
    if name not in CORE_SECTIONS and name not in _REGISTERED:
        raise _unknown_section(name)
    expected = section_type(name)
    if not isinstance(section, expected):
        hint = f"; to change some of its keys, use config.with_values({name!r}, key=value)"
        raise CanterError(
            f"config section '{name}' must be of type {expected.__name__}, got {type(section).__name__} {section!r:.60}"
            + (hint if isinstance(section, dict) else "")
        )
    return typed_section(name, section)


def field_types(section: str) -> dict[str, Any]:
    """Each key of a section and its type."""
    cls = section_type(section)
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in fields(cls)}


def field_names(section: str) -> list[str]:
    return [f.name for f in fields(section_type(section))]
