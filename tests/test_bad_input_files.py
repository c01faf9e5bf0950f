"""Bad input around files and settings: one line, a non-zero exit, and nothing of a run folder replaced."""

from __future__ import annotations

import gzip
import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from canter.cli.main import main
from canter.config.build import build_config
from canter.errors import CanterError
from conftest import ARCHIVED_RUN, error_line


def one_line(capsys, argv, expected):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("canter: error: ") and expected in err, err


def test_an_output_never_replaces_a_file_of_a_run_folder(archived_run, tmp_path, capsys):
    newest = sorted((archived_run / "checkpoints").iterdir())[-1]
    before = {p: p.read_bytes() for p in archived_run.rglob("*") if p.is_file()}
    one_line(capsys, ["export", str(archived_run), "--out", str(newest)], "checkpoints/ belongs to the run folder")
    one_line(
        capsys,
        ["eval", str(archived_run), "--json", str(archived_run / "config.toml")],
        "it is a file of the run folder",
    )
    # eval.json is bench's cached final evaluation, which plot and report score the run by.
    one_line(
        capsys, ["eval", str(archived_run), "--json", str(archived_run / "eval.json")], "it is a file of the run folder"
    )
    # A checkpoint given where its run folder belongs: the message says how to pick it.
    newest_path = sorted((archived_run / "checkpoints").iterdir())[-1]
    one_line(capsys, ["eval", str(newest_path)], "is a file, not a run folder; pass the run folder, and --checkpoint")
    one_line(
        capsys,
        ["report", str(archived_run), "--episodes", "0", "--out", str(archived_run / "metrics.csv")],
        "one HTML page",
    )
    assert {p: p.read_bytes() for p in archived_run.rglob("*") if p.is_file() and p.name != ".writer.lock"} == before
    # A new file beside them is an ordinary output.
    assert main(["export", str(archived_run), "--out", str(archived_run / "policy.npz")]) == 0


def test_an_output_that_is_a_link_pipe_or_device_is_refused(archived_run, tmp_path, capsys):
    pipe = tmp_path / "p.npz"
    os.mkfifo(pipe)
    one_line(
        capsys, ["export", str(archived_run), "--out", str(pipe)], "it is not a plain file (a link, pipe or device)"
    )
    link = tmp_path / "l.npz"
    link.symlink_to(tmp_path / "elsewhere.npz")
    one_line(capsys, ["export", str(archived_run), "--out", str(link)], "it is not a plain file")
    assert pipe.exists() and not pipe.is_file() and link.is_symlink()


def test_damaged_run_files_are_one_line_errors(archived_run, tmp_path, capsys):
    (archived_run / "versions.json").write_text(json.dumps({"run_format": 0}))
    one_line(
        capsys, ["train", "--resume", str(archived_run), "--total-steps", "9000"], "run_format 0, not a whole number"
    )
    (archived_run / "versions.json").write_text(json.dumps({"run_format": 1}))
    rows = (archived_run / "metrics.csv").read_bytes()
    (archived_run / "metrics.csv").unlink()
    (archived_run / "metrics.csv.gz").write_bytes(gzip.compress(rows)[:60])
    one_line(capsys, ["train", "--resume", str(archived_run), "--total-steps", "9000"], "is not a whole gzip file")
    (archived_run / "metrics.csv.gz").unlink()
    (archived_run / "metrics.csv").write_text("global_step,episodic_return\n1," + "9" * 200_000 + "\n")
    one_line(capsys, ["plot", str(archived_run), "--out", str(tmp_path / "a.png")], "metrics.csv is damaged")
    (archived_run / "metrics.csv").write_text("global_step\n1\n2\n")
    one_line(capsys, ["plot", str(archived_run), "--out", str(tmp_path / "a.png")], "no metric with values to plot")
    # NUL bytes in place of a line's end join two rows into one: refused, not read with a row lost.
    (archived_run / "metrics.csv").write_bytes(rows[:300] + b"\0" * 200 + rows[500:])
    line = rows[:300].count(b"\n") + 1
    for argv in (
        ["plot", str(archived_run), "--out", str(tmp_path / "a.png")],
        ["train", "--resume", str(archived_run), "--total-steps", "9000"],
    ):
        one_line(capsys, argv, f"metrics.csv is damaged (NUL bytes on line {line}); restore it from a copy, or move")
    lines = rows.splitlines(keepends=True)
    (archived_run / "metrics.csv").write_bytes(lines[0] + lines[1].rstrip() + b",7,8\r\n")
    one_line(capsys, ["plot", str(archived_run), "--out", str(tmp_path / "a.png")], "line 2 has more cells than")
    # A file zeroed whole: the one refusal, without the note that a resume logs on from its checkpoint.
    (archived_run / "metrics.csv").write_bytes(b"\0" * len(rows))
    one_line(
        capsys,
        ["train", "--resume", str(archived_run), "--total-steps", "9000"],
        "metrics.csv is damaged (NUL bytes on line 1)",
    )


