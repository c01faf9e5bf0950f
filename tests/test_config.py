import dataclasses

import pytest

from canter.config.build import build_config
from canter.config.overrides import all_keys, apply_overrides
from canter.config.presets import preset_names
from canter.config.reference import docs_table
from canter.config.schema import Config
from canter.config.serialize import from_toml_text, to_toml
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
    toml.write_text("[ppo]\nclip = 0.3\nlr = 1e-4\n[net]\nhidden = [32, 32]\n")
    config = build_config(
        "Hopper-v5",
        preset="cleanrl",
        config_file=str(toml),
        sets=["ppo.clip=0.1", "net.hidden=128,64", "ppo.target_kl=0.02"],
        seed=3,
        total_steps=2_000_000,
    )
    assert config.ppo.clip == 0.1  # --set beats the file
    assert config.ppo.lr == 1e-4  # the file beats the preset
    assert config.net.hidden == (128, 64)
    assert config.ppo.target_kl == 0.02
    assert config.run.seed == 3 and config.run.total_steps == 2_000_000
    assert config.env.num_envs == 1  # the preset beats the defaults


def test_a_key_set_by_a_flag_and_by_set_is_refused_naming_both():
    """The flag would win silently; each flag is named as the user typed it."""
    config = build_config("Hopper-v5", flags={"env.backend": "gymnasium", "run.eval_every": 5000}, seed=4)
    assert config.env.backend == "gymnasium" and config.run.eval_every == 5000 and config.run.seed == 4
    cases = [
        (
            {"sets": ["env.backend=envpool"], "flags": {"env.backend": "gymnasium"}},
            "env.backend is given twice, by --backend and by --set env.backend",
        ),
        (
            {"sets": ["run.eval_every=7"], "flags": {"run.eval_every": 5000}},
            "run.eval_every is given twice, by --eval-every and",
        ),
        ({"sets": ["run.seed=7"], "seed": 0}, r"run.seed is given twice, by --seed \(or --seeds\) and"),
        ({"sets": ["run.algo=sac"], "algo": "ppo"}, r"run.algo is given twice, by --algo \(or --algos\) and"),
    ]
    for kwargs, message in cases:
        with pytest.raises(CanterError, match=message):
            build_config("Hopper-v5", **kwargs)


def test_strings_with_quotes_backslashes_and_control_characters_survive_the_round_trip():
    for folder in ['runs/"quoted"', "C:\\runs", "line\nbreak", "tab\there", "bell\x07", "ünïcode"]:
        config = build_config("Hopper-v5", sets=[]).with_values("run", out_dir=folder)
        assert from_toml_text(to_toml(config), "test").run.out_dir == folder


def test_the_algorithm_asked_for_is_the_one_the_preset_and_the_checks_see():
    """A report's preset names its algorithm; --algo overrides it, and the checks follow --algo, not the preset."""
    assert build_config("HumanoidStandup-v4", preset="report000-humanoidstandup").run.algo == "rpo"
    config = build_config("HumanoidStandup-v4", preset="report000-humanoidstandup", algo="ppo")
    assert config.run.algo == "ppo" and config.run.preset == "report000-humanoidstandup"
    with pytest.raises(CanterError, match=r"rpo.alpha has no effect on ppo"):  # checked against the preset's rpo before
        build_config("HumanoidStandup-v4", preset="report000-humanoidstandup", algo="ppo", sets=["rpo.alpha=0.3"])
    with pytest.raises(CanterError, match=r"preset report002-ddpg holds settings for ddpg only, not sac"):
        build_config("BipedalWalker-v3", preset="report002-ddpg", algo="sac", sets=["sac.tau=0.01"])


def test_toml_round_trip_preserves_everything():
    config = build_config("Walker2d-v5", sets=["ppo.critic_lr=1e-3", "run.stop_at_return=300", "net.hidden=8"])
    again = from_toml_text(to_toml(config), "test")
    assert again == config
    nones = build_config("Walker2d-v5")
    assert from_toml_text(to_toml(nones), "test") == nones


def test_the_divisor_a_refusal_offers_is_the_largest_one_found_by_trying_each():
    from canter.algos.ppo.sections import largest_divisor

    for batch in range(1, 400):
        for at_most in (1, 2, 7, 64, 100, batch, batch + 5):
            tried = max(d for d in range(1, min(batch, at_most) + 1) if batch % d == 0)
            assert largest_divisor(batch, at_most) == tried
    # A batch of a billion answers at once (trying each number up to it took minutes).
    assert largest_divisor(1_000_000_000, 999_999_999) == 500_000_000
    assert largest_divisor(2 * 999_999_937, 999_999_000) == 2  # 999,999,937 is prime


