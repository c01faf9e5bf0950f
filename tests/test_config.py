import dataclasses

import pytest

from canter.config.schema import (Config, all_keys, apply_overrides, build_config, docs_table, from_toml_text,
                           preset_names, to_toml)
from canter.errors import CanterError


def test_config_is_frozen_and_every_key_addressable():
    config = Config()
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.ppo.lr = 1.0
    for key in all_keys():
        section, name = key.split(".")
        assert hasattr(getattr(config, section), name)


def test_precedence_defaults_preset_file_set_flags(tmp_path):
    base = build_config("Hopper-v5", preset="cleanrl")
    assert base.env.num_envs == 1 and base.ppo.n_steps == 2048 and base.run.preset == "cleanrl"
    toml = tmp_path / "c.toml"
    toml.write_text('[ppo]\nclip = 0.3\nlr = 1e-4\n[net]\nhidden = [32, 32]\n')
    config = build_config("Hopper-v5", preset="cleanrl", config_file=str(toml),
                          sets=["ppo.clip=0.1", "net.hidden=128,64", "ppo.target_kl=0.02"], seed=3,
                          total_steps=2_000_000)
    assert config.ppo.clip == 0.1            # --set beats the file
    assert config.ppo.lr == 1e-4             # the file beats the preset
    assert config.net.hidden == (128, 64)
    assert config.ppo.target_kl == 0.02
    assert config.run.seed == 3 and config.run.total_steps == 2_000_000
    assert config.env.num_envs == 1          # the preset beats the defaults


def test_toml_round_trip_preserves_everything():
    config = build_config("Walker2d-v5", sets=["ppo.critic_lr=1e-3", "run.stop_at_return=300", "net.hidden=8"])
    again = from_toml_text(to_toml(config), "test")
    assert again == config
    nones = build_config("Walker2d-v5")
    assert from_toml_text(to_toml(nones), "test") == nones


@pytest.mark.parametrize("sets, message", [
    (["ppo.clipp=0.1"], "unknown config key 'ppo.clipp'"),
    (["ppo.clip=abc"], "ppo.clip: expected a number"),
    (["env.num_envs=1.5"], "env.num_envs: expected an integer"),
    (["net.hidden=a,b"], "net.hidden: expected comma-separated integers"),
    (["run.tensorboard=maybe"], "run.tensorboard: expected true or false"),
    (["ppo.lr=0"], "ppo.lr must be > 0"),
    (["ppo.lr=-1e-4"], "ppo.lr must be > 0"),
    (["ppo.minibatch_size=100"], "does not divide the batch"),
    (["ppo.gamma=1.5"], "ppo.gamma must be in (0, 1]"),
    (["nosection"], "--set expects section.key=value"),
    (["bogus.key=1"], "unknown config key 'bogus.key'"),
])
def test_bad_overrides_are_one_line_errors(sets, message):
    with pytest.raises(CanterError) as info:
        build_config("Hopper-v5", sets=sets)
    assert message in str(info.value)
    assert "\n" not in str(info.value)