def test_a_report_shows_damaged_summary_values_as_dashes_and_skips_dangling_links(archived_run, tmp_path):
    summary = json.loads((archived_run / "summary.json").read_text())
    (archived_run / "summary.json").write_text(json.dumps(summary | {"wall_seconds": float("nan"), "sps": 1e400}))
    (archived_run / "videos").mkdir()
    (archived_run / "videos" / "step_000000000001.mp4").symlink_to(tmp_path / "gone.mp4")
    (archived_run / "robustness").mkdir()
    (archived_run / "robustness" / "mass.png").symlink_to(tmp_path / "gone.png")
    assert main(["report", str(archived_run), "--episodes", "0", "--out", str(tmp_path / "r.html")]) == 0
    assert "gone" not in (tmp_path / "r.html").read_text()


@pytest.mark.parametrize(
    ("sets", "message"),
    [
        (["ppo.epochs=99999999999999999999"], "ppo.epochs must be below 2,147,483,648 in size"),
        (["env.num_envs=3000000000"], "env.num_envs must be below 2,147,483,648 in size"),
        (["net.log_std_init=nan"], "net.log_std_init must be a finite number, got nan"),
        (["ppo.ent_coef=inf"], "ppo.ent_coef must be a finite number, got inf"),
        (["run.preset=cleanrl"], "pass --preset cleanrl rather than --set run.preset"),
        # The learner computes in float32, where these would be inf and 0.
        (["ppo.lr=1e300"], "ppo.lr 1e+300 is beyond float32's range (1.18e-38 to 3.4e+38 in size)"),
        (["ppo.lr=1e-40"], "ppo.lr 1e-40 is beyond float32's range"),
        (["env.clip_obs=1e39"], "env.clip_obs 1e+39 is beyond float32's range"),
        (["run.algo=sac", "sac.tau=1e-39"], "sac.tau 1e-39 is beyond float32's range"),
    ],
)
def test_settings_out_of_range_are_refused_before_training(sets, message):
    with pytest.raises(CanterError, match=re.escape(message)):
        build_config("Hopper-v5", sets=sets)


def test_step_budgets_may_pass_int32_and_run_preset_may_repeat_the_preset():
    assert build_config("Hopper-v5", sets=["run.total_steps=5e9"]).run.total_steps == 5_000_000_000
    assert build_config("Hopper-v5", preset="cleanrl", sets=["run.preset=cleanrl"]).run.preset == "cleanrl"
    aliased = build_config("Hopper-v5", preset="seed002-ddpg", sets=["run.preset=seed002-ddpg"])
    assert aliased.run.preset == "report002-ddpg"


@pytest.mark.parametrize("url", ["sqlite://", "sqlite:///", "sqlite:///:memory:"])
def test_an_in_memory_study_storage_is_refused(url, tmp_path, capsys):
    argv = ["tune", "Hopper-v5", "--trials", "1", "--total-steps", "2048", "--storage", url]
    one_line(capsys, argv + ["--out-dir", str(tmp_path)], "an in-memory database, which the worker processes cannot")


def test_video_settings_the_renderer_cannot_take(archived_run, tmp_path, capsys, monkeypatch):
    out = str(tmp_path / "v.mp4")
    one_line(
        capsys, ["video", str(archived_run), "--out", out, "--height", "100000"], "--width and --height go up to 4096"
    )
    monkeypatch.setenv("MUJOCO_GL", "bogus")
    one_line(capsys, ["video", str(archived_run), "--out", out], "MUJOCO_GL=bogus is not one of MuJoCo's renderers")
    from canter.use.renderer import configure_gl

    for accepted in ("glx", "EGL", "cgl"):  # MuJoCo's own names, which it reads lower-cased
        monkeypatch.setenv("MUJOCO_GL", accepted)
        assert configure_gl() == accepted


