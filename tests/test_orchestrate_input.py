"""Bad input to canter tune and canter bench, refused in one line before any trial or cell trains: search spaces over
keys the command sets itself, a --set that a sampled or gridded value would replace, a run folder as a bench's
--out, a study name with a path in it, an env with discrete actions; and the words of a failure once a job ran."""

from pathlib import Path

import optuna
import pytest

from canter.cli.main import main
from canter.errors import CanterError
from canter.orchestrate.bench import failures_text
from canter.orchestrate.bench_folder import refuse_run_or_study_folder
from canter.orchestrate.bench_grid import BenchSettings, make_cells
from canter.orchestrate.jobs import JOB_START, exit_text, failure_reason
from canter.orchestrate.search_space import parse_space
from canter.orchestrate.tune import (
    STUDY_KEYS,
    TuneSettings,
    check_settings,
    check_study_settings,
    fixed_keys,
    owned_keys,
    seeds_text,
)

ENV = "InvertedPendulum-v5"


def _tune(tmp_path: Path, space: str | None = None, **kwargs) -> TuneSettings:
    if space is not None:
        (tmp_path / "space.toml").write_text(space)
        kwargs["space_file"] = str(tmp_path / "space.toml")
    return TuneSettings(env_id=ENV, total_steps=4096, out_dir=str(tmp_path / "tune"), **kwargs)


def _bench(**kwargs) -> BenchSettings:
    return BenchSettings(**{"algos": ("ppo",), "envs": (ENV,), "seeds": (0,), "total_steps": 4096, **kwargs})


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


# ------------------------------------------------------------------------------------------------ search spaces


@pytest.mark.parametrize("key", sorted(STUDY_KEYS | owned_keys(TuneSettings(env_id=ENV), Path()).keys()))
def test_a_space_cannot_search_a_key_tune_sets(key):
    """A sampled env.id trained another env inside the study; a sampled run.out_dir was overridden, yet shown in the
    results as the trial's value."""
    section, _, name = key.partition(".")
    with pytest.raises(CanterError) as refused:
        parse_space({section: {name: {"choices": ["x", "y"]}}}, "space.toml", fixed_keys(TuneSettings(env_id=ENV)))
    assert str(refused.value).startswith(f"space.toml: [{key}] cannot be searched: it is set by tune")
    assert str(refused.value).endswith("; drop it from the space")


def test_tune_refuses_a_space_file_that_searches_the_env_or_the_budget(tmp_path):
    for space, message in [
        ('[env.id]\nchoices = ["Hopper-v5"]\n', "[env.id] cannot be searched: it is set by tune's ENV argument"),
        ("[run.total_steps]\nchoices = [2048, 100000000]\n", "[run.total_steps] cannot be searched: it is set by "),
        ('[run.algo]\nchoices = ["td3"]\n', "[run.algo] cannot be searched: it is set by tune's --algo"),
    ]:
        with pytest.raises(CanterError) as refused:
            check_settings(_tune(tmp_path, space))
        assert str(refused.value).startswith(f"{tmp_path / 'space.toml'}: {message}"), refused.value


@pytest.mark.parametrize(
    "data, message",
    [
        ({"ppo": {"epochs": {"low": 1.5, "high": 10}}}, "ppo.epochs: expected an integer, got 1.5"),
        ({"ppo": {"lr": {"choices": [float("nan")]}}}, "ppo.lr must be a finite number, got nan"),
        ({"ppo": {"lr": {"low": float("nan"), "high": 1.0}}}, "ppo.lr must be a finite number, got nan"),
        ({"ppo": {"epochs": {"low": 1, "high": 2**31 + 5}}}, "ppo.epochs must be below 2,147,483,648"),
        (
            {"net": {"hidden": {"choices": ["abc"]}}},
            "net.hidden: expected comma-separated integers (or joined by dashes, 64-64), got 'abc'",
        ),
        ({"ppo": {"norm_adv": {"low": 0, "high": 1}}}, "ppo.norm_adv: expected true or false, got 0"),
        ({"ppo": {"lr": {"same_as": "ppo.norm_adv"}, "norm_adv": {"choices": [True]}}}, "ppo.lr: expected a number"),
    ],
)
def test_a_bad_value_in_a_space_file_names_the_file(data, message):
    with pytest.raises(CanterError) as refused:
        parse_space(data, "space.toml")
    assert str(refused.value).startswith(f"space.toml: {message}"), refused.value


