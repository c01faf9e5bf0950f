"""Every shipped preset builds a valid config for its env, checked against the real env's spec."""

from importlib import resources

import pytest

from canter.algos import algorithm_names, get_algorithm
from canter.config.build import build_config
from canter.config.presets import (
    preset_envs,
    preset_layers,
    preset_names,
    shipped_preset_text,
)
from canter.envs import make_vec_env
from canter.errors import CanterError

# Presets without an `# env:` header line are general; they are checked on the seeds' tasks.
GENERAL_ENVS = (
    "HalfCheetah-v4",
    "Hopper-v4",
    "Walker2d-v4",
    "Humanoid-v4",
    "HumanoidStandup-v4",
    "Ant-v4",
    "BipedalWalker-v3",
)


def envs_to_check(name: str) -> tuple[str, ...]:
    return preset_envs(name) or GENERAL_ENVS


_specs: dict[str, object] = {}


def spec_of(env_id: str):
    if env_id not in _specs:
        _specs[env_id] = _brax_spec(env_id) if env_id.islower() else _auto_spec(env_id)
    return _specs[env_id]


def _auto_spec(env_id: str):
    env = make_vec_env(env_id, "auto", 1, [0])
    env.close()
    return env.spec


def _brax_spec(env_id: str):
    """Brax's envs (lower-case names, which `auto` never picks): the spec from one env's shapes, without compiling
    a vectorized reset."""
    from canter.envs.base import EnvSpec
    from canter.envs.registry import get_backend

    brax = get_backend("brax")
    if not brax.available():
        pytest.skip("brax is not installed here")
    from canter.envs.brax.env import functional_env

    env = functional_env(env_id)
    return EnvSpec(
        env_id, brax.name, 1, env.obs_dim, env.act_dim, env.action_low, env.action_high, env.max_episode_steps, ()
    )


# Brax's envs load their models through MJX to give their shapes: seconds each on the CPU.
@pytest.mark.parametrize(
    "name", [pytest.param(name, marks=pytest.mark.slow) if name == "brax" else name for name in preset_names()]
)
def test_preset_builds_a_valid_config_for_its_envs(name):
    assert resources.files("canter.presets").joinpath(f"{name}.toml").read_text().startswith("#"), (
        "a preset starts with a comment header that gives its source"
    )
    for env_id in envs_to_check(name):
        built = []
        for algo in algorithm_names():
            try:
                config = build_config(env_id, preset=name, algo=algo)
            except CanterError as exc:  # a preset that names the algorithms it holds settings for refuses the rest
                assert f"preset {name} holds settings for" in str(exc), exc
                continue
            get_algorithm(algo).validate(config, spec_of(env_id))
            built.append(algo)
        assert built, f"preset {name} builds no algorithm's config for {env_id}"


def test_seed_presets_hold_the_seeds_numbers():
    standup = build_config("HumanoidStandup-v4", preset="report000-humanoidstandup")
    assert standup.run.algo == "rpo" and standup.run.total_steps == 5_000_000
    assert (standup.ppo.n_steps, standup.ppo.minibatch_size, standup.ppo.lr, standup.ppo.ent_coef) == (
        2048,
        64,
        2e-5,
        1e-4,
    )
    assert standup.rpo.alpha == 0.5 and standup.sym.coef == 0.02 and standup.sym.groups == "3:7=7:11,11:14=14:17"
    cheetah = build_config("HalfCheetah-v4", preset="report000-halfcheetah")
    assert cheetah.ppo.ent_coef == 0.5 and cheetah.run.seed == 8 and cheetah.ppo.minibatch_size == 32
    assert "contradicts" in shipped_preset_text("report000-halfcheetah")
    hopper = build_config("Hopper-v4", preset="report002-hopper-trpo")
    assert hopper.run.algo == "trpo" and hopper.net.activation == "relu" and hopper.net.hidden == (64, 64)
    assert (hopper.trpo.critic_lr, hopper.trpo.cg_iters, hopper.trpo.cg_damping) == (2e-4, 10, 0.1)
    walker = build_config("BipedalWalker-v3", preset="report002-bipedalwalker-ppo")
    assert (walker.ppo.n_steps, walker.ppo.minibatch_size, walker.ppo.epochs, walker.env.num_envs) == (512, 32, 5, 4)
    assert (walker.ppo.gamma, walker.ppo.gae_lambda, walker.run.stop_at_return) == (0.99, 0.99, 300.0)
    dmc = build_config("WalkerWalk-v1", preset="report004-walker")
    assert (dmc.ppo.n_steps, dmc.ppo.minibatch_size, dmc.ppo.epochs, dmc.env.num_envs) == (1000, 1000, 80, 1)
    assert (dmc.ppo.lr, dmc.ppo.critic_lr, dmc.ppo.target_kl, dmc.run.total_steps) == (3e-4, 1e-3, 0.015, 750_000)
    assert dmc.net.activation == "tanh" and not dmc.env.normalize_obs and not dmc.ppo.anneal_lr


