"""Resolving a config from its layers: defaults < preset < config file < `--set` < explicit flags."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from canter.config.algorithms import (
    algorithm_names,
    check_algorithm_name,
    check_ignored_keys,
    reads_key,
    unread_key_error,
)
from canter.config.overrides import (
    SET_SOURCE,
    apply_overrides,
    flatten_toml,
    load_toml,
    parse_set_args,
)
from canter.config.presets import (
    canonical_preset,
    note_other_env,
    preset_algorithm,
    preset_layers,
    preset_names,
)
from canter.config.schema import Config
from canter.config.validate import validate
from canter.errors import CanterError
from canter.run_layout import holds_every_section

# The options that set a key and are not named after it, as a message names them (train's, and bench's and tune's).
FLAG_NAMES = {
    "env.id": "the env (its argument, or --envs)",
    "run.algo": "--algo (or --algos)",
    "run.seed": "--seed (or --seeds)",
    "run.total_steps": "--total-steps (or its default)",
}
# The keys that build_config's own arguments set, by argument, which a Python caller passes for the flags above.
ARGUMENT_NAMES = {"env.id": "env_id", "run.algo": "algo", "run.seed": "seed", "run.total_steps": "total_steps"}


def flag_name(key: str) -> str:
    """The option that sets `key`, as a message names it: `run.eval_every` is set by --eval-every."""
    return FLAG_NAMES.get(key) or "--" + key.partition(".")[2].replace("_", "-")


DEFAULT_PRESET = "fast"


def _file_preset(file_data: dict[str, Any]) -> str | None:
    """The preset a config file's run.preset names, or None for none: absent, another type (refused as a bad value
    when the file is applied) or "none", as a config built with no preset (Config's default) writes it."""
    named = file_data.get("run.preset")
    if not isinstance(named, str) or named.strip().lower() == "none":
        return None
    return named


def _base_preset(preset: str | None, file_data: dict[str, Any], config_file: str | Path | None) -> str:
    """The preset beneath the config file. run.preset records the preset a config was built from (the schema's
    "recorded, not applied"), so it must name the preset actually laid beneath the file, as --set run.preset must:
    a file that names one is laid over that one (so `canter train --config RUN/config.toml` reproduces a run of any
    preset under its own name), and one that names another than --preset is refused rather than relabelled."""
    named = _file_preset(file_data)
    if named is None:
        return canonical_preset(preset or DEFAULT_PRESET)
    from_file = canonical_preset(named)
    if from_file not in preset_names():
        raise CanterError(
            f"{config_file} sets run.preset = {named!r}, which is no preset; run.preset records the preset a "
            f"config was built from: drop it from the file, or name one of {', '.join(preset_names())}"
        )
    if preset is None:
        return from_file
    preset = canonical_preset(preset)
    if from_file != preset:  # it would misname the run
        raise CanterError(
            f"{config_file} sets run.preset = {named!r}, but the preset is {preset}; run.preset records the preset "
            f"a config was built from: pass --preset {named} (preset={named!r} from Python), or drop run.preset "
            f"from the file"
        )
    return preset


def build_config(
    env_id: str | None,
    preset: str | None = None,
    config_file: str | Path | None = None,
    sets: list[str] | None = None,
    seed: int | None = None,
    total_steps: int | None = None,
    algo: str | None = None,
    check_unread: bool = True,
    flags: Mapping[str, Any] | None = None,
    notes: bool = True,
) -> Config:
    """The config of env `env_id` (else the env.id of `sets` or the config file): defaults < `preset` < `config_file`
    < `sets` < the other arguments, validated.

    `preset` defaults to the one the config file's run.preset names, else fast; `algo` to the run.algo of `sets` or
    the file, else the preset's, else ppo. `config_file` is a TOML file (a str or Path), such as a run folder's
    config.toml; `sets` a list of "section.key=value" strings, such as ["ppo.clip=0.1"]. A key given both by `sets`
    and by its own argument (`seed`, say) is refused, as is a `sets` or file key the algorithm does not read, which
    would change nothing, except in a format-1 run folder's config.toml, which holds every algorithm's section.
    `check_unread`, `flags` and `notes` are internal: canter's commands use them to skip that check, to add the keys
    their other flags set, and to keep notes off stderr."""
    # The command line and Python callers reach the same refusals, so each names the flag, then the argument.
    if config_file is not None and not isinstance(config_file, (str, Path)):  # Path() would raise a TypeError
        raise CanterError(f"config_file= must be a path (str or Path), got {type(config_file).__name__}")
    # An empty string would otherwise read as not given.
    if config_file == "":
        raise CanterError("--config (config_file= from Python) is empty; give a TOML file, or drop it")
    if preset == "":
        raise CanterError(
            f"--preset (preset= from Python) is empty; give one of {', '.join(preset_names())}, or drop it"
        )
    if algo == "":
        raise CanterError(
            f"--algo (algo= from Python) is empty; give one of {', '.join(algorithm_names())}, or drop it"
        )
    for name, number in (("seed", seed), ("total_steps", total_steps)):
        # A float or a string would be converted as a TOML value is, where the API's other seeds refuse them.
        if number is not None and (isinstance(number, bool) or not isinstance(number, int | np.integer)):
            raise CanterError(f"{name}= must be a whole number (an int) or None, got {number!r}")
    file_data = flatten_toml(load_toml(config_file), str(config_file)) if config_file else {}
    set_data = parse_set_args([] if sets is None else sets)
    resolved_id = env_id or set_data.get("env.id") or file_data.get("env.id")
    if not resolved_id:
        raise CanterError(
            'no environment given; pass an env id, e.g. `canter train Hopper-v5` (`canter.build_config("Hopper-v5")` '
            "from Python)"
        )
    # A preset the file chose, rather than --preset, must say so where it refuses the algorithm.
    named_by = str(config_file) if preset is None and _file_preset(file_data) is not None else None
    preset = _base_preset(preset, file_data, config_file)
    if "run.preset" in file_data and isinstance(file_data["run.preset"], str):
        file_data["run.preset"] = preset  # an alias names its preset by the preset's own name
    if "run.preset" in set_data and canonical_preset(str(set_data["run.preset"])) != preset:  # it would misname the run
        raise CanterError(
            f"run.preset names the preset a run was built from; pass --preset {set_data['run.preset']} rather than "
            f"--set run.preset (preset={set_data['run.preset']!r} rather than sets= from Python): it would label a "
            f"run of preset {preset}'s settings"
        )
    if "run.preset" in set_data:
        set_data["run.preset"] = preset  # an alias names its preset by the preset's own name
    config = Config()
    first: dict[str, Any] = {"env.id": resolved_id, "run.preset": preset}
    # The algorithm comes first, so that the preset's algorithm tables, its `algos` check and the unread-key check
    # all see the one that will train: --algo, then --set run.algo, the config file's, the preset's, the default.
    resolved_algo = (
        algo or set_data.get("run.algo") or file_data.get("run.algo") or preset_algorithm(preset, str(resolved_id))
    )
    if resolved_algo:
        check_algorithm_name(str(resolved_algo))
        first["run.algo"] = resolved_algo
    config = apply_overrides(config, first, "arguments")
    if config_file and holds_every_section(config_file):  # a format-1 run folder's config.toml
        file_data = {key: value for key, value in file_data.items() if reads_key(config.run.algo, key)}
    for source, layer in preset_layers(preset, str(resolved_id), config.run.algo, named_by):
        # the algorithm asked for wins over the one a preset names
        config = apply_overrides(config, {**layer, "run.algo": config.run.algo}, source)
    if notes:
        note_other_env(preset, str(resolved_id))
    config = apply_overrides(config, file_data, str(config_file))
    from_file = config
    config = apply_overrides(config, set_data, SET_SOURCE)
    explicit: dict[str, Any] = {key: value for key, value in (("env.id", env_id), ("run.algo", algo)) if value}
    explicit |= {
        key: value for key, value in (("run.seed", seed), ("run.total_steps", total_steps)) if value is not None
    }
    explicit |= dict(flags or {})
    for key in sorted(explicit.keys() & set_data.keys()):  # the flag would win, silently
        python = f" ({ARGUMENT_NAMES[key]}= and sets= from Python)" if key in ARGUMENT_NAMES else ""
        raise CanterError(f"{key} is given twice, by {flag_name(key)} and by --set {key}{python}; give it once")
    config = apply_overrides(config, explicit, "arguments")
    if check_unread:  # after the flags: --algo replaces a config file's run.algo, and its algorithm is what trains
        for key in [*file_data, *set_data]:  # a key the algorithm does not read would change nothing
            if not reads_key(config.run.algo, key):
                raise CanterError(unread_key_error(config.run.algo, key))
        check_ignored_keys(config)
    try:
        validate(config)
    except CanterError as exc:
        if config_file and _refused_alike(from_file, exc):  # among several files, the one at fault must show
            raise CanterError(f"{exc} (in {config_file})") from None
        raise
    return config


def preset_config(config: Config) -> Config | None:
    """The config that a run's preset alone gives its env and algorithm, to tell the settings the run changed from
    those it was given; None where this canter cannot build it (a preset it no longer ships, or that no longer builds
    for this env)."""
    try:
        return build_config(config.env.id, preset=config.run.preset, algo=config.run.algo, notes=False)
    except CanterError:
        return None


def _refused_alike(config: Config, refusal: CanterError) -> bool:
    """Whether `config` (defaults < preset < config file) is refused as the whole config was: the file's values, not
    a --set or flag over them, are what validation refuses."""
    try:
        validate(config)
    except CanterError as exc:
        return str(exc) == str(refusal)
    return False
