"""Presets: named TOML layers shipped in `canter/presets/`, each completed by the tables algorithms declare for it.

A preset file holds plain sections and `[env_overrides."<glob>"]` tables (fnmatch on the env id without any
`module:` prefix); its top-level `algos` list, when present, names the only algorithms it holds settings for, and a
`# env: ID, ID` line in its header the envs it was made for. An algorithm adds its own table per preset
(`AlgorithmSpec.preset_overrides`, same layout), applied after the file's. A top-level `extends = "<preset>"` lays the
file over another preset (that preset's file and algorithm tables first), so a recipe built on another one states
only its changes; it inherits the other's `algos` unless it names its own.
"""

from __future__ import annotations

import fnmatch
import re
import sys
import tomllib
from importlib import resources
from typing import Any

from canter.config.algorithms import algorithm_spec
from canter.config.overrides import flatten_toml
from canter.errors import CanterError

# Former names of the report presets: `seed000-...` read like a run seed, so they were renamed after the report
# they reproduce. The old names keep working, with a notice.
ALIASES = {
    "seed000-halfcheetah": "report000-halfcheetah",
    "seed000-humanoidstandup": "report000-humanoidstandup",
    "seed002-bipedalwalker-ppo": "report002-bipedalwalker-ppo",
    "seed002-ddpg": "report002-ddpg",
    "seed002-hopper-trpo": "report002-hopper-trpo",
}


def preset_names() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("canter.presets").iterdir() if p.name.endswith(".toml"))


def canonical_preset(name: str) -> str:
    """The preset's current name; an old name prints a one-line notice and maps to its new one."""
    if name in ALIASES:
        print(f"canter: note: preset {name} is now called {ALIASES[name]}; use the new name", file=sys.stderr)
        return ALIASES[name]
    return name


def shipped_preset_text(name: str) -> str:
    """The text of the preset file shipped under `name`."""
    if name not in preset_names():
        raise CanterError(f"unknown preset '{name}'; choose one of: {', '.join(preset_names())}")
    return resources.files("canter.presets").joinpath(f"{name}.toml").read_text()


def preset_envs(name: str) -> tuple[str, ...]:
    """The env ids a preset was made for (its header's `# env:` lines), or () for a general preset."""
    found = re.findall(r"^# env: (.+)$", shipped_preset_text(name), flags=re.MULTILINE)
    return tuple(env_id.strip() for line in found for env_id in line.split(","))


def note_other_env(name: str, env_id: str) -> None:
    """One line on stderr when a preset made for other envs is applied to this one: its numbers were chosen for
    those envs (their action ranges, their budgets), and nothing checked them here."""
    made_for = preset_envs(name)
    base_id = env_id.split(":")[-1]
    if made_for and base_id not in made_for:
        print(
            f"canter: note: preset {name} was made for {', '.join(made_for)}; its settings are untested on {base_id}",
            file=sys.stderr,
        )


def _read_preset(name: str) -> tuple[dict[str, Any], list[str] | None, str | None]:
    """A preset's tables, and apart from them the algorithms it declares it holds settings for (its top-level
    `algos`, None for all) and the preset it extends (None for none)."""
    table = tomllib.loads(shipped_preset_text(name))
    return table, table.pop("algos", None), table.pop("extends", None)


def _read_chain(name: str) -> list[tuple[str, dict[str, Any], list[str] | None]]:
    """Each preset of a chain once, base first, ending with `name`: its name, its tables and its `algos`."""
    chain: list[tuple[str, dict[str, Any], list[str] | None]] = []
    link: str | None = name
    while link is not None:
        names = [n for n, _, _ in reversed(chain)]
        if link in names:
            loop = " -> ".join([*names, link])
            raise CanterError(f"preset {name} extends itself ({loop}); remove one of these `extends`")
        table, algos, link_base = _read_preset(link)
        chain.insert(0, (link, table, algos))
        link = link_base
    return chain


def _nearest_algorithms(chain: list[tuple[str, dict[str, Any], list[str] | None]]) -> list[str] | None:
    return next((algos for _, _, algos in reversed(chain) if algos is not None), None)


def preset_layer(table: dict[str, Any], env_id: str, source: str) -> dict[str, Any]:
    """Flatten one preset table: its plain sections, then its `[env_overrides."<glob>"]` tables matching env_id.
    Later layers win."""
    table = dict(table)
    per_env = table.pop("env_overrides", {})
    flat = flatten_toml(table, source)
    base_id = env_id.split(":")[-1]
    for pattern, tables in per_env.items():
        if fnmatch.fnmatch(base_id, pattern):
            flat.update(flatten_toml(tables, source))
    return flat


def preset_algorithm(name: str, env_id: str) -> str | None:
    """The run.algo a preset's chain sets for this env (a report's preset names its algorithm), or None."""
    algo = None
    for link, table, _ in _read_chain(name):
        algo = preset_layer(table, env_id, f"preset {link}").get("run.algo", algo)
    return None if algo is None else str(algo)


def preset_layers(
    name: str, env_id: str, algo: str = "ppo", named_by: str | None = None
) -> list[tuple[str, dict[str, Any]]]:
    """A preset's keys for this env and algorithm, layer by layer, later layers winning: for each preset in its
    chain, base first, that preset's file layer, then the algorithm's own table for it; each with the source that
    an error in it names (an algorithm's table is not in the preset file). A preset whose `algos` list names the
    algorithms it holds settings for refuses the others, which would otherwise get the bare defaults under its name.
    `named_by` is the config file whose run.preset chose the preset, where no --preset did."""
    chain = _read_chain(name)
    supported = _nearest_algorithms(chain)
    if supported and algo not in supported:
        holds = (
            f"holds settings for {', '.join(supported)} only, not {algo}; train one of those algorithms with it, "
            f"e.g. --algo {supported[0]} (algo={supported[0]!r} from Python)"
        )
        if named_by is None:
            raise CanterError(f"preset {name} {holds}, or choose another --preset (preset= from Python)")
        # --preset fast alone would be refused, as naming another preset than the file's run.preset
        raise CanterError(
            f"preset {name}, named by {named_by}'s run.preset, {holds}, or drop run.preset from {named_by} and pass "
            f"another preset, e.g. --preset fast (preset='fast' from Python)"
        )
    layers: list[tuple[str, dict[str, Any]]] = []
    for link, table, _ in chain:
        layers.append((f"preset {link}", preset_layer(table, env_id, f"preset {link}")))
        own = algorithm_spec(algo).preset_overrides.get(link)
        if own:
            source = f"{algo}'s table [{algo}.{link}] for preset {link} (its presets.toml)"
            layers.append((source, preset_layer(dict(own), env_id, source)))
    return layers


def algorithm_preset_tables(package: str, algo: str) -> dict[str, Any]:
    """An algorithm's own preset tables: `[<algo>.<preset>...]` in the presets.toml of its package."""
    table = tomllib.loads(resources.files(package).joinpath("presets.toml").read_text())
    return dict(table.get(algo, {}))