def test_an_output_folder_that_cannot_be_made_is_one_line(tmp_path, capsys):
    (tmp_path / "file").write_text("")
    out = str(tmp_path / "file" / "b")
    argv = ["bench", "--envs", "Hopper-v5", "--seeds", "0", "--total-steps", "2048", "--out", out]
    one_line(capsys, argv, "cannot make the folder")


def test_an_export_to_a_folder_says_so_first(tmp_path, capsys):
    """A folder's name seldom tells a format: the fix is a file name inside it, whatever --format says."""
    for flags in ([], ["--format", "npz"]):
        one_line(capsys, ["export", str(ARCHIVED_RUN), "--out", str(tmp_path), *flags], "it is a folder; give a file")
    assert list(tmp_path.iterdir()) == []


def test_a_resume_of_a_file_or_of_a_folder_of_runs_names_what_to_pass(tmp_path, capsys):
    """As eval, plot and report say it: the folder that holds the file, or the run folders inside."""
    import shutil

    for name in ("a", "b"):
        shutil.copytree(ARCHIVED_RUN, tmp_path / name)
    checkpoint = sorted((tmp_path / "a" / "checkpoints").iterdir())[-1]
    for given in (tmp_path / "a" / "config.toml", checkpoint):
        one_line(capsys, ["train", "--resume", str(given)], "is a file, not a run folder; pass the run folder that")
    holds_two = "is not a run folder but holds 2 run folders (a bench's?): pass them"
    one_line(capsys, ["train", "--resume", str(tmp_path)], holds_two)


def test_a_jax_platform_this_machine_lacks_is_one_line():
    code = "import sys; from canter.cli.main import main; sys.exit(main(['eval', sys.argv[1], '--episodes', '1']))"
    env = dict(os.environ, JAX_PLATFORMS="cuda")
    done = subprocess.run([sys.executable, "-c", code, str(ARCHIVED_RUN)], capture_output=True, text=True, env=env)
    assert done.returncode == 2
    lines = [line for line in done.stderr.splitlines() if line.startswith("canter: error:")]
    assert len(lines) == 1 and "JAX_PLATFORMS=cuda" in lines[0] and "unset JAX_PLATFORMS" in lines[0], done.stderr


def test_a_folder_of_run_folders_names_the_glob_that_reaches_them(tmp_path, capsys):
    bench = tmp_path / "bench"
    shutil.copytree(ARCHIVED_RUN, bench / "Hopper-v5__ppo__s0")
    (bench / "results.md").write_text("")
    for argv in (
        ["eval", str(bench)],
        ["plot", str(bench), "--out", str(tmp_path / "a.png")],
        ["video", str(bench), "--out", str(tmp_path / "v.mp4")],
    ):
        message = (
            f"{bench} is not a run folder but holds 1 run folder (a bench's?): pass them, such as "
            f"{bench / 'Hopper-v5__ppo__s0'}"
        )
        one_line(capsys, argv, message)


def test_a_relative_mlflow_store_is_recorded_absolute(tmp_path, monkeypatch):
    from canter.training.trackers.mlflow_tracker import absolute_store

    monkeypatch.chdir(tmp_path)
    (tmp_path / "mlruns").mkdir()
    cases = {
        "sqlite:///mlflow.db": f"sqlite:///{tmp_path}/mlflow.db",
        "sqlite:///m.db?timeout=5": f"sqlite:///{tmp_path}/m.db?timeout=5",
        "sqlite:////abs/m.db": "sqlite:////abs/m.db",
        "sqlite:///:memory:": "sqlite:///:memory:",
        "sqlite:///": "sqlite:///",
        "file:./mlruns": f"file://{tmp_path}/mlruns",
        "./mlruns": f"{tmp_path}/mlruns",
        "mlruns": f"{tmp_path}/mlruns",
        "databricks": "databricks",
        "http://host:5000": "http://host:5000",
        "file:///abs/mlruns": "file:///abs/mlruns",
    }
    assert {uri: absolute_store(uri) for uri in cases} == cases


def test_an_off_policy_budget_within_learning_starts_is_noted():
    from canter.config.algorithms import warm_up_note

    assert warm_up_note(build_config("Hopper-v5", algo="td3", total_steps=4096)) == (
        "td3 acts at random for its first td3.learning_starts=25,000 steps and updates nothing before them, so this "
        "4,096-step run will not learn; give a larger --total-steps or --set td3.learning_starts=N"
    )
    assert warm_up_note(build_config("Hopper-v5", algo="sac", total_steps=5000)).startswith(
        "sac acts at random for its first sac.learning_starts=5,000 steps"
    )
    assert warm_up_note(build_config("Hopper-v5", algo="td3", total_steps=25_001)) is None
    assert warm_up_note(build_config("Hopper-v5", total_steps=4096)) is None  # ppo has no such phase


