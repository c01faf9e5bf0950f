"""Hyperparameter search spaces: editable TOML files whose keys are config keys.

    [ppo.lr]                      # a range: uniform, or log-uniform with log = true
    low = 1e-5
    high = 1.0
    log = true

    [ppo.n_steps]                 # a set of choices
    choices = [8, 16, 32, 64]

    [ddpg.critic_lr]              # tied: the value sampled for another key of the space
    same_as = "ddpg.actor_lr"

An integer key with a range samples integers (`step` optional), a float key floats; `choices` work for any key,
including tuples written as strings ("64-64"). A file is checked in full before any trial: every key must be a
config key, every value must have the key's type and pass the key's own validation, and a range must not be empty.
The keys the caller sets itself (`fixed`: tune's env, algorithm, seeds, budget and run keys) cannot be searched.
canter ships one space per algorithm, in its folder (`AlgorithmSpec.search_space`); `--space FILE` takes an edited copy.
"""

from __future__ import annotations

import math
import os
import stat
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Any

from canter.config.algorithms import algorithm_spec
from canter.config.overrides import all_keys, apply_overrides, key_suggestion
from canter.config.schema import Config, field_types
from canter.config.validate import validate
from canter.config.values import coerce
from canter.errors import CanterError
from canter.parsing import toml_table

_RANGE_KEYS = {"low", "high", "log", "step"}
_NONE_FIXED: Mapping[str, str] = MappingProxyType({})


@dataclass(frozen=True)
class Param:
    key: str  # section.key
    choices: tuple[Any, ...] | None = None  # values as Optuna stores them (tuples as "64-64" strings)
    low: float | int | None = None
    high: float | int | None = None
    log: bool = False
    step: float | int | None = None
    integer: bool = False
    same_as: str | None = None  # takes the value sampled for another key


@dataclass(frozen=True)
class SearchSpace:
    params: tuple[Param, ...]
    source: str

    @property
    def keys(self) -> list[str]:
        return [p.key for p in self.params]

    def suggest(self, trial: Any) -> dict[str, Any]:
        """One `{section.key: value}` draw from an Optuna trial (or FixedTrial)."""
        values: dict[str, Any] = {}
        for p in self.params:
            if p.same_as is not None:
                continue
            if p.choices is not None:
                values[p.key] = trial.suggest_categorical(p.key, list(p.choices))
                continue
            assert p.low is not None and p.high is not None, "a param without choices is a range"
            if p.integer:
                values[p.key] = trial.suggest_int(p.key, int(p.low), int(p.high), step=int(p.step or 1), log=p.log)
            else:
                values[p.key] = trial.suggest_float(p.key, float(p.low), float(p.high), step=p.step, log=p.log)
        for p in self.params:
            if p.same_as is not None:
                values[p.key] = values[p.same_as]
        return values


def default_space_text(algo: str) -> str:
    """The search space an algorithm ships in its folder (`AlgorithmSpec.search_space`)."""
    package, name = algorithm_spec(algo).search_space
    return resources.files(package).joinpath(name).read_text()


def load_space(path: str | Path | None, algo: str, fixed: Mapping[str, str] = _NONE_FIXED) -> SearchSpace:
    """The space of `path`, or the one `algo` ships; `fixed`: key -> what sets it instead (`parse_space`)."""
    import tomllib

    if path is None:
        return parse_space(tomllib.loads(default_space_text(algo)), f"the shipped {algo} search space", fixed)
    if not str(path).strip():  # Path("") is the current folder
        raise CanterError("--space is empty; give a search space TOML file, or drop --space")
    return parse_space(_read_space_file(Path(path)), str(path), fixed)


_SPACE_TAKES = "--space takes a search space TOML file"