@pytest.mark.parametrize("preset", ["fast", "cleanrl"])
def test_rpo_alpha_is_small_where_0_5_collapses(preset):
    for env_id in ("Ant-v4", "InvertedDoublePendulum-v4", "Reacher-v4", "Pusher-v4"):
        assert build_config(env_id, preset=preset, algo="rpo").rpo.alpha == 0.01
    assert build_config("Hopper-v4", preset=preset, algo="rpo").rpo.alpha == {"fast": 0.1, "cleanrl": 0.5}[preset]
    assert build_config("Ant-v4", preset=preset, algo="ppo").rpo.alpha == 0.5  # only rpo's table


def test_humanoidstandup_mirror_groups_and_signs_match_the_model():
    """The preset pairs right/left actuators by name, and negates exactly the left joints whose axis makes the same
    torque produce the un-mirrored motion (checked on the model: a rotation axis mirrors as a pseudovector)."""
    import os

    import gymnasium
    import mujoco
    import numpy as np

    from canter.algos.ppo.symmetry import parse_groups

    xml = os.path.join(os.path.dirname(gymnasium.__file__), "envs/mujoco/assets/humanoidstandup.xml")
    model = mujoco.MjModel.from_xml_path(xml)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    config = build_config("HumanoidStandup-v4", preset="report000-humanoidstandup")
    reflect = np.diag([1.0, -1.0, 1.0])  # the sagittal plane is y = 0
    for pair in parse_groups(config.sym.groups, config.sym.negate):
        # The seed's pairs put the right limb first and the left limb as its mirror.
        for right, left, sign in zip(pair.first, pair.mirror, pair.signs):
            right_name, left_name = model.actuator(right).name, model.actuator(left).name
            assert right_name.startswith("right_") and left_name == "left_" + right_name[len("right_") :]
            axis_r = data.xaxis[model.actuator(right).trnid[0]]
            axis_l = data.xaxis[model.actuator(left).trnid[0]]
            np.testing.assert_allclose(axis_l, sign * -(reflect @ axis_r), atol=1e-6)
            assert model.actuator(right).gear[0] == model.actuator(left).gear[0]


def test_fast_preset_uses_small_minibatches_for_ppo_and_rpo_on_hopper_and_walker2d_only():
    def picked(env_id, algo):
        config = build_config(env_id, algo=algo)
        return config.ppo.minibatch_size, config.net.log_std_init

    assert picked("Hopper-v5", "ppo") == (64, -1.0)
    assert picked("Hopper-v4", "ppo") == (64, -1.0)
    assert picked("Walker2d-v5", "ppo") == (64, 0.0)
    assert picked("HalfCheetah-v5", "ppo") == (512, -1.0)
    assert picked("Hopper-v5", "rpo") == (64, -1.0)
    assert picked("Walker2d-v5", "rpo") == (64, 0.0)
    assert picked("HalfCheetah-v5", "rpo") == (512, -1.0)
    assert picked("Hopper-v5", "trpo")[1] == -1.0


def test_tianshou_preset_is_tianshous_example_settings_and_off_policy_only():
    """The settings the sac-tianshou Walker2d runs were made with (`--set` flags on top of `fast`) are exactly what
    `--preset tianshou` gives on every key sac reads, so those results can be regenerated either way."""
    import dataclasses

    from canter.errors import CanterError

    flags = ["sac.actor_lr=1e-3", "sac.autotune=false", "sac.alpha=0.2", "sac.learning_starts=10000"]
    run_config = build_config("Walker2d-v5", algo="sac", sets=flags)
    preset_config = build_config("Walker2d-v5", preset="tianshou", algo="sac")
    as_run = {s: dataclasses.asdict(run_config.section(s)) for s in ("env", "sac", "run")}
    preset = {s: dataclasses.asdict(preset_config.section(s)) for s in ("env", "sac", "run")}
    assert as_run["env"] == preset["env"]
    # alpha_lr is Tianshou's 3e-4 in the preset but is never read with a fixed alpha (autotune off).
    assert preset["sac"].pop("alpha_lr") == 3e-4 and not preset["sac"]["autotune"]
    as_run["sac"].pop("alpha_lr")
    assert as_run["sac"] == preset["sac"]
    assert {k: v for k, v in as_run["run"].items() if k != "preset"} == {
        k: v for k, v in preset["run"].items() if k != "preset"
    }
    ddpg = build_config("Hopper-v5", preset="tianshou", algo="ddpg").ddpg
    assert (ddpg.actor_lr, ddpg.critic_lr, ddpg.policy_delay, ddpg.learning_starts) == (1e-3, 1e-3, 1, 25_000)
    td3 = build_config("Hopper-v5", preset="tianshou", algo="td3").td3
    assert td3 == build_config("Hopper-v5", preset="cleanrl", algo="td3").td3
    with pytest.raises(
        CanterError,
        match=r"preset tianshou holds settings for sac, td3, ddpg only, not ppo; "
        r"train one of those algorithms with it, e.g. --algo sac \(algo='sac' from Python\)",
    ):
        build_config("Walker2d-v5", preset="tianshou")


