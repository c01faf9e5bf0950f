"""Robustness sweeps: spec parsing, model edits checked against hand-computed values, and the CLI outputs."""

import json
import shutil
import warnings

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from canter.cli.main import main
from canter.errors import CanterError
from canter.use.vary import (
    VarySpec,
    apply_scale,
    counting_instabilities,
    object_names,
    original_value,
    parse_spec,
    sweep,
)


def hopper():
    env = gym.make("Hopper-v5")
    return env, env.unwrapped.model, env.unwrapped.data


def subtree_masses(model) -> np.ndarray:
    """Reference: each body's own mass plus its descendants', from the parent table."""
    total = np.array(model.body_mass, copy=True)
    for body in range(model.nbody - 1, 0, -1):  # children come after their parents in MuJoCo's body order
        total[model.body_parentid[body]] += total[body]
    return total


def test_parse_spec():
    assert parse_spec("body_mass:torso=0.5,1,1.5") == VarySpec("body_mass", "torso", (0.5, 1.0, 1.5))
    assert parse_spec("gravity=2") == VarySpec("gravity", None, (2.0,))
    assert parse_spec("geom_friction=0.5").name is None
    assert parse_spec("body_mass:torso=0.5,1").slug == "body_mass_torso"
    for bad, message in [
        ("body_mass:torso", "expected PARAM"),
        ("mass:torso=1", "valid: body_mass"),
        ("body_mass:torso=1,x", "not a number"),
        ("body_mass:torso=0", "> 0"),
        ("body_mass:torso=nan", "> 0"),
        ("gravity:z=1", "takes no name"),
        ("body_mass=1,0.5,1.0", "scale 1.0 is given twice"),
    ]:
        with pytest.raises(CanterError, match=message):
            parse_spec(bad)


def test_body_mass_scaling_changes_mass_and_recomputes_dependent_quantities():
    env, model, data = hopper()
    torso = object_names(model, "body").index("torso")
    mass = model.body_mass.copy()
    inertia_weight = model.body_invweight0.copy()
    apply_scale(model, data, parse_spec("body_mass:torso=1.5"), 1.5)
    expected = mass.copy()
    expected[torso] *= 1.5
    np.testing.assert_allclose(model.body_mass, expected)
    np.testing.assert_allclose(model.body_subtreemass, subtree_masses(model))
    assert model.body_subtreemass[0] == pytest.approx(mass.sum() + 0.5 * mass[torso])
    # mj_setConst also recomputed the inverse inertia weights at qpos0: a heavier torso is harder to accelerate.
    assert model.body_invweight0[torso, 0] < inertia_weight[torso, 0]
    env.close()


def test_stale_subtree_mass_is_what_mj_setconst_fixes():
    """Guards the test above: editing body_mass alone leaves body_subtreemass stale."""
    env, model, data = hopper()
    model.body_mass[1] *= 2.0
    assert not np.allclose(model.body_subtreemass, subtree_masses(model))
    mujoco.mj_setConst(model, data)
    np.testing.assert_allclose(model.body_subtreemass, subtree_masses(model))
    env.close()


@pytest.mark.parametrize(
    "text, read, row",
    [
        (
            "geom_friction:foot_geom=0.5",
            lambda m: m.geom_friction,
            lambda m: object_names(m, "geom").index("foot_geom"),
        ),
        ("actuator_gear:thigh_joint=0.5", lambda m: m.actuator_gear, lambda m: 0),
        ("gravity=0.5", lambda m: m.opt.gravity, lambda m: slice(None)),
        ("body_mass=0.5", lambda m: m.body_mass, lambda m: slice(None)),
    ],
)
def test_other_parameters_scale_only_their_target(text, read, row):
    env, model, data = hopper()
    before = np.array(read(model), copy=True)
    apply_scale(model, data, parse_spec(text), 0.5)
    expected = before.copy()
    expected[row(model)] *= 0.5
    np.testing.assert_allclose(read(model), expected)
    assert not np.allclose(read(model), before)
    env.close()


def test_unknown_name_lists_the_valid_names():
    env, model, _ = hopper()
    with pytest.raises(CanterError, match=r"valid body names: world, torso, thigh, leg, foot$"):
        original_value(model, parse_spec("body_mass:torsoo=1"))
    with pytest.raises(CanterError, match="valid actuator names: thigh_joint, leg_joint, foot_joint"):
        original_value(model, parse_spec("actuator_gear:hip=1"))
    env.close()


def test_instability_warnings_are_counted_not_printed(capfd):
    """Gravity 1e30 makes MuJoCo reset the state mid-episode and warn; the warnings are counted, not passed to the
    handler before (which dm_control, once imported, sets), and that handler is back afterwards."""
    env, model, data = hopper()
    env.reset(seed=0)
    apply_scale(model, data, parse_spec("gravity=1e30"), 1e30)
    before = mujoco.get_mju_user_warning()
    seen: list[str] = []
    mujoco.set_mju_user_warning(seen.append)
    try:
        with counting_instabilities() as unstable:
            for _ in range(3):
                mujoco.mj_step(model, data)
        counted = len(unstable)
        assert counted >= 3 and all("unstable" in text for text in unstable) and seen == []
        mujoco.mj_step(model, data)
        assert seen and len(unstable) == counted  # the handler from before is back
    finally:
        mujoco.set_mju_user_warning(before)
    assert "Nan, Inf or huge value" not in "".join(capfd.readouterr())
    env.close()


