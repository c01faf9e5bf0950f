"""Run folders written before the restructure (format 1, tests/fixtures/runs-v1, made by a704fbb) still load:
they evaluate, plot, report, export and resume, reading never writes to them, and resuming migrates them."""

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from canter.cli.main import main
from canter.config.experiment import flat_config, group_by_experiment
from canter.training import run_folder
from canter.training.run_folder import RUN_FORMAT, read_config, run_format

pytestmark = pytest.mark.slow

FIXTURES = Path(__file__).parent / "fixtures" / "runs-v1"
ALGORITHM_RUNS = ("ppo", "rpo", "trpo", "td3", "ddpg", "sac")
GROUP = ("ppo-group-s0", "ppo-group-s1")


@pytest.fixture()
def v1_runs(tmp_path):
    target = tmp_path / "runs-v1"
    shutil.copytree(FIXTURES, target)
    return target


def _digest(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def test_fixtures_are_format_1_and_read_as_their_algorithms():
    for name in ALGORITHM_RUNS + GROUP:
        assert run_format(FIXTURES / name) == 1
        config = read_config(FIXTURES / name)
        assert config.run.algo == name.split("-")[0]
        # Format 1 kept every section; those the algorithm does not read are not part of the config's meaning.
        assert "[sac]" in (FIXTURES / name / "config.toml").read_text()
    assert group_by_experiment([read_config(FIXTURES / name) for name in GROUP]) == [[0, 1]]


def test_a_v1_runs_config_toml_trains_anew_as_the_run_it_belongs_to(v1_runs, capsys):
    """`canter train --config RUN/config.toml`, and build_config(None, config_file=...) from Python (the advice for a
    finished run whose only checkpoint is damaged), take a format-1 file, whose sections the algorithm does not read
    would otherwise each be refused."""
    from canter.config.build import build_config
    from canter.run_layout import holds_every_section

    for name in ALGORITHM_RUNS:
        file = FIXTURES / name / "config.toml"
        assert holds_every_section(file)
        assert flat_config(build_config(None, config_file=str(file))) == flat_config(read_config(FIXTURES / name)), name
    run = v1_runs / "ppo"
    shutil.rmtree(run / "checkpoints")  # a finished run kept without its checkpoints
    argv = ["train", "--config", str(run / "config.toml"), "--total-steps", "256", "--out-dir", str(v1_runs / "new")]
    assert main([*argv, "--quiet"]) == 0, capsys.readouterr().err
    [new] = (v1_runs / "new").iterdir()
    given = {"run.total_steps": 256, "run.out_dir": str(v1_runs / "new")}
    assert flat_config(read_config(new)) == flat_config(read_config(run)) | given
    assert not holds_every_section(new / "config.toml"), "a new run writes format 2"


def test_v1_runs_evaluate_plot_report_and_export_without_being_written(v1_runs, tmp_path, capsys, monkeypatch):
    import canter.use.statistics

    # The plot's statistics of 8 runs: few resamples, since what is checked here is that v1 runs are read.
    monkeypatch.setattr(canter.use.statistics, "REPS", 100)
    before = _digest(v1_runs)
    runs = [str(v1_runs / name) for name in ALGORITHM_RUNS + GROUP]
    report_json = tmp_path / "eval.json"
    assert main(["eval", *runs, "--episodes", "2", "--json", str(report_json)]) == 0
    evaluated = json.loads(report_json.read_text())
    assert [r["algo"] for r in evaluated["runs"]] == [*ALGORITHM_RUNS, "ppo", "ppo"]
    # The ppo run (seed 3) and the seed group (0, 1) were trained with one config: one experiment.
    assert len(evaluated["groups"]) == 1 and evaluated["groups"][0]["seeds"] == [3, 0, 1]
    assert main(["plot", *runs, "--out", str(tmp_path / "curves.png")]) == 0
    assert (tmp_path / "curves.png").stat().st_size > 0
    assert (
        main(
            [
                "report",
                str(v1_runs / "ppo"),
                str(v1_runs / "td3"),
                "--episodes",
                "1",
                "--out",
                str(tmp_path / "report.html"),
            ]
        )
        == 0
    )
    assert "td3" in (tmp_path / "report.html").read_text()
    for name in ALGORITHM_RUNS:
        out = tmp_path / f"{name}.npz"
        assert main(["export", str(v1_runs / name), "--out", str(out)]) == 0
        assert np.load(out)["w0"].ndim == 2
    assert _digest(v1_runs) == before


@pytest.mark.parametrize("name", ALGORITHM_RUNS)
def test_a_v1_run_resumes_and_is_migrated(v1_runs, name):
    run = v1_runs / name
    steps = json.loads((run / "summary.json").read_text())["global_step"]
    rows_before = (run / "metrics.csv").read_text().count("\n")
    assert main(["train", "--resume", str(run), "--total-steps", str(steps + 400), "--quiet"]) == 0
    assert json.loads((run / "summary.json").read_text())["global_step"] >= steps + 400
    assert (run / "metrics.csv").read_text().count("\n") > rows_before
    assert run_format(run) == RUN_FORMAT
    text = (run / "config.toml").read_text()
    unread = {"td3", "ddpg", "sac", "trpo", "rpo"} - {name}
    assert not any(f"[{section}]" in text for section in unread)
    # Every key the algorithm reads is kept (the others, such as the ppo.minibatch_size trpo ignores, are dropped).
    assert flat_config(read_config(run)) == flat_config(
        read_config(FIXTURES / name).with_values("run", total_steps=steps + 400)
    )


def test_a_v1_seed_group_resumes_together(v1_runs):
    runs = [str(v1_runs / name) for name in GROUP]
    assert main(["train", "--resume", *runs, "--total-steps", "1800", "--quiet"]) == 0
    for run in runs:
        assert run_format(Path(run)) == RUN_FORMAT
        assert json.loads((Path(run) / "summary.json").read_text())["global_step"] >= 1800


def test_migration_is_one_step_per_version_and_a_newer_format_is_refused(v1_runs):
    run = v1_runs / "sac"
    run_folder.migrate(run)
    assert run_format(run) == 2
    assert "[ppo]" not in (run / "config.toml").read_text()
    versions = json.loads((run / "versions.json").read_text())
    assert versions["run_format"] == 2 and versions["jax"]  # the packages that made the run are kept
    (run / "versions.json").write_text(json.dumps(dict(versions, run_format=RUN_FORMAT + 1)))
    from canter.errors import CanterError

    with pytest.raises(CanterError, match=f"run-folder format {RUN_FORMAT + 1}, this canter reads up to"):
        read_config(run)


def test_a_new_run_folder_records_when_it_was_made(tmp_path):
    """An archive renames run folders, whose names held their date; versions.json keeps it as evidence."""
    from datetime import UTC, datetime

    before = datetime.now(UTC).replace(microsecond=0)
    run_folder.create(tmp_path / "run", read_config(FIXTURES / "sac"))
    created = json.loads((tmp_path / "run" / "versions.json").read_text())["created"]
    assert before <= datetime.strptime(created, "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=UTC) <= datetime.now(UTC)
