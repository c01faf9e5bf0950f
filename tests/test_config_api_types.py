"""Values given to a config through the Python API (Config.with_values, Config.replace, the constructor) are typed as
the TOML and --set paths type them, or refused in one line naming the key; `build_config`'s `sets` is a list."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import canter
from canter.config.schema import Config, EnvConfig, RunConfig
from canter.config.serialize import from_toml_text, to_toml
from canter.errors import CanterError


@pytest.fixture(scope="module")
def config() -> Config:
    return canter.build_config("Pendulum-v1", total_steps=2048, notes=False)


def test_a_bool_given_as_text_trains_as_its_config_toml_reads_back(config: Config) -> None:
    # "no" is truthy: kept as given, it trained with normalization and was loaded without it
    off = config.with_values("env", normalize_obs="no")
    assert off.env.normalize_obs is False
    assert from_toml_text(to_toml(off), "test").env.normalize_obs is False


@pytest.mark.parametrize(
    ("section", "key", "given", "expected"),
    [
        ("run", "seed", 1.0, 1),
        ("ppo", "n_steps", np.int64(128), 128),
        ("env", "num_envs", 16.0, 16),
        ("ppo", "lr", "3e-4", 3e-4),
        ("ppo", "lr", np.float32(0.5), 0.5),
        ("run", "out_dir", Path("/tmp/canter-runs"), "/tmp/canter-runs"),
        ("net", "hidden", [np.int64(32), 32], (32, 32)),
        ("run", "max_minutes", "none", None),
        ("env", "normalize_obs", np.bool_(False), False),
        ("env", "normalize_obs", np.float64(1.0) > 0, True),
    ],
)
def test_harmless_other_types_are_converted_as_toml_values_are(
    config: Config, section: str, key: str, given: object, expected: object
) -> None:
    value = getattr(config.with_values(section, **{key: given}).section(section), key)
    assert value == expected and type(value) is type(expected)


@pytest.mark.parametrize(
    ("section", "key", "given", "message"),
    [
        ("run", "seed", 1.5, r"^run\.seed: expected an integer, got 1\.5$"),
        ("env", "normalize_obs", "maybe", r"^env\.normalize_obs: expected true or false, got 'maybe'$"),
        ("ppo", "lr", "fast", r"^ppo\.lr: expected a number, got 'fast'$"),
        ("env", "num_envs", True, r"^env\.num_envs: expected an integer, got True$"),
        ("env", "num_envs", np.bool_(True), r"^env\.num_envs: expected an integer, got np\.True_$"),
        ("run", "out_dir", 3, r"^run\.out_dir: expected a string, got 3$"),
        pytest.param("ppo", "lr", 10**400, r"^ppo\.lr: expected a number, got 1000", id="int-past-float"),
    ],
)
def test_wrong_types_are_one_line_errors_naming_the_key(
    config: Config, section: str, key: str, given: object, message: str
) -> None:
    with pytest.raises(CanterError, match=message):
        config.with_values(section, **{key: given})


def test_a_section_built_by_hand_is_typed_when_it_joins_a_config(config: Config) -> None:
    replaced = config.replace(run=dataclasses.replace(config.run, seed=np.int64(3)))
    assert type(replaced.run.seed) is int and replaced.run.seed == 3
    built = Config(env=EnvConfig(id="Pendulum-v1", num_envs=np.int64(2)))
    assert type(built.env.num_envs) is int
    with pytest.raises(CanterError, match=r"^run\.seed: expected an integer, got 0\.5$"):
        Config(run=RunConfig(seed=0.5))  # type: ignore[arg-type]
    with pytest.raises(CanterError, match=r"^run\.seed: expected an integer, got 'x'$"):
        dataclasses.replace(config, run=dataclasses.replace(config.run, seed="x"))


def test_a_section_of_the_wrong_kind_names_the_section_and_its_class(config: Config) -> None:
    with pytest.raises(CanterError, match=r"^config section 'ppo' must be of type PPOConfig, got dict .*with_values"):
        config.replace(ppo={"n_steps": 128})
    with pytest.raises(CanterError, match=r"^config section 'ppo' must be of type PPOConfig, got TD3Config"):
        config.replace(ppo=config.td3)
    with pytest.raises(CanterError, match=r"^config section 'env' must be of type EnvConfig, got RunConfig"):
        config.replace(env=config.run)


def test_unknown_keys_and_sections_of_with_values_are_one_line_errors(config: Config) -> None:
    with pytest.raises(CanterError, match=r"^config section 'run' has no key 'sed'; did you mean run\.seed\?$"):
        config.with_values("run", sed=1)
    with pytest.raises(CanterError, match=r"^config has no section 'rn'; did you mean run\?$"):
        config.with_values("rn", seed=1)


def test_a_config_built_the_usual_way_is_left_as_it_is(config: Config) -> None:
    # the check must not copy, or change, a config whose values the TOML path already typed
    again = dataclasses.replace(config)
    assert again == config
    assert all(again.section(name) is config.section(name) for name in ("env", "run", "ppo", "net", "sac"))


def test_sets_given_as_one_string_is_refused_with_the_fix() -> None:
    with pytest.raises(CanterError, match=r"takes a list of \"section\.key=value\" strings.*pass \['ppo\.clip=0\.1'\]"):
        canter.build_config("Pendulum-v1", sets="ppo.clip=0.1")  # type: ignore[arg-type]


def test_a_set_entry_that_is_not_text_is_refused() -> None:
    with pytest.raises(
        CanterError, match=r"^--set \(sets= from Python\) expects section\.key=value text, got 1 \(int\)$"
    ):
        canter.build_config("Pendulum-v1", sets=[1])  # type: ignore[list-item]