@pytest.mark.parametrize(
    "sets, message",
    [
        (["ppo.clipp=0.1"], "unknown config key 'ppo.clipp'"),
        (["ppo.clip=abc"], "ppo.clip: expected a number"),
        (["env.num_envs=1.5"], "env.num_envs: expected an integer"),
        (["net.hidden=a,b"], "net.hidden: expected comma-separated integers"),
        (["run.tensorboard=maybe"], "run.tensorboard: expected true or false"),
        (["ppo.lr=0"], "ppo.lr must be > 0"),
        (["ppo.lr=-1e-4"], "ppo.lr must be > 0"),
        (
            ["ppo.minibatch_size=100"],
            "does not divide the batch 2048 (ppo.n_steps 128 x env.num_envs 16); pick a divisor",
        ),
        (["ppo.minibatch_size=100"], "pick a divisor, e.g. --set ppo.minibatch_size=64"),
        (["ppo.gamma=1.5"], "ppo.gamma must be in (0, 1]"),
        (["env.normalize_reward=false", "env.reward_scale=0"], "env.reward_scale must be a positive number, got 0"),
        (["env.normalize_reward=false", "env.reward_scale=inf"], "env.reward_scale must be a finite number, got inf"),
        (["env.reward_scale=0.1"], "set env.normalize_reward=false or env.reward_scale=1"),
        (["run.stop_at_return=nan"], "run.stop_at_return must be a finite number or none, got nan"),
        (["net.hidden=-64,-64"], "net.hidden: layer sizes must be positive integers, such as 64,64, got '-64,-64'"),
        (["run.seed=4294967296"], "run.seed must be from 0 to 4294967295, got 4294967296"),
        (["run.seed=-1"], "run.seed must be from 0 to 4294967295, got -1"),
        (["run.stop_at_return=inf"], "run.stop_at_return must be a finite number or none, got inf"),
        (["nosection"], "--set (sets= from Python) expects section.key=value"),
        (["bogus.key=1"], "unknown config key 'bogus.key'"),
    ],
)
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
    with pytest.raises(CanterError, match=r"unknown config key 'ppo.clip_range'.*did you mean ppo.clip"):
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
    config = apply_overrides(
        Config(),
        {"ppo.epochs": "4", "env.normalize_obs": "false", "ppo.target_kl": "none", "run.total_steps": "1e6"},
        "test",
    )
    assert config.ppo.epochs == 4 and config.env.normalize_obs is False and config.ppo.target_kl is None
    assert config.run.total_steps == 1_000_000


def _preset_keys(name, env_id, algo):
    """A preset's keys for the env and algorithm, its layers merged as build_config lays them."""
    from canter.config.presets import preset_layers

    return {key: value for _, layer in preset_layers(name, env_id, algo) for key, value in layer.items()}


def test_preset_layers_env_then_algo():
    import tomllib

    from canter.config.presets import preset_layer

    table = tomllib.loads("""
[env]
num_envs = 16
[env_overrides."Hopper*".ppo]
lr = 1e-4
[env_overrides."Hopper*".env]
num_envs = 2
""")
    assert preset_layer(table, "Hopper-v5", "t") == {"env.num_envs": 2, "ppo.lr": 1e-4}
    assert preset_layer(table, "Walker2d-v5", "t") == {"env.num_envs": 16}
    # An algorithm's own table for a preset (its folder's presets.toml) lies over the preset file.
    assert _preset_keys("fast", "Hopper-v5", "ppo")["ppo.minibatch_size"] == 64
    assert _preset_keys("fast", "Hopper-v5", "trpo")["ppo.minibatch_size"] == 512
    assert _preset_keys("fast", "Hopper-v5", "rpo")["rpo.alpha"] == 0.1
    assert _preset_keys("fast", "Ant-v5", "rpo")["rpo.alpha"] == 0.01
    assert _preset_keys("fast", "Hopper-v5", "td3")["env.num_envs"] == 1
    assert _preset_keys("fast", "Hopper-v5", "ppo")["env.num_envs"] == 16


