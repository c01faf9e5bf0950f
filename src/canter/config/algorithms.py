"""What each algorithm declares to the rest of canter, without importing JAX: its name, the config keys it reads,
its config checks, its search space, its preset overrides and its plot labels.

Each algorithm builds one `AlgorithmSpec` in its own folder (`canter/algos/<name>/sections.py`) and registers it
there; `canter/algos/registry.py` lists those modules, one line per algorithm. This package never imports them.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from canter.config.schema import CORE_SECTIONS, field_names, section_names
from canter.errors import CanterError


@dataclass(frozen=True)
class AlgorithmSpec:
    name: str
    summary: str
    # The module whose `ALGORITHMS[name]` is the runtime `canter.algos.Algorithm` record (imported lazily: JAX).
    runtime: str
    # What it reads beyond env.* and run.*: whole sections ("ppo") or single keys ("ppo.n_steps").
    reads: tuple[str, ...]
    # Checks across the keys it reads (each section's own checks run for every section); `validate(config)`.
    validate: Callable[[Any], None]
    # (package, file) of the TOML search space that `canter tune` uses by default.
    search_space: tuple[str, str]
    # The env steps of one jitted iteration, autoreset steps included (`iteration_steps(config)`): a run spends its
    # budget in whole iterations. `iteration_keys` are the settings that size it, named when a budget is rounded up.
    iteration_steps: Callable[[Any], int]
    iteration_keys: tuple[str, ...]
    # Per preset name, the preset table this algorithm adds on top of the preset file (the same layout as a preset:
    # plain sections and `[env_overrides."<glob>"]`).
    preset_overrides: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    # (title, y-axis label) of the metrics.csv columns it logs.
    plot_labels: Mapping[str, tuple[str, str]] = field(default_factory=dict)
    # On-policy: the samples of one rollout (`rollout_batch(config)`), and the keys that must divide it, which
    # `canter tune` cuts to the batch when it samples them larger.
    rollout_batch: Callable[[Any], int] | None = None
    batch_divisors: tuple[str, ...] = ()
    # Seeds train one per process (`canter bench`) rather than vmapped in one program: see docs/multiseed.md.
    seeds_train_apart: bool = False
    # The metrics.csv columns that a config turns off (logged as 0 or empty then), which plots leave out:
    # `unused_metrics(config)`.
    unused_metrics: Callable[[Any], tuple[str, ...]] = lambda config: ()
    # Keys of its section that it never reads (inherited by the section), with why: `check_ignored_keys`.
    ignores: Mapping[str, str] = field(default_factory=dict)
    # The key of the env steps it acts at random before its first update ("td3.learning_starts"), if it has them.
    warm_up_key: str | None = None
    # The keys that size one call's memory beyond the train state, which the refusal of a program too large for the
    # memory names; empty: `iteration_keys` (an on-policy rollout is its memory, an off-policy call's is its batch).
    call_memory_keys: tuple[str, ...] = ()

    def memory_keys(self) -> tuple[str, ...]:
        return self.call_memory_keys or self.iteration_keys


_REGISTERED: dict[str, AlgorithmSpec] = {}


def register_algorithm(spec: AlgorithmSpec) -> None:
    known = _REGISTERED.get(spec.name)
    if known is not None and known is not spec:
        raise ValueError(f"algorithm '{spec.name}' is already registered")
    # A `reads` entry names what config.toml keeps and what --set may change for the algorithm: a typo there
    # would surface as a traceback in training, and a missing own section as its keys refused.
    for entry in spec.reads:
        section, _, key = entry.partition(".")
        if section not in section_names() or (key and key not in field_names(section)):
            raise ValueError(f"algorithm '{spec.name}' reads {entry!r}, which is no registered config section or key")
    # A plot titles a metrics column once for every run in it, whatever their algorithms (`all_plot_labels`).
    for other in _REGISTERED.values():
        for column, label in spec.plot_labels.items():
            if other is not spec and other.plot_labels.get(column, label) != label:
                raise ValueError(
                    f"algorithm '{spec.name}' labels the metrics column '{column}' {label}, but '{other.name}' labels "
                    f"it {other.plot_labels[column]}; one plot titles a column once, so give it the same label or "
                    f"another column name"
                )
    _REGISTERED[spec.name] = spec


def algorithm_names() -> list[str]:
    return list(_REGISTERED)


def check_algorithm_name(name: str) -> None:
    if name not in _REGISTERED:
        close = difflib.get_close_matches(name.lower(), list(_REGISTERED), n=1, cutoff=0.5)
        hint = f"did you mean {close[0]}? " if close else ""
        raise CanterError(f"unknown algorithm '{name}'; {hint}choose one of: {', '.join(_REGISTERED)}")


def algorithm_spec(name: str) -> AlgorithmSpec:
    check_algorithm_name(name)
    return _REGISTERED[name]


def all_plot_labels() -> dict[str, tuple[str, str]]:
    labels: dict[str, tuple[str, str]] = {}
    for spec in _REGISTERED.values():
        labels.update(spec.plot_labels)
    return labels


def unused_metrics(config: Any) -> tuple[str, ...]:
    """The diagnostics that the run's config turns off."""
    return algorithm_spec(config.run.algo).unused_metrics(config)