def test_brax_preset_holds_brax_published_ppo_settings():
    """Brax's training notebook: ant 4096 envs, batch 2048 x 32 minibatches x unroll 5, 4 updates, entropy 1e-2;
    humanoid 2048 envs, batch 1024 x 32 x unroll 10, 8 updates, entropy 1e-3; both lr 3e-4, discount 0.97; reward
    scaling ant 10, humanoid 0.1."""
    published = {"ant": (4096, 2048, 5, 4, 1e-2, 10.0), "humanoid": (2048, 1024, 10, 8, 1e-3, 0.1)}
    for env_id, (num_envs, batch_size, unroll_length, updates, entropy_cost, reward_scaling) in published.items():
        config = build_config(env_id, preset="brax", sets=["env.backend=brax"])
        ppo = config.ppo
        assert config.env.num_envs == num_envs and ppo.epochs == updates and ppo.ent_coef == entropy_cost
        assert config.env.reward_scale == reward_scaling and not config.env.normalize_reward
        assert ppo.n_steps * num_envs == batch_size * 32 * unroll_length
        assert ppo.minibatch_size == batch_size * unroll_length
        assert (ppo.lr, ppo.gamma, ppo.gae_lambda, ppo.clip, ppo.anneal_lr) == (3e-4, 0.97, 0.95, 0.3, False)
        assert config.net.hidden == (32,) * 4 and config.net.critic_hidden == (256,) * 5


def test_humanoid_preset_is_the_recipe_the_humanoid_runs_measured():
    """The runs of benchmarks/gpu/humanoid_cpu/grad-norm.md trained the recipe as the brax preset plus the `--set`
    flags below (through an earlier `--preset humanoid` and `--set ppo.max_grad_norm=0.5`): both give exactly the
    same settings on every key ppo reads."""
    import dataclasses

    from canter.errors import CanterError

    flags = [
        "env.num_envs=2048",
        "ppo.n_steps=80",
        "ppo.minibatch_size=5120",
        "ppo.epochs=8",
        "ppo.ent_coef=1e-3",
        "env.reward_scale=0.1",
        "net.log_std_init=-0.916",
        "net.hidden=256,256,256",
        "ppo.max_grad_norm=0.5",
    ]
    measured = build_config("Humanoid-v5", preset="brax", sets=flags)
    shipped = build_config("Humanoid-v5", preset="humanoid")
    for section in ("env", "net", "ppo"):
        assert dataclasses.asdict(measured.section(section)) == dataclasses.asdict(shipped.section(section)), section
    assert shipped.run.preset == "humanoid" and shipped.run.total_steps == 10_000_000
    assert shipped.run.eval_every == 1_000_000
    with pytest.raises(CanterError, match=r"preset humanoid holds settings for ppo only, not sac"):
        build_config("Humanoid-v5", preset="humanoid", algo="sac")


def test_the_humanoid_recipe_is_the_same_on_braxs_humanoid_env():
    """The brax preset's table for Brax's own `humanoid` env must not reach through `extends` into the recipe."""

    def keys(env_id):  # the layers merged, later ones winning, as build_config lays them
        return {key: value for _, layer in preset_layers("humanoid", env_id) for key, value in layer.items()}

    assert keys("humanoid") == keys("Humanoid-v5")


def test_a_preset_made_for_other_envs_says_so_in_one_line(capsys):
    build_config("Humanoid-v5", preset="humanoid")
    build_config("Hopper-v5", preset="fast")
    assert capsys.readouterr().err == ""
    build_config("Ant-v5", preset="humanoid")
    assert capsys.readouterr().err == (
        "canter: note: preset humanoid was made for Humanoid-v5; its settings are untested on Ant-v5\n"
    )
    build_config("gymnasium:Walker2d-v4", preset="report002-hopper-trpo")
    assert "preset report002-hopper-trpo was made for Hopper-v4; its settings are untested on Walker2d-v4" in (
        capsys.readouterr().err
    )
    assert preset_envs("brax") == ("ant", "humanoid") and preset_envs("fast") == ()