@pytest.mark.slow
def test_cli_vary_marks_diverged_physics_unstable(tiny_hopper_run, tmp_path, capfd):
    """MuJoCo's resets of diverged physics earn returns of 1e37; such a point says so instead of showing them."""
    code = main(
        ["eval", str(tiny_hopper_run), "--episodes", "2", "--vary", "gravity=1e30,1", "--out", str(tmp_path / "g.png")]
    )
    out, err = capfd.readouterr()
    assert code == 0, err
    assert "Nan, Inf or huge value" not in out + err
    rows = [line for line in out.splitlines() if line.startswith("ppo/")]
    assert "1e+30 unstable: MuJoCo warned of diverged physics" in rows[0] and "±" not in rows[0], out
    assert "unstable" not in rows[1] and "±" in rows[1], out
    points = json.loads((tmp_path / "g.json").read_text())["runs"][0]["points"]
    assert points[0]["unstable_warnings"] > 0 and points[1]["unstable_warnings"] == 0


@pytest.mark.slow
def test_each_scale_starts_from_the_original_model(tiny_hopper_run):
    """A repeated scale gives the same result: the second 2.0 is not applied to an already doubled mass."""
    from canter.use.policy import load

    policy = load(tiny_hopper_run)
    points = sweep(policy, VarySpec("body_mass", "torso", (2.0, 2.0, 1.0)), episodes=2, deterministic=True, seed=0)
    assert points[0]["returns"] == points[1]["returns"]
    assert points[0]["value"] == pytest.approx(2 * points[2]["value"])
    assert points[0]["returns"] != points[2]["returns"]


@pytest.mark.slow
def test_cli_vary_writes_table_json_and_plot(tiny_hopper_run, tmp_path, capsys):
    run = tiny_hopper_run
    code = main(["eval", str(run), "--episodes", "2", "--vary", "body_mass:torso=0.5,1.5"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "0.5" in out and "1.5" in out and "±" in out
    report = json.loads((run / "robustness" / "body_mass_torso.json").read_text())
    png = (run / "robustness" / "body_mass_torso.png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 10_000
    points = report["runs"][0]["points"]
    assert [p["scale"] for p in points] == [0.5, 1.5] and all(len(p["returns"]) == 2 for p in points)
    assert points[0]["return_mean"] == pytest.approx(np.mean(points[0]["returns"]))
    assert points[1]["value"] == pytest.approx(3 * points[0]["value"]) == pytest.approx(1.5 * report["original"])
    # A sweep on another env is named after it, beside the sweep of the run's own env, which it leaves as it was (in
    # a copy: the report tests read the shared run's sweeps).
    copy = shutil.copytree(run, tmp_path / "copy")
    code = main(["eval", str(copy), "--env", "Hopper-v4", "--episodes", "1", "--vary", "body_mass:torso=0.5,1.5"])
    assert code == 0, capsys.readouterr().err
    assert json.loads((copy / "robustness" / "Hopper-v4_body_mass_torso.json").read_text())["env"] == "Hopper-v4"
    assert (copy / "robustness" / "body_mass_torso.png").read_bytes() == png
    # Two runs (here one and its copy) on one plot, written where --out says.
    twin = shutil.copytree(run, tmp_path / "twin")
    code = main(
        ["eval", str(run), str(twin), "--episodes", "1", "--vary", "gravity=0.9", "--out", str(tmp_path / "g.png")]
    )
    assert code == 0
    assert f"wrote {tmp_path / 'g.png'} and {tmp_path / 'g.json'}" in capsys.readouterr().out
    assert len(json.loads((tmp_path / "g.json").read_text())["runs"]) == 2
    assert (tmp_path / "g.png").stat().st_size > 10_000


@pytest.mark.slow
def test_cli_vary_bad_inputs(tiny_hopper_run, tmp_path, capsys):
    blocked = tmp_path / "file"
    blocked.write_text("")
    for argv, message in [
        (["--vary", "body_mass:torsoo=0.5"], "valid body names: world, torso"),
        (["--vary", "body_mass:torso=0.5", "--out", str(blocked / "x.png")], "cannot write"),
        (["--vary", "body_mass:torso=0.5", "--out", str(tmp_path / "x.svg")], "PNG"),
        (["--out", str(tmp_path / "x.png")], "without --vary"),
        (["--vary", "body_mass:torso=0.5", "--vary", "gravity=0.9"], "one parameter per command"),
    ]:
        code = main(["eval", str(tiny_hopper_run), "--episodes", "1"] + argv)
        _out, err = capsys.readouterr()
        assert code != 0 and message in err and err.count("\n") == 1, (argv, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]  # nothing partial left behind


def test_varying_an_env_gymnasium_lacks_names_the_backend_that_has_it():
    """A DM Control env is EnvPool's alone, and --vary edits Gymnasium's MuJoCo models."""
    from canter.errors import CanterError
    from canter.use.vary import check_spec, parse_spec

    with pytest.raises(CanterError) as refused:
        check_spec("CheetahRun-v1", parse_spec("gravity=0.5,1"))
    assert str(refused.value) == (
        "--vary edits the MuJoCo model of CheetahRun-v1 in Gymnasium, which has no such env (only EnvPool has it); "
        "drop --vary, which varies only Gymnasium's envs"
    )


def test_an_overflowing_observation_of_diverged_physics_prints_no_numpy_warning(archived_run, tmp_path, capfd):
    """InvertedPendulum's observation is its raw state, which a diverged model pushes past float32's range."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        argv = [
            "eval",
            str(archived_run),
            "--episodes",
            "1",
            "--vary",
            "gravity=1e30",
            "--out",
            str(tmp_path / "g.png"),
        ]
        assert main(argv) == 0
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], [str(w.message) for w in caught]
    assert "unstable: MuJoCo warned of diverged physics" in capfd.readouterr().out