def budget_rounding_note(config: Any) -> str | None:
    """A note when the run's budget is far from a whole number of its iterations: it trains until the iteration
    that reaches run.total_steps ends, so a budget below one iteration trains a whole one. None within 10%. The
    budget counts no autoreset steps (one after each episode end), so where episodes end a run can take another
    iteration, and a budget of whole iterations always does: the note says so rather than advise a multiple that
    would not end on an iteration boundary (how many autoreset steps a run has depends on its episodes)."""
    spec = algorithm_spec(config.run.algo)
    per_iteration = spec.iteration_steps(config)
    budget = config.run.total_steps
    trained = -(-budget // per_iteration) * per_iteration
    if trained - budget <= budget / 10:
        return None
    sizes = " x ".join(f"{key} {key_value(config, key):,}" for key in spec.iteration_keys)
    return (
        f"{spec.name} trains in whole iterations of {per_iteration:,} env steps ({sizes}), to the end of the one "
        f"that reaches the budget, so this run.total_steps={budget:,} run trains about {trained:,}; autoreset steps "
        f"(one per episode end) do not count, so where episodes end it can take one more iteration, even with a "
        f"multiple of {per_iteration:,}; for a finer budget give smaller {' / '.join(spec.iteration_keys)}"
    )


def slow_call_note(config: Any, seconds: float) -> str:
    """The note for a run whose jitted calls are long: it logs, checkpoints and stops on a signal only between them."""
    spec = algorithm_spec(config.run.algo)
    sizes = ", ".join(f"{key}={key_value(config, key):,}" for key in spec.iteration_keys)
    keys = " / ".join(spec.iteration_keys)
    return (
        f"one call of the training program took {seconds:,.0f} s, and the run logs, checkpoints and stops on Ctrl-C "
        f"or SIGTERM only between calls; to do those sooner give a smaller {keys} (now {sizes})"
    )


def warm_up_note(config: Any) -> str | None:
    """A note when the whole budget falls within the steps an algorithm acts at random before its first update:
    such a run learns nothing. None otherwise, and for an algorithm with no such phase."""
    key = algorithm_spec(config.run.algo).warm_up_key
    if key is None:
        return None
    starts = key_value(config, key)
    budget = config.run.total_steps
    if budget > starts:
        return None
    return (
        f"{config.run.algo} acts at random for its first {key}={starts:,} steps and updates nothing before them, so "
        f"this {budget:,}-step run will not learn; give a larger --total-steps or --set {key}=N"
    )


def key_value(config: Any, key: str) -> Any:
    """The value of `section.key` in a config."""
    section, _, name = key.partition(".")
    return getattr(getattr(config, section), name)


def reads_key(algo: str, key: str) -> bool:
    """Whether `algo` reads `section.key` (or the whole section when `key` is a section name)."""
    reads = algorithm_spec(algo).reads
    section = key.partition(".")[0]
    return section in CORE_SECTIONS or section in reads or key in reads


def read_sections(algo: str) -> list[tuple[str, tuple[str, ...] | None]]:
    """(section, names) for what `algo` reads beyond env and run, in its declared order: None means the whole
    section, a tuple the single keys it reads of it."""
    out: dict[str, list[str] | None] = {}
    for item in algorithm_spec(algo).reads:
        section, _, name = item.partition(".")
        if not name:
            out[section] = None
        elif (names := out.setdefault(section, [])) is not None:  # None: the whole section is read already
            names.append(name)
    return [(s, None if names is None else tuple(names)) for s, names in out.items()]


def unread_key_error(algo: str, key: str) -> str:
    """The one-line refusal of a key that `algo` would silently ignore, pointing to the key it does read."""
    section, _, name = key.partition(".")
    reads = algorithm_spec(algo).reads
    sections = [s for s in reads if "." not in s]
    single = [k for k in reads if "." in k]
    listed = ", ".join([f"{s}.*" for s in sections] + single + ["env.*", "run.*"])
    twins = [f"{s}.{name}" for s in sections if s != section and name in field_names(s)]
    if twins:
        fix = f"set {twins[0]} instead"
    else:
        readers = ", ".join(a for a in _REGISTERED if reads_key(a, key)) or "no algorithm"
        fix = f"drop it ({key} is read by {readers})"
    return f"{key} has no effect on {algo}, which reads {listed}; {fix}"


def check_ignored_keys(config: Any) -> None:
    """Refuse a key the algorithm ignores set away from its default: it would change nothing but split runs into
    different experiments. Only what a user builds is checked (`build_config`), so run folders that hold one load."""
    spec = algorithm_spec(config.run.algo)
    for key, why in spec.ignores.items():
        section, _, name = key.partition(".")
        values = config.section(section)
        if getattr(values, name) != getattr(type(values)(), name):
            raise CanterError(f"{key} has no effect on {spec.name} ({why}); leave it out")