def test_a_preset_that_extends_another_lays_its_keys_over_the_others(monkeypatch):
    """`extends` puts the base preset's file and its algorithm tables first, then the preset's own file, and passes
    on the base's `algos` unless the preset names its own; a loop of presets is refused in one line."""
    from canter.config import presets
    from canter.errors import CanterError

    extra = {
        "child": 'extends = "fast"\n[ppo]\nlr = 1e-4\nminibatch_size = 128\n',
        "grandchild": 'extends = "child"\nalgos = ["ppo"]\n[env]\nnum_envs = 4\n',
        "strict": 'algos = ["td3"]\n[env]\nnum_envs = 3\n',
        "heir": 'extends = "strict"\n',
        "loop-a": 'extends = "loop-b"\n',
        "loop-b": 'extends = "loop-a"\n',
    }
    shipped = presets.shipped_preset_text
    monkeypatch.setattr(presets, "shipped_preset_text", lambda name: extra.get(name) or shipped(name))

    child = _preset_keys("child", "Hopper-v5", "ppo")
    # The child's minibatch wins over fast's ppo table for Hopper; fast's env layer stays.
    assert (child["ppo.minibatch_size"], child["ppo.lr"], child["env.num_envs"]) == (128, 1e-4, 16)
    assert _preset_keys("child", "Hopper-v5", "td3")["env.num_envs"] == 1
    # The whole chain, base first: fast's layer, then the child's, then the grandchild's own.
    grandchild = _preset_keys("grandchild", "Hopper-v5", "ppo")
    assert (grandchild["net.log_std_init"], grandchild["ppo.lr"], grandchild["env.num_envs"]) == (-1.0, 1e-4, 4)
    with pytest.raises(CanterError, match="preset grandchild holds settings for ppo only, not td3"):
        _preset_keys("grandchild", "Hopper-v5", "td3")
    with pytest.raises(CanterError, match="preset heir holds settings for td3 only, not ppo"):
        _preset_keys("heir", "Hopper-v5", "ppo")
    with pytest.raises(CanterError, match=r"preset loop-a extends itself \(loop-a -> loop-b -> loop-a\)"):
        _preset_keys("loop-a", "Hopper-v5", "ppo")


@pytest.mark.parametrize(
    "sets, message",
    [
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
        (["sym.coef=0.1", "sym.groups=0=0"], "sym.groups pairs dimension 0 with itself, which adds nothing to the"),
        (["sym.coef=0.1", "sym.groups=0=0", "sym.negate=0", "sym.compare=log_prob"], "pairs dimension 0 with itself"),
    ],
)
def test_bad_onpolicy_variant_settings_are_refused(sets, message):
    with pytest.raises(CanterError) as info:
        build_config("Hopper-v5", sets=sets)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_a_dimension_mirrored_onto_its_own_negation_is_a_plane_of_symmetry():
    config = build_config("Hopper-v5", sets=["sym.coef=0.1", "sym.groups=0=0", "sym.negate=0"])
    assert config.sym.groups == "0=0" and config.sym.negate == (0,)
    assert build_config("Hopper-v5", sets=["sym.groups=0=0"]).sym.coef == 0  # with the loss off, groups are unread


def test_onpolicy_variant_keys_round_trip():
    config = build_config(
        "Hopper-v5",
        algo="rpo",
        sets=["sym.coef=0.02", "sym.groups=0:1=1:2", "sym.negate=1", "ppo.objective=kl_penalty", "rpo.alpha=0.01"],
    )
    assert config.sym.negate == (1,) and from_toml_text(to_toml(config), "test") == config


@pytest.mark.parametrize(
    "algo, key, fix",
    [
        ("sac", "td3.noise=ou", "set sac.noise instead"),
        ("td3", "net.hidden=64,64", "set td3.hidden instead"),
        ("trpo", "ppo.lr=1e-3", "drop it (ppo.lr is read by ppo, rpo)"),
        ("ppo", "trpo.max_kl=0.02", "drop it (trpo.max_kl is read by trpo)"),
        ("ppo", "rpo.alpha=0.1", "drop it (rpo.alpha is read by rpo)"),
    ],
)
def test_a_set_key_the_algorithm_ignores_is_refused(algo, key, fix):
    with pytest.raises(CanterError) as info:
        build_config("Hopper-v5", sets=[key], algo=algo)
    message = str(info.value)
    assert message.startswith(f"{key.split('=')[0]} has no effect on {algo}, which reads ") and message.endswith(fix)


def test_a_config_files_key_is_checked_against_the_algorithm_that_trains(tmp_path):
    """--algo replaces a config file's run.algo: the file's ppo.lr has no effect on td3, whatever the file names."""
    config_file = tmp_path / "ppo.toml"
    config_file.write_text('[run]\nalgo = "ppo"\n\n[ppo]\nlr = 0.001\n')
    with pytest.raises(CanterError) as info:
        build_config("Hopper-v5", config_file=str(config_file), algo="td3")
    assert str(info.value).startswith("ppo.lr has no effect on td3, which reads ")
    assert build_config("Hopper-v5", config_file=str(config_file)).ppo.lr == 0.001  # the file's own algorithm