# ----------------------------------------------------------------------------------- a --set that would be dropped


def test_tune_refuses_a_set_of_a_key_its_space_samples(tmp_path):
    """The shipped ppo space samples ppo.clip: the trials trained the sampled clip, not the --set one."""
    with pytest.raises(CanterError) as refused:
        check_settings(_tune(tmp_path, sets=("ppo.clip=0.3",)))
    assert str(refused.value) == (
        "ppo.clip is given by --set and sampled by the search space too (the shipped ppo search space); drop "
        "--set ppo.clip to search it, or drop [ppo.clip] from the space to fix its value"
    )
    check_settings(_tune(tmp_path, "[ppo.lr]\nlow = 1e-4\nhigh = 1e-2\n", sets=("ppo.clip=0.3",)))


@pytest.mark.parametrize("key, grid", [("ppo.clip", ("0.1",)), ("env.id", (ENV,))])
def test_bench_refuses_a_set_of_a_key_its_grid_gives(key, grid):
    with pytest.raises(CanterError, match=rf"^{key} is given by both --grid and --set; keep --grid {key}=\.\.\. or"):
        make_cells(_bench(grid=((key, grid),), sets=(f"{key}=0.2",)))


def test_bench_takes_the_last_of_a_set_key_given_twice():
    (cell,) = make_cells(_bench(sets=("ppo.clip=0.1", "ppo.clip=0.2")))
    assert cell.config.ppo.clip == 0.2


# -------------------------------------------------------------------------------------------- where things go


def test_bench_refuses_a_run_folder_as_its_out_folder(tmp_path, capsys):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    with pytest.raises(CanterError, match=r"is a run folder \(it holds checkpoints/\), not a bench folder; give a"):
        refuse_run_or_study_folder(run)
    (run / "config.toml").write_text("[run]\n")
    (run / ".writer.lock").write_text("the run's own\n")
    before = sorted(p.name for p in run.iterdir())
    argv = ["bench", "--envs", ENV, "--seeds", "0", "--total-steps", "4096", "--episodes", "1", "--out", str(run)]
    assert main(argv) == 2
    err = _one_line_error(capsys)
    assert f"--out {run} is a run folder (it holds config.toml and checkpoints/)" in err
    assert sorted(p.name for p in run.iterdir()) == before and (run / ".writer.lock").read_text() == "the run's own\n"
    refuse_run_or_study_folder(tmp_path / "new")  # a folder to make, or a bench folder, is what --out takes
    refuse_run_or_study_folder(tmp_path)
    own = tmp_path / "own"  # a folder holding the user's base config for the bench is no run folder
    own.mkdir()
    (own / "config.toml").write_text("[ppo]\nclip = 0.1\n")
    refuse_run_or_study_folder(own)
    (own / "metrics.csv").write_text("global_step\n")
    with pytest.raises(CanterError, match=r"it holds config.toml and metrics.csv\)"):
        refuse_run_or_study_folder(own)
    archive = tmp_path / "archive"  # a finished run kept without its checkpoints, its metrics packed
    archive.mkdir()
    (archive / "config.toml").write_text("[run]\n")
    (archive / "metrics.csv.gz").write_bytes(b"")
    with pytest.raises(CanterError, match=r"it holds config.toml and metrics.csv.gz\)"):
        refuse_run_or_study_folder(archive)


