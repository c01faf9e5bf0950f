"""Bad input that once got a misleading or missing message: one line naming the problem and the fix, exit 2."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from canter.cli.main import main
from canter.config.build import build_config
from canter.errors import CanterError, first_sentence
from conftest import ARCHIVED_RUN, error_line

SEEDS_RANGE = "expected seeds from 0 to 4294967295, got '-1,2' (see --help)"


@pytest.mark.parametrize(
    "argv, message",
    [
        (["train", "Hopper-v5", "--seeds", "-1,2"], f"train: argument --seeds: {SEEDS_RANGE}"),
        (["train", "Hopper-v5", "--seeds=-1,2"], f"train: argument --seeds: {SEEDS_RANGE}"),
        (["train", "--seeds", "-1,2", "Hopper-v5"], f"train: argument --seeds: {SEEDS_RANGE}"),
        (["bench", "--envs", "Hopper-v5", "--seeds", "-1,2"], f"bench: argument --seeds: {SEEDS_RANGE}"),
        (
            ["train", "Hopper-v5", "--seed", "-1e3"],
            "train: argument --seed: expected a whole number such as 0, got '-1e3' (see --help)",
        ),
    ],
)
def test_a_value_that_starts_with_a_minus_reaches_the_option_s_own_check(argv, message, capsys):
    assert error_line(capsys, argv) == message


@pytest.mark.parametrize(
    "value, message",
    [
        ("-4", "net.hidden: layer sizes must be positive integers, such as 64,64, got '-4'"),
        ("64,-64", "net.hidden: layer sizes must be positive integers, such as 64,64, got '64,-64'"),
    ],
)
def test_a_negative_layer_size_says_sizes_are_positive(value, message, capsys):
    assert error_line(capsys, ["train", "Hopper-v5", "--set", f"net.hidden={value}"]) == message


@pytest.mark.parametrize(
    "argv, newer",
    [
        (["train", "Hopper-v2"], "train Hopper-v5 (or Hopper-v4) instead"),
        (["train", "Walker2d-v3", "--backend", "gymnasium"], "train Walker2d-v5 (or Walker2d-v4) instead"),
    ],
)
def test_an_old_mujoco_version_points_to_the_current_one(argv, newer, capsys):
    line = error_line(capsys, argv)
    assert line.startswith(f"{argv[1]} is an old MuJoCo version that needs mujoco-py") and newer in line, line
    assert not Path("runs").exists()


def test_an_output_folder_that_is_a_file_says_so(tmp_path, capsys):
    (tmp_path / "empty.toml").write_text("")
    argv = ["bench", "--envs", "Hopper-v5", "--seeds", "0", "--total-steps", "2048", "--out"]
    assert error_line(capsys, [*argv, "empty.toml"]) == (
        "cannot make the folder empty.toml: it is a file, not a folder; move empty.toml out of the way, or pick "
        "another path"
    )
    assert error_line(capsys, [*argv, "empty.toml/bench"]) == (
        "cannot make the folder empty.toml/bench: empty.toml is a file, not a folder; move empty.toml out of the way, "
        "or pick another path"
    )


@pytest.mark.parametrize("command", [["report", "--episodes", "0"], ["plot", "--out", "curves.png"]])
def test_a_run_folder_without_metrics_names_no_other_command(command, archived_run, capsys):
    (archived_run / "metrics.csv").unlink()
    line = error_line(capsys, [command[0], str(archived_run), *command[1:]])
    assert line == f"no metrics.csv in {archived_run}; pass a run folder written by `canter train`"


def test_a_checkpoint_folder_is_not_a_checkpoint(archived_run, capsys):
    line = error_line(
        capsys, ["eval", str(archived_run), "--checkpoint", str(archived_run / "checkpoints"), "--episodes", "1"]
    )
    assert line.startswith(
        f"checkpoint {archived_run / 'checkpoints'} is a folder; --checkpoint (checkpoint= from Python) takes last, "
        f"best or a .npz"
    )


@pytest.mark.parametrize("which", ["last", "best"])
def test_a_checkpoints_entry_that_is_a_file_is_named(which, archived_run, capsys):
    shutil.rmtree(archived_run / "checkpoints")
    (archived_run / "checkpoints").write_text("")
    line = error_line(capsys, ["eval", str(archived_run), "--checkpoint", which, "--episodes", "1"])
    assert line.startswith(
        f"{archived_run / 'checkpoints'} is not a folder, where a run keeps its checkpoints; move it away"
    )


def test_a_missing_search_space_file_is_named_as_one(capsys):
    assert error_line(capsys, ["tune", "Hopper-v5", "--space", "nofile.toml"]) == (
        "search space file not found: nofile.toml"
    )


@pytest.mark.parametrize(
    "flag, message",
    [
        ("--config", "--config (config_file= from Python) is empty; give a TOML file, or drop it"),
        ("--preset", "--preset (preset= from Python) is empty; give one of "),
        ("--out-dir", "--out-dir is empty; give a folder for the run folders, or drop --out-dir"),
    ],
)
@pytest.mark.parametrize("form", ["apart", "joined"])
def test_an_empty_value_is_refused(flag, message, form, capsys):
    given = [flag, ""] if form == "apart" else [f"{flag}="]
    assert error_line(capsys, ["train", "Hopper-v5", *given]).startswith(message)
    assert not Path("runs").exists()


@pytest.mark.parametrize("episodes", ["0", "1"])
def test_report_of_a_best_checkpoint_a_run_lacks_is_refused_with_or_without_evaluation(episodes, archived_run, capsys):
    argv = ["report", str(archived_run), "--checkpoint", "best", "--episodes", episodes, "--out", "r.html"]
    assert error_line(capsys, argv).startswith(
        f"{archived_run} has no best checkpoint: it never evaluated during training"
    )
    assert not Path("r.html").exists()


def test_a_config_file_s_run_preset_is_the_preset_beneath_it(tmp_path):
    file = tmp_path / "c.toml"
    file.write_text('[run]\npreset = "cleanrl"\n')
    config = build_config("Hopper-v5", config_file=str(file))
    cleanrl = build_config("Hopper-v5", preset="cleanrl")
    assert config.run.preset == "cleanrl" and config == cleanrl  # laid over cleanrl, not labelled over fast's values
    assert build_config("Hopper-v5", preset="cleanrl", config_file=str(file)) == cleanrl
    # as --set run.preset is refused where it would name another preset than the one applied
    with pytest.raises(CanterError, match=r"sets run\.preset = 'cleanrl', but the preset is fast"):
        build_config("Hopper-v5", preset="fast", config_file=str(file))


@pytest.mark.parametrize(
    "preset, text, message",
    [
        (
            ["--preset", "fast"],
            'preset = "cleanrl"',
            "c.toml sets run.preset = 'cleanrl', but the preset is fast; run.preset records the preset a config was "
            "built from: pass --preset cleanrl (preset='cleanrl' from Python), or drop run.preset from the file",
        ),
        ([], 'preset = "mine"', "c.toml sets run.preset = 'mine', which is no preset; run.preset records the preset"),
    ],
)
def test_a_config_file_s_run_preset_that_would_misname_the_run_is_refused(preset, text, message, capsys):
    Path("c.toml").write_text(f"[run]\n{text}\n")
    assert error_line(capsys, ["train", "Hopper-v5", "--config", "c.toml", *preset]).startswith(message)
    assert not Path("runs").exists()


def test_a_config_file_whose_run_preset_is_none_names_no_preset(tmp_path):
    """A config built with no preset (the Python API's Config, whose run.preset is none) writes run.preset as "none":
    such a file is laid over --preset, else fast, as a file without run.preset is."""
    from dataclasses import replace

    from canter.config.schema import Config
    from canter.config.serialize import to_toml

    built = build_config("Hopper-v5")
    none = replace(built, run=replace(built.run, preset=Config().run.preset))
    file = tmp_path / "none.toml"
    file.write_text(to_toml(none))
    assert 'preset = "none"' in file.read_text()
    assert build_config(None, config_file=str(file)) == built
    cleanrl = build_config(None, preset="cleanrl", config_file=str(file))
    assert cleanrl.run.preset == "cleanrl"
    file.write_text('[run]\npreset = "None"\n')
    assert build_config("Hopper-v5", config_file=str(file)) == built


def test_a_preset_the_config_file_names_that_excludes_the_algorithm_names_the_file(capsys):
    Path("c.toml").write_text('[run]\npreset = "report002-ddpg"\n')
    line = error_line(capsys, ["train", "Hopper-v5", "--config", "c.toml", "--algo", "ppo"])
    assert line == (
        "preset report002-ddpg, named by c.toml's run.preset, holds settings for ddpg only, not ppo; train one of "
        "those algorithms with it, e.g. --algo ddpg (algo='ddpg' from Python), or drop run.preset from c.toml and "
        "pass another preset, e.g. --preset fast (preset='fast' from Python)"
    )
    # --preset fast alone is refused, as naming another preset than the file's; dropping run.preset is what frees it
    assert error_line(capsys, ["train", "Hopper-v5", "--config", "c.toml", "--preset", "fast"]).startswith(
        "c.toml sets run.preset = 'report002-ddpg', but the preset is fast"
    )
    Path("c.toml").write_text("[run]\n")
    assert build_config("Hopper-v5", preset="fast", config_file="c.toml", algo="ppo").run.preset == "fast"
    # a --preset the user chose is named as before
    with pytest.raises(CanterError, match=r"^preset report002-ddpg holds settings for ddpg only, not ppo; .* choose"):
        build_config("Hopper-v5", preset="report002-ddpg", algo="ppo")
    assert not Path("runs").exists()


@pytest.fixture
def settings_of(monkeypatch):
    """The settings `canter tune` or `canter bench` would run with, from its arguments, without running them."""
    import canter.orchestrate.bench
    import canter.orchestrate.tune

    given = []
    monkeypatch.setattr(canter.orchestrate.tune, "tune", given.append)
    monkeypatch.setattr(canter.orchestrate.bench, "bench", given.append)

    def settings(argv):
        assert main(argv) == 0
        return given.pop()

    return settings


@pytest.mark.parametrize("preset, resolved", [([], "cleanrl"), (["--preset", "cleanrl"], "cleanrl")])
def test_tune_and_bench_lay_a_config_file_over_the_preset_its_run_preset_names(preset, resolved, settings_of):
    from canter.orchestrate.bench_grid import make_cells
    from canter.orchestrate.tune import check_settings

    Path("cl.toml").write_text('[run]\npreset = "cleanrl"\n')
    cleanrl = build_config("Hopper-v5", preset="cleanrl", seed=0, total_steps=1_000_000, algo="ppo")
    tune = settings_of(["tune", "Hopper-v5", "--config", "cl.toml", *preset])
    base, _ = check_settings(tune)
    assert base.run.preset == resolved and base == cleanrl
    bench = settings_of(["bench", "--envs", "Hopper-v5", "--config", "cl.toml", "--seeds", "0", *preset])
    (cell,) = make_cells(bench)
    assert cell.config.run.preset == resolved and cell.config == cleanrl
    assert cell.run_dir(Path("bench"), 0) == Path("bench/Hopper-v5__ppo__s0")


def test_tune_and_bench_without_preset_or_config_file_use_fast(settings_of):
    from canter.orchestrate.bench_grid import make_cells
    from canter.orchestrate.tune import check_settings

    tune = settings_of(["tune", "Hopper-v5"])
    assert tune.preset is None and check_settings(tune)[0].run.preset == "fast"
    bench = settings_of(["bench", "--envs", "Hopper-v5", "--seeds", "0"])
    assert bench.preset is None and make_cells(bench)[0].config.run.preset == "fast"


@pytest.mark.parametrize("command", [["tune", "Hopper-v5"], ["bench", "--envs", "Hopper-v5", "--seeds", "0"]])
def test_tune_and_bench_refuse_a_preset_the_config_file_s_run_preset_contradicts(command, capsys):
    Path("cl.toml").write_text('[run]\npreset = "cleanrl"\n')
    line = error_line(capsys, [*command, "--config", "cl.toml", "--preset", "fast"])
    assert "cl.toml sets run.preset = 'cleanrl', but the preset is fast" in line, line
    assert not Path("tune").exists() and not Path("bench").exists()


@pytest.mark.parametrize("given", [["--space", ""], ["--space="], ["--space", "  "]])
def test_an_empty_search_space_is_refused(given, capsys):
    assert error_line(capsys, ["tune", "Hopper-v5", *given]) == (
        "--space is empty; give a search space TOML file, or drop --space"
    )
    assert not Path("tune").exists()


@pytest.mark.parametrize(
    ("sets", "named"),
    [([], True), (["--set", "ppo.lr=-2"], False), (["--set", "ppo.lr=0.001"], None)],
    ids=["file", "set-over-file", "set-mends-file"],
)
def test_a_value_the_config_file_gives_that_is_refused_names_the_file(sets, named, capsys):
    """Validation runs on the whole config; a refusal that the file's own values cause names the file, one that a
    --set over it causes does not, and a --set may mend the file."""
    Path("c.toml").write_text("[ppo]\nlr = -1\n")
    argv = ["train", "Hopper-v5", "--config", "c.toml", *sets]
    if named is None:
        build_config("Hopper-v5", config_file="c.toml", sets=["ppo.lr=0.001"])
        return
    line = error_line(capsys, argv)
    assert line.startswith("ppo.lr must be > 0") and line.endswith(" (in c.toml)") == named, line


def test_a_camera_index_of_minus_one_is_the_free_camera(archived_run, capsys):
    """Help says `name or index`: -1 is MuJoCo's free camera, and an index below it is refused with the choices."""
    from canter.use.video_players import GymnasiumPlayer

    line = error_line(
        capsys, ["video", str(archived_run), "--out", "v.gif", "--camera", "-2", "--width", "32", "--height", "32"]
    )
    assert line == (
        "InvertedPendulum-v4 has no camera '-2'; cameras: -1 (the free camera), or omit --camera for the default view"
    )
    GymnasiumPlayer("InvertedPendulum-v4", 32, 32, "-1").close()


@pytest.mark.slow
def test_a_video_renders_from_the_free_camera(archived_run, capsys):
    argv = ["video", str(archived_run), "--out", "v.gif", "--camera", "-1", "--width", "32", "--height", "32"]
    assert main([*argv, "--max-steps", "3"]) == 0, capsys.readouterr().err
    assert Path("v.gif").stat().st_size > 0


def test_first_sentence_keeps_a_library_message_to_its_cause():
    paragraph = (
        "The filesystem tracking backend (e.g., './mlruns') is in maintenance mode. Please migrate to a database "
        "backend (e.g., 'sqlite:///mlflow.db'). See https://mlflow.org/docs for more.\nTraceback line"
    )
    assert first_sentence(RuntimeError(paragraph)) == (
        "The filesystem tracking backend (e.g., './mlruns') is in maintenance mode."
    )
    assert first_sentence(ValueError("no such table: runs")) == "no such table: runs"
    assert first_sentence(OSError("version 1.2 of x. `pip install y` fixes it")) == "version 1.2 of x."
    assert first_sentence(KeyError()) == "KeyError"


@pytest.mark.parametrize(
    "argv, message",
    [
        (["eval", "no\nsuch"], "run folder not found: no\\nsuch"),
        (["train", "Hop\nper-v5"], "unknown env id 'Hop\\nper-v5' for canter; did you mean "),
        (
            ["train", "Hopper-v5", "--set", "ppo.l\r\nr=1"],
            "unknown config key 'ppo.l\\r\\nr' in --set (sets= from Python); did you mean ",
        ),
    ],
)
def test_a_line_break_in_a_given_value_is_written_escaped_so_the_error_stays_one_line(argv, message, capsys):
    assert error_line(capsys, argv).startswith(message)


@pytest.mark.parametrize("flag", ["--max-minutes", "--stop-at-return"])
@pytest.mark.parametrize("value", ["-inf", "nan"])
def test_a_limit_flag_refuses_what_limits_nothing_and_names_inf_not_none(flag, value, capsys):
    assert error_line(capsys, ["train", "Hopper-v5", flag, value]) == (
        f"train: argument {flag}: expected a finite number, or inf for no limit, got {value!r} (see --help)"
    )


def test_a_config_file_that_lists_as_a_file_but_cannot_be_read_is_one_line(capsys):
    assert error_line(capsys, ["train", "Hopper-v5", "--config", "/proc/self/mem"]) == (
        "cannot read /proc/self/mem: Input/output error; give a TOML file that can be read"
    )


def test_a_grid_of_layer_sizes_is_told_the_dashes_that_join_one_value(tmp_path, capsys):
    argv = ["bench", "--envs", "Hopper-v5", "--grid", "net.hidden=64-64,abc", "--out", str(tmp_path / "b")]
    assert error_line(capsys, argv) == (
        "net.hidden: expected comma-separated integers (or joined by dashes, 64-64), got 'abc'"
    )


def test_an_error_line_escapes_control_characters_only():
    from canter.errors import error_line

    assert error_line(CanterError("a\nb\tc\u2028d")) == "canter: error: a\\nb\\tc\\u2028d"
    names = "runs/実験\u30001 فارسی\u200cها 👩\u200d💻 café"
    assert error_line(CanterError(names)) == f"canter: error: {names}"


@pytest.mark.parametrize("episodes", ["0", "1"])
@pytest.mark.parametrize("given", ["missing", "of another run"])
def test_report_refuses_a_checkpoint_file_as_eval_does_with_or_without_evaluation(
    given, episodes, archived_run, tmp_path, capsys
):
    """With --episodes 0 nothing loaded the file, so a page named a checkpoint that was not there or not the run's."""
    other = sorted((ARCHIVED_RUN.parent / "sac" / "checkpoints").iterdir())[-1]
    file = tmp_path / "missing.npz" if given == "missing" else other
    report = ["report", str(archived_run), "--checkpoint", str(file), "--episodes", episodes, "--out", "r.html"]
    assert error_line(capsys, report) == error_line(capsys, ["eval", str(archived_run), "--checkpoint", str(file)])
    assert not Path("r.html").exists()


def test_report_without_evaluation_takes_a_checkpoint_file_of_its_own_run(archived_run, tmp_path, capsys):
    kept = tmp_path / "kept.npz"  # one of its own, moved out of checkpoints/
    shutil.copy(sorted((archived_run / "checkpoints").glob("ckpt_*.npz"))[0], kept)
    argv = ["report", str(archived_run), "--checkpoint", str(kept), "--episodes", "0", "--out", "r.html"]
    assert main(argv) == 0, capsys.readouterr().err
    assert Path("r.html").is_file()


def test_best_missing_from_a_run_that_evaluates_during_training_is_not_said_never_to_have_evaluated(
    archived_run, capsys
):
    config = archived_run / "config.toml"
    config.write_text(config.read_text().replace("[run]\n", "[run]\neval_every = 512\n", 1))
    assert error_line(capsys, ["eval", str(archived_run), "--checkpoint", "best"]) == (
        f"{archived_run} has no best checkpoint: {archived_run / 'checkpoints' / 'best.npz'} is missing, though the "
        f"run evaluates during training (run.eval_every): deleted, or the run stopped before its first evaluation; "
        f"drop --checkpoint best to use the last checkpoint (checkpoint='last' from Python), or pass a checkpoint file"
    )


def test_an_archive_without_its_checkpoints_but_with_its_best_points_to_it(archived_run, capsys):
    folder = archived_run / "checkpoints"
    shutil.copy(sorted(folder.glob("ckpt_*.npz"))[-1], folder / "best.npz")
    for path in folder.glob("ckpt_*.npz"):
        path.unlink()
    assert error_line(capsys, ["eval", str(archived_run)]) == (
        f"{archived_run} holds a finished run without its checkpoints (an archive?): it has no policy to load or "
        f"train on; plot reads its metrics, as report does with --episodes 0, and a new run trains it again; eval, "
        f"video, export and report can take --checkpoint best (checkpoint='best' from Python) instead"
    )
    assert main(["eval", str(archived_run), "--checkpoint", "best", "--episodes", "1"]) == 0, capsys.readouterr().err