def test_keys_an_algorithm_reads_are_accepted():
    assert build_config("Hopper-v5", sets=["ppo.gamma=0.98", "net.hidden=32,32"], algo="trpo").ppo.gamma == 0.98
    assert build_config("Hopper-v5", sets=["td3.tau=0.01", "env.normalize_obs=true"], algo="td3").td3.tau == 0.01
    assert build_config("Hopper-v5", sets=["sym.coef=0"], algo="rpo").sym.coef == 0


def test_any_ppo_n_steps_works_for_trpo_or_names_the_trpo_key():
    # The batch 100 x 16 = 1600: ppo's minibatch (512) is not read by trpo, so it does not matter; trpo's own
    # critic minibatch (128) does not divide it, and the error names that key and a divisor that works.
    with pytest.raises(
        CanterError,
        match=r"^trpo.critic_minibatch_size 128 does not divide the batch 1600 .*"
        r"--set trpo.critic_minibatch_size=100$",
    ):
        build_config("Hopper-v5", algo="trpo", sets=["ppo.n_steps=100"])
    config = build_config("Hopper-v5", algo="trpo", sets=["ppo.n_steps=100", "trpo.critic_minibatch_size=100"])
    assert config.ppo.n_steps == 100
    with pytest.raises(CanterError, match=r"^ppo.minibatch_size has no effect on trpo"):
        build_config("Hopper-v5", algo="trpo", sets=["ppo.n_steps=100", "ppo.minibatch_size=160"])
    for n_steps in (1, 7, 64, 100, 333, 2048):
        try:
            build_config("Hopper-v5", algo="trpo", sets=[f"ppo.n_steps={n_steps}"])
        except CanterError as exc:
            assert str(exc).startswith("trpo.critic_minibatch_size"), exc


def test_config_toml_holds_env_run_and_what_the_algorithm_reads():
    sac = to_toml(build_config("Hopper-v5", algo="sac"))
    assert "[sac]" in sac and "[env]" in sac and "[run]" in sac
    assert not any(f"[{s}]" in sac for s in ("ppo", "net", "td3", "ddpg", "trpo", "rpo", "sym"))
    trpo = to_toml(build_config("Hopper-v5", algo="trpo"))
    ppo_table = trpo.split("[ppo]\n")[1].split("\n\n")[0].splitlines()
    assert [line.split(" = ")[0] for line in ppo_table] == ["n_steps", "gamma", "gae_lambda", "norm_adv"]
    from canter.config.experiment import flat_config

    assert flat_config(from_toml_text(sac, "sac")) == flat_config(build_config("Hopper-v5", algo="sac"))


def test_experiment_key_ignores_seed_budget_and_output_keys_only():
    from canter.config.experiment import (
        differing_keys,
        experiment_key,
        group_by_experiment,
    )

    base = build_config("Hopper-v5")
    same = [
        base.with_values("run", **{key: value})
        for key, value in (
            ("seed", 7),
            ("total_steps", 5),
            ("max_minutes", 3.0),
            ("stop_at_return", 10.0),
            ("out_dir", "x"),
            ("preset", "cleanrl"),
            ("video_every", 1000),
            ("tensorboard", False),
            ("checkpoint_every", 1),
            ("keep_checkpoints", 9),
            ("compress_checkpoints", True),
        )
    ]
    same.append(base.with_values("env", envpool_shards=2))
    assert all(experiment_key(c) == experiment_key(base) for c in same)
    different = [
        base.with_values("ppo", lr=1e-3),
        base.with_values("env", num_envs=8),
        base.with_values("env", backend="gymnasium"),
        base.with_values("run", algo="rpo"),
    ]
    assert all(experiment_key(c) != experiment_key(base) for c in different)
    assert group_by_experiment([base, same[0], different[0], same[5]]) == [[0, 1, 3], [2]]
    assert differing_keys([base, different[0]]) == ["ppo.lr"]
    # Keys the algorithm does not read never count: a changed sac default cannot split ppo runs.
    assert experiment_key(base.with_values("sac", tau=0.5)) == experiment_key(base)


def test_old_report_preset_names_still_work_with_a_notice(capsys):
    old = build_config("HumanoidStandup-v4", preset="seed000-humanoidstandup")
    assert old == build_config("HumanoidStandup-v4", preset="report000-humanoidstandup")
    assert "preset seed000-humanoidstandup is now called report000-humanoidstandup" in capsys.readouterr().err
    assert old.run.preset == "report000-humanoidstandup"
