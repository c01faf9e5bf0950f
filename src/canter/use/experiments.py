"""Runs grouped into experiments, and the labels a plot and a report give them.

Runs that are seeds of one experiment (`canter.config.experiment`: equal in every key that changes what is
learned) form one group. Groups are labelled by the keys in which they differ (`experiment_labels`); the
statistics aggregate the groups of one method across envs (`method_labels`).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from canter.config.build import preset_config
from canter.config.experiment import (
    BUDGET_KEY,
    comparison_key,
    differing_keys,
    experiment_key,
    flat_config,
    repeated_seed_note,
)
from canter.config.schema import Config
from canter.config.values import set_text
from canter.use.curves import RunCurves

# Keys that name an experiment; a label uses only these when they tell the groups apart.
HEADLINE_KEYS = ("env.id", "run.algo", "run.preset")
SHORT_NAMES = {"env.id": "env", "run.algo": "algo", "run.preset": "preset", BUDGET_KEY: "budget"}


@dataclass(frozen=True)
class Experiment:
    """The runs that are seeds of one experiment, with the label a plot gives them."""

    label: str
    runs: tuple[RunCurves, ...]


def _show(key: str, value: Any) -> str:
    return f"{SHORT_NAMES.get(key, key)}={set_text(value)}"


def _label_keys(flats: Sequence[dict[str, Any]], configs: Sequence[Config]) -> list[list[str]]:
    """The keys that label each config (see `experiment_labels`)."""
    if len(configs) == 1:
        return [list(HEADLINE_KEYS)]
    diff = differing_keys(configs, comparison_key)
    headline = [k for k in HEADLINE_KEYS if any(f.get(k) != flats[0].get(k) for f in flats[1:])]
    keys = []
    for flat in flats:
        same_headline = [f for f in flats if all(f.get(k) == flat.get(k) for k in headline)]
        extra = [k for k in diff if k not in headline and k in flat and any(f.get(k) != flat[k] for f in same_headline)]
        keys.append(headline + extra)
    return keys


def experiment_labels(configs: Sequence[Config]) -> list[str]:
    """One label per config, from the keys in which they differ: the headline keys (env, algo, preset) when they
    tell the configs apart, plus any other differing key needed to tell apart configs whose headline is equal.
    A single config is labelled by its env, algo and preset."""
    flats = [flat_config(c) for c in configs]
    if len(configs) == 1:
        return [" ".join(_show(k, flats[0][k]) for k in HEADLINE_KEYS)]
    return [
        ", ".join(_show(k, flat[k]) for k in keys) or "same config"
        for flat, keys in zip(flats, _label_keys(flats, configs))
    ]


def method_keys(configs: Sequence[Config]) -> list[tuple[tuple[str, Any], ...]]:
    """What each run's method is on any env: its algorithm, preset and budget, the learning keys that some runs of
    one algorithm and preset on one env set to different values (a grid's keys: every run names its value), and
    the keys it sets apart from what its preset gives its env (a preset may give each env its own values; those
    stay the same method)."""
    by_env: dict[tuple[str, str, str], list[Config]] = {}
    for config in configs:
        by_env.setdefault((config.env.id, config.run.algo, config.run.preset), []).append(config)
    varied = {key for same_env in by_env.values() for key in differing_keys(same_env)}
    missing = object()
    keys = []
    for config in configs:
        preset = preset_config(config)
        base = flat_config(preset) if preset is not None else {}  # every key it sets counts as its own then
        changed = [
            (k, v) for k, v in experiment_key(config) if k != "env.id" and (k in varied or base.get(k, missing) != v)
        ]
        head = (("run.algo", config.run.algo), ("run.preset", config.run.preset))
        keys.append((*head, *changed, (BUDGET_KEY, config.run.total_steps)))
    return keys


_PER_ENV = "preset's per env"


def _headline(method: tuple) -> str:
    return ", ".join(_show(k, v) for k, v in method[:2])  # its algorithm and preset (`method_keys` puts them first)


def _method_values(configs: Sequence[Config], keys: Sequence[tuple]) -> dict[tuple, dict[str, Any]]:
    """Each method's value of each key its runs read (`_PER_ENV` where its envs' values differ). A key its algorithm
    does not read is left out rather than given None, so no label can claim another algorithm's key as `=none`."""
    flats = [flat_config(c) for c in configs]
    names = list(dict.fromkeys(name for method in keys for name, _ in method))
    values: dict[tuple, dict[str, Any]] = {}
    for method in dict.fromkeys(keys):
        own = [f for f, k in zip(flats, keys) if k == method]
        found = {}
        for name in names:
            read = [f[name] for f in own if name in f]
            if read:
                found[name] = read[0] if len({repr(v) for v in read}) == 1 and len(read) == len(own) else _PER_ENV
        values[method] = found
    return values


def _telling_keys(values: dict[tuple, dict[str, Any]]) -> dict[tuple, list[str]]:
    """The keys each method's label names: the algorithm where algorithms differ, and any key the method reads in
    which a method of its algorithm differs from it (or does not read it). Comparing only within an algorithm keeps
    a ppo row free of sac's keys and of the settings (budget, env count) that its algorithm already tells apart."""
    missing = object()
    telling = {}
    for method, own in values.items():
        peers = [v for v in values.values() if v is not own]
        keys = []
        for name, value in own.items():
            rivals = peers if name == "run.algo" else [v for v in peers if v.get("run.algo") == own.get("run.algo")]
            if any(repr(v.get(name, missing)) != repr(value) for v in rivals):
                keys.append(name)
        telling[method] = keys
    return telling


def method_labels(configs: Sequence[Config]) -> list[str]:
    """One label per config, equal for the configs of one method (`method_keys`), whose scores on several envs the
    statistics aggregate. A label names the algorithm where algorithms differ, and the keys of its own in which
    methods of one algorithm differ (the preset, the budget, the keys some method changed from its preset); a single
    method is labelled by its algorithm and preset."""
    keys = method_keys(configs)
    methods = list(dict.fromkeys(keys))
    if len(methods) == 1:
        return [_headline(keys[0])] * len(configs)
    values = _method_values(configs, keys)
    telling = _telling_keys(values)
    # a method that differs from its peers only in keys it does not read is named by its algorithm and preset
    labels = {m: ", ".join(_show(k, values[m][k]) for k in telling[m]) or _headline(m) for m in methods}
    if len(set(labels.values())) < len(methods):  # values that coincide across envs: name the changes themselves
        shared = set.intersection(*(set(m) for m in methods))
        labels = {m: ", ".join(_show(k, v) for k, v in [i for i in m if i not in shared] or m[:2]) for m in methods}
    return [labels[k] for k in keys]


def experiments_of(runs: Sequence[RunCurves]) -> list[Experiment]:
    """Runs that are seeds of one experiment trained to one budget (`canter.config.experiment.comparison_key`) form
    one group, in first-seen order; a seed that is there twice is noted."""
    note = repeated_seed_note([run.config for run in runs], [str(run.run_dir) for run in runs])
    if note is not None:
        print(f"canter: note: {note}", file=sys.stderr)
    keyed: dict[tuple, list[RunCurves]] = {}
    for run in runs:
        keyed.setdefault(comparison_key(run.config), []).append(run)
    members = list(keyed.values())
    labels = experiment_labels([m[0].config for m in members])
    return [Experiment(label, tuple(m)) for label, m in zip(labels, members)]
