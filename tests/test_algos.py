import pytest

from canter.algos import algorithm_names, check_algorithm_name, get_algorithm
from canter.cli.main import main
from canter.config.build import build_config
from canter.errors import CanterError


def test_every_registered_algorithm_has_a_complete_record():
    for name in algorithm_names():
        algorithm = get_algorithm(name)
        assert algorithm.name == name and algorithm.metric_names


def test_unknown_algorithm_lists_the_valid_ones(capsys):
    with pytest.raises(CanterError, match="choose one of: ppo"):
        check_algorithm_name("ppx")
    with pytest.raises(CanterError, match="unknown algorithm 'nope'"):
        build_config("Hopper-v5", algo="nope")
    assert main(["train", "Hopper-v5", "--algo", "nope", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown algorithm 'nope'" in err


def test_continuous_only_algorithms_name_themselves_for_discrete_actions(tmp_path):
    from canter.training.loop import train

    for algo in ("rpo", "trpo"):
        config = build_config("CartPole-v1", algo=algo, sets=[f"run.out_dir={tmp_path}", "env.num_envs=4"])
        with pytest.raises(CanterError, match=f"{algo} is continuous-only, but CartPole-v1 has discrete actions"):
            train(config)
    assert not any(tmp_path.iterdir())


def test_env_dependent_checks_happen_before_any_work(tmp_path):
    from canter.training.loop import train

    config = build_config(
        "Hopper-v4",
        algo="rpo",
        sets=[f"run.out_dir={tmp_path}", "env.num_envs=4", "sym.coef=0.02", "sym.groups=3:7=7:11,11:14=14:17"],
    )
    with pytest.raises(CanterError, match=r"sym.groups: index 16 is out of the action range 0..2 .*\(rpo\)"):
        train(config)
    with pytest.raises(CanterError, match=r"sym.coef has no effect on trpo, .*drop it"):
        build_config("Hopper-v4", algo="trpo", sets=["sym.coef=0.02", "sym.groups=0=1"])
    # A config file is checked the same way (a run's saved config.toml holds only the keys its algorithm reads).
    with_sym = tmp_path / "sym.toml"
    with_sym.write_text('[sym]\ncoef = 0.02\ngroups = "0=1"\n')
    with pytest.raises(CanterError, match=r"sym.coef has no effect on trpo, .*drop it"):
        build_config("Hopper-v4", algo="trpo", config_file=str(with_sym))
    assert list(tmp_path.iterdir()) == [with_sym]


def test_an_algorithm_that_relabels_another_ones_plot_column_is_refused():
    """Plot labels are one namespace (a plot titles a column once for all its runs): a new algorithm giving ppo's
    grad_norm another title would silently retitle ppo's plots, so its registration is refused."""
    import dataclasses

    from canter.config.algorithms import algorithm_spec, all_plot_labels, register_algorithm

    ppo = algorithm_spec("ppo")
    assert "grad_norm" in ppo.plot_labels
    before = all_plot_labels()
    relabelled = dataclasses.replace(ppo, name="a2c", plot_labels={"grad_norm": ("Gradient norm", "L2")})
    with pytest.raises(ValueError, match=r"algorithm 'a2c' labels the metrics column 'grad_norm'"):
        register_algorithm(relabelled)
    assert all_plot_labels() == before
    with pytest.raises(CanterError, match=r"unknown algorithm 'a2c'"):
        algorithm_spec("a2c")


@pytest.mark.parametrize("reads", [("net", "td3x"), ("td3", "ppo.norm_advantage")])
def test_an_algorithm_reading_no_such_section_or_key_is_refused_at_registration(reads):
    import dataclasses

    from canter.config.algorithms import algorithm_spec, register_algorithm

    typo = dataclasses.replace(algorithm_spec("td3"), name="td3typo", reads=reads)
    with pytest.raises(ValueError, match=r"algorithm 'td3typo' reads '.*', which is no registered config section"):
        register_algorithm(typo)


def test_every_algorithm_section_is_read_by_an_algorithm():
    """A section no algorithm lists in `reads` is left out of config.toml, and its keys are refused as read by none."""
    from canter.config.algorithms import algorithm_names, algorithm_spec
    from canter.config.schema import CORE_SECTIONS, section_names

    read = {entry.split(".")[0] for name in algorithm_names() for entry in algorithm_spec(name).reads}
    assert set(section_names()) - set(CORE_SECTIONS) - read == set()


@pytest.mark.parametrize(
    "table, message",
    [
        ({"ppo": {"n_step": 8}}, r"unknown config key 'ppo\.n_step' in ppo's table \[ppo\.fast\] for preset fast"),
        ({"ppo": {"n_steps": "eight"}}, r"\(in ppo's table \[ppo\.fast\] for preset fast \(its presets\.toml\)\)"),
    ],
)
def test_a_bad_key_in_an_algorithms_preset_table_names_that_table(monkeypatch, table, message):
    """An algorithm's table for a preset lives in its own folder, not in the preset file, so its errors name it."""
    import dataclasses

    from canter.config import algorithms

    ppo = algorithms.algorithm_spec("ppo")
    monkeypatch.setitem(algorithms._REGISTERED, "ppo", dataclasses.replace(ppo, preset_overrides={"fast": table}))
    with pytest.raises(CanterError, match=message):
        build_config("Hopper-v5", algo="ppo", preset="fast")


def test_a_runtime_record_keyed_by_another_name_is_refused_before_a_run_folder_is_made(monkeypatch, tmp_path):
    """`ALGORITHMS = {"PPO": ...}` in the runtime module: one line that names the dict and its keys, and no
    half-made run folder."""
    import dataclasses
    import sys
    import types

    from canter.config import algorithms
    from canter.training.loop import train

    runtime = types.ModuleType("misfiled_runtime")
    runtime.ALGORITHMS = {"PPO": get_algorithm("ppo")}  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "misfiled_runtime", runtime)
    ppo = algorithms.algorithm_spec("ppo")
    monkeypatch.setitem(algorithms._REGISTERED, "ppo", dataclasses.replace(ppo, runtime="misfiled_runtime"))
    config = build_config("InvertedPendulum-v4", sets=[f"run.out_dir={tmp_path}", "env.num_envs=4"])
    message = r"misfiled_runtime\.ALGORITHMS has no 'ppo' \(it has 'PPO'\); key its Algorithm record by"
    with pytest.raises(CanterError, match=message):
        train(config)
    assert not any(tmp_path.iterdir())
