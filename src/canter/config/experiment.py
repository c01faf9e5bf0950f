"""Which runs are seeds of one experiment: the one rule, used by eval, plot, report, bench and tune.

Two runs are seeds of one experiment when every key their algorithm reads and whose role is `LEARNING`
(`canter.config.fields`) is equal. The seed, the budget (`run.total_steps`, `run.max_minutes`,
`run.stop_at_return`) and output and bookkeeping keys (`run.out_dir`, `run.preset`, `run.video_every`,
`run.tensorboard`, the checkpoint keys, `env.envpool_shards`) do not count. The budget does not count so that a
run extended by bench or `--resume` stays in its experiment, although with `ppo.anneal_lr` the learning-rate
schedule follows the budget.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import fields
from typing import Any

from canter.config.fields import LEARNING, role_of
from canter.config.schema import Config
from canter.config.serialize import written_keys


def flat_config(config: Config) -> dict[str, Any]:
    """`{"section.key": value}` of every key the run reads."""
    return {
        f"{section}.{name}": getattr(config.section(section), name)
        for section, names in written_keys(config)
        for name in names
    }


def learning_keys(config: Config) -> list[str]:
    """The keys the run reads that change what is learned, in config.toml order."""
    keys = []
    for section, names in written_keys(config):
        roles = {f.name: role_of(f) for f in fields(config.section(section))}
        keys += [f"{section}.{name}" for name in names if roles[name] == LEARNING]
    return keys


def experiment_key(config: Config) -> tuple[tuple[str, Any], ...]:
    flat = flat_config(config)
    return tuple((key, flat[key]) for key in learning_keys(config))


BUDGET_KEY = "run.total_steps"


def comparison_key(config: Config) -> tuple[tuple[str, Any], ...]:
    """What makes finished runs seeds of one result when eval, plot and report compare them: the experiment and the
    budget it trained to. A resume may change the budget (`experiment_key` leaves it out for that), but an annealed
    learning rate stretches over it, and scores at different budgets are not samples of one number."""
    return (*experiment_key(config), (BUDGET_KEY, config.run.total_steps))


def group_by_experiment(configs: Sequence[Config]) -> list[list[int]]:
    """Indices of the configs, grouped by experiment and budget (`comparison_key`), in order of first appearance."""
    groups: dict[tuple[tuple[str, Any], ...], list[int]] = {}
    for i, config in enumerate(configs):
        groups.setdefault(comparison_key(config), []).append(i)
    return list(groups.values())


def repeated_seed_note(configs: Sequence[Config], names: Sequence[str]) -> str | None:
    """A note naming runs that are the same seed of one experiment and budget: each counts as a run of the group,
    though a rerun of a seed repeats its result rather than adding an independent sample. None if there are none."""
    seen: dict[tuple[Any, ...], str] = {}
    repeats = []
    for config, name in zip(configs, names):
        first = seen.setdefault((comparison_key(config), config.run.seed), name)
        if first != name:
            repeats.append((first, name, config.run.seed))
    if not repeats:
        return None
    first, name, seed = repeats[0]
    more = f" (and {len(repeats) - 1} more such runs)" if len(repeats) > 1 else ""
    return (
        f"{first} and {name} are both seed {seed} of one experiment{more}; each counts as a run of its group, but a "
        f"rerun repeats a seed rather than adding an independent one: leave one out, or train another seed"
    )


def differing_keys(configs: Sequence[Config], key_of: Callable[[Config], Any] = experiment_key) -> list[str]:
    """Learning keys (with `key_of=comparison_key`, and the budget) whose values are not the same in every config, in
    config.toml order."""
    keyed = [dict(key_of(c)) for c in configs]
    order: list[str] = []
    for k in keyed:
        order += [key for key in k if key not in order]
    missing = object()
    return [key for key in order if any(k.get(key, missing) != keyed[0].get(key, missing) for k in keyed[1:])]