def test_an_algorithm_declares_its_warm_up_exactly_when_its_section_has_learning_starts():
    from canter.config.algorithms import algorithm_names, algorithm_spec
    from canter.config.schema import field_names

    for name in algorithm_names():
        spec = algorithm_spec(name)
        sections = [section for section in spec.reads if "." not in section]
        having = [section for section in sections if "learning_starts" in field_names(section)]
        assert spec.warm_up_key == (f"{having[0]}.learning_starts" if having else None), name


@pytest.mark.slow
def test_the_warm_up_note_comes_once_the_run_is_accepted_and_never_before_a_refusal(capsys, tmp_path):
    out = ["--out-dir", str(tmp_path), "--quiet"]
    refused = error_line(capsys, ["train", "CartPole-v1", "--algo", "td3", "--total-steps", "200", *out])
    assert refused.startswith("td3 is continuous-only, but CartPole-v1 has discrete actions"), refused
    tiny = ["--set", "td3.hidden=16,16", "--set", "run.tensorboard=false"]
    assert main(["train", "Pendulum-v1", "--algo", "td3", "--total-steps", "200", *tiny, *out]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if "acts at random" in line]
    assert notes == [
        "canter: note: td3 acts at random for its first td3.learning_starts=25,000 steps and updates nothing before "
        "them, so this 200-step run will not learn; give a larger --total-steps or --set td3.learning_starts=N"
    ]


def test_a_budget_far_from_whole_iterations_is_noted():
    from canter.config.algorithms import algorithm_spec, budget_rounding_note

    # brax preset: 4,096 envs x 80 steps = 327,680 env steps per iteration, so 4,096 steps train a whole iteration.
    config = build_config("ant", preset="brax", total_steps=4096)
    assert algorithm_spec("ppo").iteration_steps(config) == 4096 * 80
    # It advises no multiple: autoreset steps do not count, so a multiple trains one iteration more where episodes
    # end (test_a_budget_of_whole_iterations_trains_one_more_where_episodes_end).
    assert budget_rounding_note(config) == (
        "ppo trains in whole iterations of 327,680 env steps (env.num_envs 4,096 x ppo.n_steps 80), to the end of "
        "the one that reaches the budget, so this run.total_steps=4,096 run trains about 327,680; autoreset steps "
        "(one per episode end) do not count, so where episodes end it can take one more iteration, even with a "
        "multiple of 327,680; for a finer budget give smaller env.num_envs / ppo.n_steps"
    )
    # td3: 16 envs and 1,000 steps per call are 62 vector steps, 992 env steps; 1,500 train 1,984.
    td3 = build_config("Hopper-v5", algo="td3", total_steps=1500, sets=["env.num_envs=16"])
    assert algorithm_spec("td3").iteration_steps(td3) == 992
    note = budget_rounding_note(td3)
    assert "992 env steps (td3.steps_per_call 1,000), to the end of the one that reaches the budget, so this " in note
    assert "run.total_steps=1,500 run trains about 1,984; autoreset steps" in note
    assert note.endswith("even with a multiple of 992; for a finer budget give smaller td3.steps_per_call")
    # Within 10% of the budget, or a whole number of iterations, says nothing.
    fast = build_config("Hopper-v5", total_steps=1_000_000)
    assert 0 < 1_000_000 % algorithm_spec("ppo").iteration_steps(fast) < 10_000
    assert budget_rounding_note(fast) is None
    assert budget_rounding_note(replace(config, run=replace(config.run, total_steps=20 * 327_680))) is None
    assert budget_rounding_note(replace(config, run=replace(config.run, total_steps=2 * 327_680))) is None


