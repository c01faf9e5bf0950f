"""`canter.build_config` is called from Python as well as by the CLI: each of its refusals is one line that names the
argument a Python caller passes (`preset=`, `sets=`, ...), not only the flag."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

import canter
from canter.errors import CanterError


def refusal(**given: Any) -> str:
    with pytest.raises(CanterError) as caught:
        canter.build_config(**{"env_id": "Hopper-v5", "notes": False, **given})
    message = str(caught.value)
    assert "\n" not in message
    return message


@pytest.mark.parametrize(
    ("given", "names"),
    [
        ({"preset": ""}, ["--preset", "preset="]),
        ({"algo": ""}, ["--algo", "algo="]),
        ({"config_file": ""}, ["--config", "config_file="]),
        ({"env_id": None}, ["canter train Hopper-v5", 'build_config("Hopper-v5")']),
        ({"sets": ["run.preset=cleanrl"]}, ["--preset cleanrl", "preset='cleanrl'", "sets="]),
        ({"seed": 1, "sets": ["run.seed=2"]}, ["--seed", "seed=", "sets="]),
        ({"total_steps": 1000, "sets": ["run.total_steps=2000"]}, ["--total-steps", "total_steps=", "sets="]),
        ({"algo": "sac", "sets": ["run.algo=ppo"]}, ["--algo", "algo=", "sets="]),
        ({"sets": ["env.id=Pendulum-v1"]}, ["env_id=", "sets="]),
        ({"sets": [1]}, ["--set", "sets="]),
        ({"sets": ["ppo.clip"]}, ["--set", "sets="]),
        ({"preset": "report002-ddpg", "algo": "ppo"}, ["--algo ddpg", "algo='ddpg'", "--preset", "preset="]),
    ],
)
def test_a_refusal_names_the_python_argument_after_the_flag(given: dict[str, Any], names: list[str]) -> None:
    message = refusal(**given)
    for name in names:
        assert name in message, message
    assert message.index(names[0]) < message.index(names[-1])  # the CLI's form first, as the CLI's tests read it


@pytest.mark.parametrize("path", ["folder", "/dev/null"])
def test_a_config_path_of_the_wrong_kind_names_config_file(path: str, tmp_path: Path) -> None:
    message = refusal(config_file=str(tmp_path) if path == "folder" else path)
    assert "--config (config_file= from Python) takes a TOML file" in message


def test_a_config_file_s_other_preset_names_preset(tmp_path: Path) -> None:
    file = tmp_path / "c.toml"
    file.write_text('[run]\npreset = "cleanrl"\n')
    message = refusal(preset="fast", config_file=file)
    assert "pass --preset cleanrl (preset='cleanrl' from Python), or drop run.preset from the file" in message


def test_a_preset_the_file_names_that_excludes_the_algorithm_names_algo_and_preset(tmp_path: Path) -> None:
    file = tmp_path / "c.toml"
    file.write_text('[run]\npreset = "report002-ddpg"\n')
    message = refusal(config_file=str(file), algo="ppo")
    assert "e.g. --algo ddpg (algo='ddpg' from Python)" in message
    assert "e.g. --preset fast (preset='fast' from Python)" in message


@pytest.mark.parametrize(
    ("sets", "shown"),
    [
        ({"ppo.clip": 0.1}, "got a dict; pass a string per key, such as ['ppo.clip=...']"),
        ("ppo.clip=0.1", "got the string 'ppo.clip=0.1'; pass ['ppo.clip=0.1']"),
    ],
)
def test_sets_that_is_no_list_is_refused_naming_sets(sets: object, shown: str) -> None:
    message = refusal(sets=sets)
    assert message.startswith('sets= takes a list of "section.key=value" strings, ') and message.endswith(shown)


def test_a_config_file_that_is_no_path_is_refused_naming_config_file() -> None:
    assert refusal(config_file=5) == "config_file= must be a path (str or Path), got int"


def test_a_config_file_may_be_a_path(tmp_path: Path) -> None:
    file = tmp_path / "c.toml"
    file.write_text("[ppo]\nclip = 0.1\n")
    assert canter.build_config("Hopper-v5", config_file=file, notes=False).ppo.clip == 0.1


def test_a_key_only_a_command_s_flag_gives_names_no_python_argument() -> None:
    # `flags` is the CLI's own: there is no Python argument to name
    message = refusal(flags={"run.max_minutes": 3}, sets=["run.max_minutes=4"])
    assert message == "run.max_minutes is given twice, by --max-minutes and by --set run.max_minutes; give it once"
