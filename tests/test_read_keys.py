"""Every key a config holds is read by something, and each list of choices is declared once."""

import ast
import dataclasses
import inspect

import pytest

from canter import build_config
from canter.config.schema import section_names, section_type
from canter.config.serialize import from_toml_text, to_toml
from canter.core import networks
from canter.core.netconfig import ACTIVATION_CHOICES, ACTIVATIONS
from canter.errors import CanterError
from canter.use import export


def _numpy_forward_activations() -> set[str]:
    """The names of the table inside `numpy_forward`, which stands alone (the docs quote it) and so keeps its own."""
    tree = ast.parse(inspect.getsource(export.numpy_forward))
    tables = [node for node in ast.walk(tree) if isinstance(node, ast.Dict)]
    assert len(tables) == 1
    return {ast.literal_eval(key) for key in tables[0].keys}


def test_every_activation_map_covers_exactly_the_configs_names():
    assert set(networks.ACTIVATION_FUNCTIONS) == set(ACTIVATIONS)
    assert set(export.ONNX_ACTIVATIONS) == set(ACTIVATIONS)
    assert _numpy_forward_activations() == set(ACTIVATIONS)


@pytest.mark.parametrize("algo, key", [("ppo", "net.activation"), ("td3", "td3.activation"), ("sac", "sac.activation")])
def test_an_unknown_activation_is_refused_naming_every_choice(algo, key):
    with pytest.raises(CanterError) as info:
        build_config("Hopper-v5", algo=algo, sets=[f"{key}=swish"])
    assert str(info.value) == f"{key} must be {ACTIVATION_CHOICES}, got 'swish'"
    assert all(name in ACTIVATION_CHOICES for name in ACTIVATIONS)


def test_every_activation_key_documents_the_same_choices():
    docs = {
        section: field.metadata["doc"]
        for section in section_names()
        for field in dataclasses.fields(section_type(section))
        if field.name == "activation"
    }
    assert {"net", "td3", "ddpg", "sac"} <= set(docs)
    assert all(doc == f"Hidden activation: {ACTIVATION_CHOICES}." for doc in docs.values()), docs


@pytest.mark.parametrize("key", ["noise_std", "ou_theta", "ou_dt"])
def test_sac_refuses_the_exploration_noise_keys_it_never_reads(key, tmp_path):
    """They would change nothing but split sac's runs into different experiments."""
    with pytest.raises(CanterError, match=rf"sac.{key} has no effect on sac \(it explores by sampling its policy\)"):
        build_config("Hopper-v5", algo="sac", sets=[f"sac.{key}=0.7"])
    config = build_config("Hopper-v5", algo="sac")
    assert config.sac.noise_std == 0.1
    # A run's config.toml gives every key of its section: it is still a config file to start from.
    path = tmp_path / "config.toml"
    path.write_text(to_toml(config))
    assert build_config("Hopper-v5", algo="sac", config_file=str(path)) == config


def test_a_sac_run_folder_that_set_a_noise_key_still_loads():
    """Folders written before the refusal hold such values; eval, export, report and --resume read them."""
    config = build_config("Hopper-v5", algo="sac")
    old = config.replace(sac=dataclasses.replace(config.sac, noise_std=0.2, ou_theta=3.0))
    assert from_toml_text(to_toml(old), "config.toml").sac.noise_std == 0.2