@pytest.mark.slow
def test_the_rounded_budget_note_comes_from_training_after_its_checks(tmp_path, capsys):
    """Printed once the run has passed every check, so that a refused run still gets one line."""
    argv = ["train", "InvertedPendulum-v5", "--total-steps", "100", "--out-dir", str(tmp_path), "--quiet"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "canter: note: ppo trains in whole iterations of 2,048 env steps" in err, err


@pytest.mark.slow
def test_a_budget_of_whole_iterations_trains_one_more_where_episodes_end(tmp_path):
    """What the budget note says instead of advising a multiple: Pendulum's 200-step episodes end within the first
    iteration of 4 x 256 env steps, their autoreset steps do not count, so a budget of exactly one iteration takes
    two (and no note is printed for it)."""
    from canter.config.algorithms import algorithm_spec, budget_rounding_note
    from canter.training.loop import train

    sets = ["net.hidden=16,16", "run.tensorboard=false", "env.num_envs=4", "ppo.n_steps=256"]
    config = build_config("Pendulum-v1", total_steps=1024, sets=sets + ["ppo.minibatch_size=256", "ppo.epochs=1"])
    config = replace(config, run=replace(config.run, out_dir=str(tmp_path)))
    assert algorithm_spec("ppo").iteration_steps(config) == 1024 and budget_rounding_note(config) is None
    result = train(config)
    assert 1024 < result.global_step < 2048  # two iterations, less the autoreset steps after the episode ends


def test_a_v4_id_asked_for_on_purpose_makes_no_deprecation_warning():
    code = "from canter.envs.gymnasium.single import make_single; make_single('HalfCheetah-v4').close()"
    done = subprocess.run([sys.executable, "-W", "default", "-c", code], capture_output=True, text=True, check=True)
    assert "out of date" not in done.stderr, done.stderr


def test_one_run_that_cannot_be_evaluated_keeps_the_others_results(tmp_path, capsys, monkeypatch):
    import canter.use.evaluate

    good, bad = tmp_path / "good", tmp_path / "bad"
    shutil.copytree(ARCHIVED_RUN, good)
    shutil.copytree(ARCHIVED_RUN, bad)
    real = canter.use.evaluate.evaluate

    def evaluate(policy, **kwargs):
        if policy.source == bad:
            raise CanterError("cannot import module 'my_pkg.envs'")
        return real(policy, **kwargs)

    monkeypatch.setattr(canter.use.evaluate, "evaluate", evaluate)
    out = tmp_path / "eval.json"
    assert main(["eval", str(bad), str(good), "--episodes", "1", "--json", str(out)]) == 2
    captured = capsys.readouterr()
    # A row is the run's path, cut to its column when long, then the checkpoint: match the path's end and `last`.
    rows = [line.split() for line in captured.out.splitlines()]
    assert any(row[0].endswith("good") and row[1] == "last" for row in rows if len(row) > 1), captured.out
    assert not any(row[0].endswith("bad") for row in rows if row), captured.out
    assert captured.err == (
        f"canter: error: 1 of 2 runs could not be evaluated ({bad}: cannot import module 'my_pkg.envs'); the other 1 "
        f"are above and in {out}\n"
    )
    assert [row["run"] for row in json.loads(out.read_text())["runs"]] == [str(good)]


def test_a_checkpoint_file_of_another_run_is_refused_and_one_of_its_own_is_taken(archived_run, tmp_path, capsys):
    """Results carry the run folder's name, so `--checkpoint FILE` of another run would be reported as this run's
    (a td3 policy on InvertedPendulum once scored under a Pendulum ppo label)."""
    other = sorted((ARCHIVED_RUN.parent / "sac" / "checkpoints").iterdir())[-1]
    for command in (["eval"], ["export", "--out", str(tmp_path / "p.onnx")]):
        argv = [command[0], str(archived_run), *command[1:], "--checkpoint", str(other)]
        one_line(capsys, argv, "is a checkpoint of another run than")
    assert not (tmp_path / "p.onnx").exists()
    kept = tmp_path / "kept.npz"  # one of its own, moved out of checkpoints/
    shutil.copy(sorted((archived_run / "checkpoints").iterdir())[0], kept)
    assert main(["eval", str(archived_run), "--checkpoint", str(kept), "--episodes", "1"]) == 0


@pytest.mark.parametrize("where", ["long", "missing_parent"])
def test_a_path_the_file_system_refuses_is_one_line(tmp_path, capsys, where):
    out = tmp_path / ("z" * 300) if where == "long" else Path("/proc/no-such-folder/runs")
    one_line(capsys, ["train", "Pendulum-v1", "--out-dir", str(out), "--total-steps", "64"], str(out)[:20])


def test_an_out_dir_that_is_not_utf8_is_refused_before_any_work(tmp_path, capsys):
    out = os.fsdecode(bytes(tmp_path) + b"/bad\xffname")
    one_line(capsys, ["train", "Pendulum-v1", "--out-dir", out, "--total-steps", "64"], "is not valid UTF-8")
    assert not Path(out).exists()


def test_a_bad_value_in_a_file_names_the_file(archived_run, tmp_path, capsys):
    """Among many run folders given to plot, a bad value alone did not say which config.toml holds it."""
    text = (archived_run / "config.toml").read_text()
    (archived_run / "config.toml").write_text(text.replace("clip = 0.2", 'clip = "wide"', 1))
    one_line(
        capsys,
        ["plot", str(archived_run), "--out", str(tmp_path / "p.png")],
        f"got 'wide' (in {archived_run / 'config.toml'})",
    )
    given = tmp_path / "given.toml"
    given.write_text('[ppo]\nclip = "wide"\n')
    one_line(capsys, ["train", "Pendulum-v1", "--config", str(given)], f"got 'wide' (in {given})")


def test_a_path_of_the_wrong_kind_says_what_is_wanted(archived_run, tmp_path, capsys):
    one_line(
        capsys,
        ["train", "Pendulum-v1", "--config", str(tmp_path)],
        "is a folder; --config (config_file= from Python) takes a TOML file",
    )
    one_line(capsys, ["plot", str(archived_run / "config.toml")], "is a file, not a run folder")
    one_line(
        capsys,
        ["eval", str(archived_run), "--checkpoint", "lst"],
        "--checkpoint (checkpoint= from Python) takes last, best or a .npz file",
    )


def test_a_policy_refuses_observations_that_are_not_real_numbers(archived_run):
    import jax

    import canter

    policy = canter.load(archived_run)
    good = np.zeros((2, policy.obs_dim))
    assert policy(good).shape == (2, policy.act_dim) and policy(good.astype(int).tolist()).shape == (2, policy.act_dim)
    with pytest.raises(CanterError, match="policy expects numeric observations of shape"):
        policy(np.full((2, policy.obs_dim), "a"))
    with pytest.raises(CanterError, match="real-valued observations, got complex numbers"):
        policy(good + 1j)
    with pytest.raises(CanterError, match=rf"observations of shape \(batch, {policy.obs_dim}\), got \(2, 1\)"):
        policy(np.zeros((2, 1)))
    with pytest.raises(CanterError, match=r"shape \(batch, 4\), got rows of different lengths$"):
        policy([[1.0, 2.0, 3.0, 4.0], [1.0, 2.0]])
    with pytest.raises(CanterError, match=r"inside jax.jit, vmap or grad; use policy.traced\(\)"):
        jax.jit(lambda obs: policy(obs))(np.zeros((1, policy.obs_dim), np.float32))
    # The caller owns what it gets, a batch's actions or one observation's.
    for actions in (policy(good), policy(good[0]), policy(good, deterministic=False, seed=1)):
        actions += 1
    # numpy reads None as NaN, on which the policy would act
    with pytest.raises(CanterError, match=r"policy expects numeric observations of shape \(batch, \d+\), got None$"):
        policy(None)
    holey = good.astype(object)
    holey[1, 0] = None
    with pytest.raises(CanterError, match=r"got None among them$"):
        policy(holey)
    with pytest.raises(CanterError, match=r"got None among them$"):
        policy([None] * policy.obs_dim)


@pytest.mark.parametrize("seed", [1.5, "7", True, -1, 2**70])
def test_the_python_api_refuses_a_seed_that_is_not_one(archived_run, seed):
    import canter

    policy = canter.load(archived_run)
    obs = np.zeros((1, policy.obs_dim))
    with pytest.raises(CanterError, match=r"seed must be a whole number from 0 to 4294967295, got "):
        policy(obs, deterministic=False, seed=seed)
    with pytest.raises(CanterError, match=r"seed must be a whole number from 0 to 4294967295, got "):
        canter.evaluate(policy, episodes=1, seed=seed)


def test_the_python_api_refuses_arguments_of_the_wrong_kind_in_one_line(archived_run, tmp_path):
    import canter

    policy = canter.load(archived_run)
    config = canter.build_config("InvertedPendulum-v5", sets=[f"run.out_dir={tmp_path}"])
    for call in (
        lambda: canter.train(config, quiet="no"),
        lambda: canter.train_seeds(config, [0], quiet="no"),
        lambda: canter.resume_seeds([archived_run], quiet="yes"),
    ):
        with pytest.raises(CanterError, match=r"quiet must be True or False, got '(no|yes)'$"):
            call()
    assert not any(tmp_path.glob("InvertedPendulum*"))
    for name, number in (("seed", 1.0), ("seed", "1"), ("total_steps", 1000.0), ("total_steps", "1000")):
        with pytest.raises(CanterError, match=rf"^{name}= must be a whole number \(an int\) or None, got "):
            canter.build_config("InvertedPendulum-v5", **{name: number})
    assert canter.build_config("InvertedPendulum-v5", seed=np.int64(3), total_steps=np.int32(500)).run.seed == 3
    for episodes in (2.5, True, "3", 0):
        with pytest.raises(CanterError, match=r"episodes must be a whole number >= 1, got "):
            canter.evaluate(policy, episodes=episodes)
    for name in ("env_id", "backend"):
        with pytest.raises(CanterError, match=f"{name} is empty; give one, or leave it out"):
            canter.evaluate(policy, episodes=1, **{name: ""})
    with pytest.raises(CanterError, match="physics must be a mapping of settings to values, got list"):
        canter.evaluate(policy, episodes=1, physics=[("solver_iterations", 4)])
    for which in (None, 5):
        with pytest.raises(CanterError, match=r"checkpoint must be 'last', 'best' or a checkpoint file's path, got "):
            canter.load(archived_run, checkpoint=which)
    newest = sorted((archived_run / "checkpoints").glob("ckpt_*.npz"))[-1]
    with pytest.raises(CanterError, match=rf"checkpoint not found: {newest.name}; the run's own is {newest}: pass"):
        canter.load(archived_run, checkpoint=newest.name)
    within = Path("checkpoints") / newest.name  # relative to the run folder, not to the working directory
    with pytest.raises(CanterError, match=rf"checkpoint not found: {within}; the run's own is {newest}: pass"):
        canter.load(archived_run, checkpoint=within)
    with pytest.raises(CanterError, match=r"metrics.csv is a file, not a run folder; pass the folder that holds it$"):
        canter.load(archived_run / "metrics.csv")


@pytest.mark.parametrize(
    "sets, message",
    [
        (["run.out_dir="], "run.out_dir is empty; give a folder for the run folders"),
        (["run.out_dir=  "], "run.out_dir is empty"),
        (["env.backend=gymnasium", "env.envpool_shards=2"], "env.envpool_shards applies to the envpool backend only"),
    ],
)
def test_settings_that_would_do_nothing_or_write_into_the_current_folder_are_refused(sets, message):
    with pytest.raises(CanterError, match=message):
        build_config("Hopper-v5", sets=sets)
    assert build_config("Hopper-v5", sets=["env.backend=envpool", "env.envpool_shards=2"]).env.envpool_shards == 2


def test_an_empty_algo_is_refused_rather_than_read_as_the_default():
    with pytest.raises(CanterError, match=r"^--algo \(algo= from Python\) is empty; give one of ppo, .*, or drop it$"):
        build_config("Hopper-v5", algo="")


def test_new_runs_benches_and_studies_are_refused_inside_a_runs_own_folders(tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(ARCHIVED_RUN, run)
    before = sorted(run.rglob("*"))
    inside = run / "checkpoints" / "more"
    cases = [
        (["train", "Pendulum-v1", "--out-dir", str(run / "checkpoints")], "--out-dir", run / "checkpoints"),
        (["train", "Pendulum-v1", "--set", f"run.out_dir={inside}"], "--out-dir", inside),
        (["bench", "--envs", "Pendulum-v1", "--seeds", "0", "--out", str(inside)], "--out", inside),
        (["tune", "Pendulum-v1", "--trials", "1", "--out-dir", str(run / "tb")], "--out-dir", run / "tb"),
    ]
    for argv, flag, folder in cases:
        assert main([*argv, "--total-steps", "2048"]) == 2, argv
        err = capsys.readouterr().err
        owner = "checkpoints" if "checkpoints" in str(folder) else "tb"
        python = " (run.out_dir from Python)" if argv[0] == "train" else ""  # bench and tune are commands only
        assert err == (
            f"canter: error: {flag} {folder} is inside {owner}/ of the run folder {run}, which holds that run's own "
            f"files; give another {flag}{python}\n"
        ), err
    assert sorted(run.rglob("*")) == before


def test_an_empty_bench_or_study_folder_is_refused(capsys):
    for argv, flag, what in (
        (["bench", "--envs", "Pendulum-v1", "--out", ""], "--out", "a folder for the bench, or drop --out"),
        (["tune", "Pendulum-v1", "--out-dir", ""], "--out-dir", "a folder for the study folders, or drop --out-dir"),
    ):
        assert main(argv) == 2
        assert capsys.readouterr().err == f"canter: error: {flag} is empty; give {what}\n"


def test_a_projects_own_checkpoints_folder_beside_its_config_is_no_run_folder(tmp_path, monkeypatch):
    """A user's folder with a config.toml and an output folder named checkpoints/ holds no run: runs may go there."""
    from canter.files import refuse_out_dir_in_a_run, refuse_protected_target

    (tmp_path / "config.toml").write_text("[run]\n")
    (tmp_path / "checkpoints" / "Pendulum-v1__ppo__fast__s0__x").mkdir(parents=True)
    refuse_out_dir_in_a_run(tmp_path / "checkpoints", "--out-dir")
    refuse_protected_target(tmp_path / "checkpoints" / "actor.onnx")
    (tmp_path / "versions.json").write_text("{}")  # now it is a run's
    with pytest.raises(CanterError, match="is inside checkpoints/ of the run folder"):
        refuse_out_dir_in_a_run(tmp_path / "checkpoints", "--out-dir")


def test_a_folder_s_run_files_count_checkpoints_only_when_one_is_there(tmp_path):
    from canter.run_layout import run_files_in, surely_a_run

    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "ckpt_12.npz").write_bytes(b"")  # not a checkpoint's name: 12 digits are
    (tmp_path / "config.toml").write_text("[run]\n")
    assert run_files_in(tmp_path) == {"config.toml"}
    assert not surely_a_run(tmp_path)
    (tmp_path / "checkpoints" / "ckpt_000000002048.npz").write_bytes(b"")
    assert run_files_in(tmp_path) == {"config.toml", "checkpoints"}
    assert surely_a_run(tmp_path)
    (tmp_path / "config.toml").unlink()
    (tmp_path / "metrics.csv.gz").write_bytes(b"")
    assert run_files_in(tmp_path) == {"metrics.csv.gz", "checkpoints"}
    assert not surely_a_run(tmp_path)  # without its config.toml nothing here is surely a run's


def test_a_new_run_given_a_folder_that_holds_a_run_is_refused(archived_run):
    import canter

    before = sorted(archived_run.rglob("*"))
    config = canter.build_config("Pendulum-v1", total_steps=2048)
    with pytest.raises(CanterError) as refused:
        canter.train(config, run_dir=archived_run)
    assert str(refused.value) == (
        f"{archived_run} already holds a run (config.toml, metrics.csv, checkpoints); resume it (canter train "
        "--resume, or train(config, resume=...)), or give a new run folder"
    )
    assert sorted(archived_run.rglob("*")) == before


def test_seeds_given_as_text_and_an_empty_mlflow_store_are_refused(capsys):
    import canter

    config = canter.build_config("Pendulum-v1", total_steps=2048)
    with pytest.raises(CanterError, match=r"seeds must be a list of whole numbers, e.g. \[0, 1, 2\], got '01'"):
        canter.train_seeds(config, "01")
    with pytest.raises(CanterError, match=r"seed must be a whole number from 0 to 4294967295, got 1.5"):
        canter.train_seeds(config, [0, 1.5])
    one_line(capsys, ["train", "Pendulum-v1", "--track", "mlflow", "--mlflow-uri", ""], "--mlflow-uri is empty; give")
    one_line(capsys, ["eval", str(ARCHIVED_RUN), "--env", ""], "--env is empty; give an env id, or drop --env")


def test_text_nested_past_the_recursion_limit_reads_as_malformed(archived_run, tmp_path, capsys):
    # Python's parsers recurse once per level, so such text used to crash every reader with a RecursionError.
    deep_toml = tmp_path / "deep.toml"
    deep_toml.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")
    one_line(capsys, ["train", "Hopper-v5", "--config", str(deep_toml)], "malformed TOML in ")
    one_line(capsys, ["tune", "Hopper-v5", "--space", str(deep_toml)], "nested too deeply to read")
    for name in ("versions.json", "summary.json", "eval.json"):
        (archived_run / name).write_text("[" * 5000 + "]" * 5000)
    assert main(["report", str(archived_run), "--episodes", "0", "--out", str(tmp_path / "r.html")]) == 0
    (archived_run / "trackers.json").write_text("{" + '"a":{' * 5000 + "}" * 5001)
    one_line(
        capsys,
        ["train", "--resume", str(archived_run), "--total-steps", "9000"],
        "trackers.json is not the JSON canter writes",
    )