def test_bad_files(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[ppo\nclip = ")
    with pytest.raises(CanterError, match="malformed TOML"):
        build_config("Hopper-v5", config_file=str(bad))
    unknown = tmp_path / "unknown.toml"
    unknown.write_text("[ppo]\nclip_range = 0.2\n")
    with pytest.raises(CanterError, match="unknown config key 'ppo.clip_range'.*did you mean ppo.clip"):
        build_config("Hopper-v5", config_file=str(unknown))
    with pytest.raises(CanterError, match="config file not found"):
        build_config("Hopper-v5", config_file=str(tmp_path / "missing.toml"))
    with pytest.raises(CanterError, match="unknown preset"):
        build_config("Hopper-v5", preset="nope")


def test_presets_ship_and_docs_cover_every_key():
    assert {"cleanrl", "fast"} <= set(preset_names())
    table = docs_table()
    for key in all_keys():
        assert f"`{key}`" in table


def test_apply_overrides_coerces_types():
    config = apply_overrides(Config(), {"ppo.epochs": "4", "env.normalize_obs": "false", "ppo.target_kl": "none",
                                        "run.total_steps": "1e6"}, "test")
    assert config.ppo.epochs == 4 and config.env.normalize_obs is False and config.ppo.target_kl is None
    assert config.run.total_steps == 1_000_000


def test_preset_layers_env_then_algo(tmp_path, monkeypatch):
    import tomllib

    from canter.config.schema import _preset_layer

    table = tomllib.loads("""
[env]
num_envs = 16
[env_overrides."Hopper*".ppo]
lr = 1e-4
[algo_overrides.td3.env]
num_envs = 1
[algo_overrides.td3.env_overrides."Hopper*".env]
num_envs = 2
""")
    assert _preset_layer(table, "Hopper-v5", "ppo", "t") == {"env.num_envs": 16, "ppo.lr": 1e-4}
    assert _preset_layer(table, "Hopper-v5", "td3", "t") == {"env.num_envs": 2, "ppo.lr": 1e-4}
    assert _preset_layer(table, "Walker2d-v5", "td3", "t") == {"env.num_envs": 1}


@pytest.mark.parametrize("sets, message", [
    (["run.algo=trpo", "trpo.max_kl=0"], "trpo.max_kl must be > 0"),
    (["run.algo=trpo", "trpo.max_kl=-0.1"], "trpo.max_kl must be > 0"),
    (["run.algo=trpo", "trpo.cg_iters=0"], "trpo.cg_iters must be >= 1"),
    (["run.algo=trpo", "trpo.cg_damping=-1"], "trpo.cg_damping must be >= 0"),
    (["run.algo=trpo", "trpo.line_search_shrink=1"], "trpo.line_search_shrink must be in (0, 1)"),
    (["run.algo=trpo", "trpo.critic_minibatch_size=100"], "trpo.critic_minibatch_size 100 does not divide"),
    (["run.algo=rpo", "rpo.alpha=-0.1"], "rpo.alpha must be >= 0"),
    (["ppo.objective=kl"], "ppo.objective must be clip or kl_penalty"),
    (["ppo.kl_penalty_target=0"], "ppo.kl_penalty_target must be > 0"),
    (["sym.coef=-1"], "sym.coef must be >= 0"),
    (["sym.coef=0.1"], "sym.coef > 0 needs sym.groups"),
    (["sym.groups=3:7=7:10"], "pairs 4 with 3 dimensions"),
    (["sym.groups=0:2=2:4", "sym.negate=1"], "sym.negate: indices [1]"),
    (["sym.compare=std"], "sym.compare must be mean or log_prob"),
])
def test_bad_onpolicy_variant_settings_are_refused(sets, message):
    with pytest.raises(CanterError) as info:
        build_config("Hopper-v5", sets=sets)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_onpolicy_variant_keys_round_trip():
    config = build_config("Hopper-v5", algo="rpo", sets=["sym.coef=0.02", "sym.groups=0:1=1:2", "sym.negate=1",
                                                         "ppo.objective=kl_penalty", "rpo.alpha=0.01"])
    assert config.sym.negate == (1,) and from_toml_text(to_toml(config), "test") == config


@pytest.mark.parametrize("algo, key, fix", [
    ("sac", "td3.noise=ou", "set sac.noise instead"),
    ("td3", "net.hidden=64,64", "set td3.hidden instead"),
    ("trpo", "ppo.lr=1e-3", "drop it (ppo.lr is read by ppo, rpo)"),
    ("ppo", "trpo.max_kl=0.02", "drop it (trpo.max_kl is read by trpo)"),
    ("ppo", "rpo.alpha=0.1", "drop it (rpo.alpha is read by rpo)"),
])
def test_a_set_key_the_algorithm_ignores_is_refused(algo, key, fix):
    with pytest.raises(CanterError) as info:
        build_config("Hopper-v5", sets=[key], algo=algo)
    message = str(info.value)
    assert message.startswith(f"{key.split('=')[0]} has no effect on {algo}, which reads ") and message.endswith(fix)


def test_keys_an_algorithm_reads_are_accepted():
    assert build_config("Hopper-v5", sets=["ppo.gamma=0.98", "net.hidden=32,32"], algo="trpo").ppo.gamma == 0.98
    assert build_config("Hopper-v5", sets=["td3.tau=0.01", "env.normalize_obs=true"], algo="td3").td3.tau == 0.01
    assert build_config("Hopper-v5", sets=["sym.coef=0"], algo="rpo").sym.coef == 0