def _read_space_file(path: Path) -> dict[str, Any]:
    """A search space file's TOML, with messages that call it one (load_toml's are about --config files). A pipe or
    device is refused without waiting on it: it is opened without blocking and checked before it is read."""
    import tomllib

    if path.is_dir():
        raise CanterError(f"{path} is a folder; {_SPACE_TAKES}")
    not_regular = CanterError(
        f"search space file {path} is not a regular file (a device, pipe or socket); {_SPACE_TAKES}"
    )
    if path.exists() and not path.is_file():
        raise not_regular
    if not path.is_file():
        raise CanterError(f"search space file not found: {path}")
    try:
        # O_NONBLOCK: a path that became a pipe since the check opens at once rather than waiting for a writer.
        with os.fdopen(os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0)), "rb") as file:
            if not stat.S_ISREG(os.fstat(file.fileno()).st_mode):
                raise not_regular
            data = file.read()
    except PermissionError:
        raise  # the command line names the fix for every unreadable path alike
    except OSError as exc:  # a file that lists as regular but does not read, such as /proc/self/mem
        raise CanterError(f"cannot read search space file {path}: {exc.strerror or exc}; {_SPACE_TAKES}") from None
    try:
        return toml_table(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise CanterError(
            f"search space file {path} is not UTF-8 text; save it as UTF-8, or pass another with --space"
        ) from None
    except tomllib.TOMLDecodeError as exc:
        raise CanterError(f"malformed TOML in {path}: {exc}") from None


def _optuna_value(value: Any) -> Any:
    """Optuna categoricals hold None, bool, int, float and str: tuples become '64-64' and the rest stay as they are
    (not text, as `set_text` makes them), since stored studies keep these choices and a resumed study compares them."""
    return "-".join(map(str, value)) if isinstance(value, tuple) else value


def _check_alone(key: str, value: Any, source: str) -> None:
    """The value must pass the key's own validation on the default config (errors about other keys, such as a
    minibatch that does not divide the default batch, are interactions and not the value's fault)."""
    try:
        validate(apply_overrides(Config().with_values("env", id="Hopper-v5"), {key: value}, source))
    except CanterError as exc:
        if str(exc).startswith(key):
            raise CanterError(f"{source}: {key} = {value!r} is invalid: {exc}") from None


def _coerced(key: str, raw: Any, source: str) -> Any:
    """The raw value as the key's type; an error names the file, as the space's other errors do."""
    section, _, name = key.partition(".")
    try:
        return coerce(key, field_types(section)[name], raw)
    except CanterError as exc:
        raise CanterError(f"{source}: {exc}") from None


def parse_space(data: dict[str, Any], source: str, fixed: Mapping[str, str] = _NONE_FIXED) -> SearchSpace:
    """The space a TOML file's tables describe. `fixed` maps the keys the caller sets in every trial to what sets
    them: a sampled value of one would be overridden, yet shown as the trial's, or would change what is tuned."""
    known = set(all_keys())
    params: list[Param] = []
    for section, table in data.items():
        if not isinstance(table, dict):
            raise CanterError(f"{source}: '{section}' must be a table of [section.key] entries")
        for name, spec in table.items():
            key = f"{section}.{name}"
            if key not in known:
                suggestion = key_suggestion(key)
                hint = f"; {suggestion}" if suggestion else "; keys are config keys like ppo.lr"
                raise CanterError(f"{source}: unknown hyperparameter '{key}'{hint}")
            if key in fixed:
                raise CanterError(
                    f"{source}: [{key}] cannot be searched: it is set by {fixed[key]}; drop it from the space"
                )
            if not isinstance(spec, dict):
                raise CanterError(f"{source}: [{key}] must be a table with choices = [...] or low/high")
            params.append(_param(key, spec, source))
    if not params:
        raise CanterError(f"{source}: the search space is empty; add [section.key] tables")
    _check_ties(params, source)
    return SearchSpace(tuple(params), source)


def _check_ties(params: list[Param], source: str) -> None:
    by_key = {p.key: p for p in params}
    for p in params:
        if p.same_as is None:
            continue
        other = by_key.get(p.same_as)
        if other is None or other.same_as is not None:
            raise CanterError(f"{source}: [{p.key}] same_as = {p.same_as!r} must name a sampled key of this space")
        for value in other.choices or (other.low, other.high):
            _check_alone(p.key, _coerced(p.key, value, source), source)


def _param(key: str, spec: dict[str, Any], source: str) -> Param:
    extra = set(spec) - _RANGE_KEYS - {"choices", "same_as"}
    if extra:
        raise CanterError(
            f"{source}: [{key}] has unknown entries {sorted(extra)}; use choices, or low, high, log, step, or same_as"
        )
    if "same_as" in spec:
        if set(spec) != {"same_as"} or not isinstance(spec["same_as"], str):
            raise CanterError(f'{source}: [{key}] same_as = "section.key" stands alone')
        return Param(key, same_as=spec["same_as"])
    if "choices" in spec:
        if set(spec) != {"choices"}:
            raise CanterError(f"{source}: [{key}] has both choices and a range; keep one")
        choices = spec["choices"]
        if not isinstance(choices, list) or not choices:
            raise CanterError(f"{source}: [{key}] has an empty list of choices")
        values = []
        for raw in choices:
            value = _coerced(key, raw, source)
            _check_alone(key, value, source)
            values.append(_optuna_value(value))
        if len(set(map(repr, values))) != len(values):
            raise CanterError(f"{source}: [{key}] repeats a choice")
        return Param(key, choices=tuple(values))
    if "low" not in spec or "high" not in spec:
        raise CanterError(f"{source}: [{key}] needs choices = [...] or both low and high")
    low, high = _coerced(key, spec["low"], source), _coerced(key, spec["high"], source)
    if not isinstance(low, (int, float)) or isinstance(low, bool) or low is None or high is None:
        raise CanterError(f"{source}: [{key}] is not numeric; give it choices = [...]")
    if not (math.isfinite(low) and math.isfinite(high)) or not low < high:
        raise CanterError(f"{source}: [{key}] has an empty range: low {low} must be below high {high}")
    log = spec.get("log", False)
    if not isinstance(log, bool):
        raise CanterError(f"{source}: [{key}] log must be true or false")
    if log and low <= 0:
        raise CanterError(f"{source}: [{key}] is log-uniform, so low must be > 0, got {low}")
    step = spec.get("step")
    integer = isinstance(low, int)
    # Optuna takes log with no step on a float, and with step 1 on an integer.
    if step is not None and (
        not isinstance(step, (int, float))
        or isinstance(step, bool)
        or not math.isfinite(step)
        or step <= 0
        or (log and (step != 1 or not integer))
    ):
        raise CanterError(f"{source}: [{key}] step must be a positive finite number (and cannot combine with log)")
    if integer and step is not None and step != int(step):
        raise CanterError(f"{source}: [{key}] takes whole numbers, so its step must be a whole number, got {step}")
    if step is not None:
        _check_step_fits(key, low, high, step, source)
    for value in (low, high):
        _check_alone(key, value, source)
    return Param(key, low=low, high=high, log=log, step=step, integer=integer)


def _check_step_fits(key: str, low: float, high: float, step: float, source: str) -> None:
    """The range must hold a whole number of steps: Optuna would otherwise cut high down to the last step with a
    warning, and the study would record a range that it never samples."""
    steps = (high - low) / step
    whole = math.floor(steps + 1e-9)
    if abs(steps - round(steps)) <= 1e-9 * max(1.0, abs(steps)):
        return
    if whole == 0:
        raise CanterError(
            f"{source}: [{key}] step {step:g} is larger than the range {low:g} to {high:g}; pick a step that divides "
            f"high - low = {high - low:g}"
        )
    raise CanterError(
        f"{source}: [{key}] step {step:g} does not divide the range {low:g} to {high:g}; set high = "
        f"{low + whole * step:g}, or pick a step that divides high - low = {high - low:g}"
    )


def apply_sample(base: Config, values: dict[str, Any]) -> Config:
    """The trial's config: base plus the sampled values. An on-policy minibatch larger than the batch is cut to the
    batch (RL Zoo does the same), so horizon and minibatch can be sampled independently."""
    config = apply_overrides(base, values, "the search space")
    spec = algorithm_spec(config.run.algo)
    if spec.rollout_batch is not None:
        batch = spec.rollout_batch(config)
        for key in spec.batch_divisors:
            section, _, name = key.partition(".")
            if getattr(config.section(section), name) > batch:
                config = config.with_values(section, **{name: batch})
    validate(config)
    return config