@pytest.mark.parametrize("name", ["../../etc", "a/b", "/tmp/x", ".", "..", "", "a\\b", "x\ny"])
def test_a_study_name_must_be_a_plain_name(tmp_path, capsys, name):
    with pytest.raises(CanterError, match=r"is not a plain name; give one without '/', "):
        TuneSettings(env_id=ENV, study_name=name)
    assert main(["tune", ENV, "--study", name, "--out-dir", str(tmp_path / "t")]) == 2
    assert "is not a plain name" in _one_line_error(capsys)
    assert not (tmp_path / "t").exists()


@pytest.mark.parametrize("name", ["hopper-ppo_2.b", "hopper lr sweep", "ppo+sym", "exp=3", "études"])
def test_a_plain_study_name_is_a_folder_of_the_out_dir(name):
    """Any name without a path in it: studies made before names were checked must still resume."""
    assert TuneSettings(env_id=ENV, study_name=name).study_dir == Path("tune") / name


# ---------------------------------------------------------------------------------- an env no job can train


def test_an_env_with_discrete_actions_is_refused_before_any_job(tmp_path):
    message = r"^canter's algorithms are continuous-only, but CartPole-v1 has discrete actions \(Discrete\(2\)\)"
    with pytest.raises(CanterError, match=message):
        make_cells(_bench(envs=("CartPole-v1",)))
    with pytest.raises(CanterError, match=message):
        check_settings(TuneSettings(env_id="CartPole-v1", out_dir=str(tmp_path)))
    make_cells(_bench(envs=("Pendulum-v1",), sets=("env.backend=gymnasium",)))  # a continuous one on that backend


# ------------------------------------------------------------------------------------------ what a failure says


def test_a_bench_does_not_advise_a_retry_that_fails_the_same_way():
    refused = "training process failed (exit 2): canter: error: CartPole-v1 has discrete actions; choose another env"
    crashed = "training process failed (exit 1): RuntimeError: oops"
    text = failures_text({"a": crashed, "b": refused}, 3)
    assert text == f"2 of 3 cells failed ({refused}); do what it says, then re-run: a retry alone fails the same way"
    assert "retry them" not in text
    assert failures_text({"a": crashed}, 3) == f"1 of 3 cells failed ({crashed}); re-run the same command to retry them"


def test_a_killed_job_is_probably_out_of_memory_and_jax_s_trailer_is_no_reason(tmp_path):
    assert exit_text(-9) == "killed by signal 9 (SIGKILL, probably out of memory)"
    assert exit_text(-15) == "killed by signal 15 (SIGTERM)"
    (tmp_path / "train.log").write_text(
        f"{JOB_START} 2026-11-29 07:00:00\n"
        "Traceback (most recent call last):\n"
        "TypeError: add got incompatible shapes for broadcasting: (3,), (4,).\n"
        "--------------------\n"
        "For simplicity, JAX has removed its internal frames from the traceback of the following exception. Set "
        "JAX_TRACEBACK_FILTERING=off to include these.\n"
    )
    assert failure_reason(tmp_path, 1) == (
        "training process failed (exit 1): TypeError: add got incompatible shapes for broadcasting: (3,), (4,)."
    )


# ------------------------------------------------------------------------------------------------ seed lists


def test_seed_lists_are_short_in_messages(tmp_path):
    assert seeds_text(tuple(range(100000))) == "0-99999"
    assert seeds_text((0, 1)) == "0, 1"
    assert seeds_text((3, 5, 8, 13, 21, 34, 55)) == "3, 5, 8, 13, 21, ... (7 seeds)"
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(direction="maximize", study_name="s")
    name = "seeds (--seed, --seeds-per-trial)"
    check_study_settings(study, {name: ",".join(map(str, range(100000)))}, tmp_path / "trials")
    study.add_trial(optuna.trial.create_trial(value=1.0))  # a finished trial: other settings are refused
    with pytest.raises(CanterError) as refused:
        check_study_settings(study, {name: "0"}, tmp_path / "trials")
    assert str(refused.value) == (
        f"study 's' was run with {name} 0-99999, but this command gives 0; its trials would not compare: use the "
        f"same settings, or a new --study"
    )
