"""Whose folder is whose: canter bench refuses a study folder of canter tune, or tune's --out-dir, as its --out, and
tune refuses a bench folder as its --out-dir or study folder, each in one line before it writes anything; a refused
tune leaves no folder it made; and each command still takes its own folder again."""

import json
from pathlib import Path

import optuna
import pytest

from canter.cli.main import main
from canter.errors import CanterError
from canter.orchestrate.bench_folder import bench_files_in, refuse_run_or_study_folder
from canter.orchestrate.study import claim_study, open_storage, study_files_in
from canter.orchestrate.tune import (
    TuneSettings,
    check_settings,
    check_study_settings,
    make_study,
    study_settings,
)
from conftest import error_line

ENV = "Pendulum-v1"
BENCH = ["bench", "--envs", ENV, "--seeds", "0", "--total-steps", "1024", "--episodes", "1"]


def _listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def _tune_study(url: str, name: str, total_steps: int) -> None:
    """A tune study in the storage at `url` with a finished trial, which other settings are refused."""
    settings = TuneSettings(env_id=ENV, total_steps=total_steps, storage_url=url, study_name=name)
    study = make_study(settings, open_storage(settings.storage))
    check_study_settings(study, study_settings(settings, *check_settings(settings)), Path("nowhere"))
    study.add_trial(optuna.trial.create_trial(value=1.0))


def _tune_without_trials(monkeypatch, argv: list[str]) -> int:
    """`canter tune` with its worker left out: the study, its folder and its summary are made, and nothing trains."""
    import canter.orchestrate.tune

    monkeypatch.setattr(canter.orchestrate.tune, "worker", lambda *args: None)
    return main(["tune", ENV, "--trials", "1", *argv])


def test_a_refused_tune_leaves_no_folder_it_made(tmp_path, capsys):
    url = f"sqlite:///{tmp_path / 'shared.db'}"
    _tune_study(url, "s", total_steps=1024)
    out = tmp_path / "new" / "tune"
    argv = ["tune", ENV, "--total-steps", "2048", "--storage", url, "--study", "s", "--out-dir", str(out)]
    err = error_line(capsys, argv)
    assert err.startswith("study 's' was run with --total-steps 1024, but this command gives 2048;"), err
    assert not (tmp_path / "new").exists()

    # Another command's study: refused after the storage is reached, and again nothing is left.
    bench_study = optuna.create_study(storage=url, study_name="grid")
    claim_study(bench_study, "bench")
    argv = ["tune", ENV, "--total-steps", "1024", "--storage", url, "--study", "grid", "--out-dir", str(out)]
    assert "holds a canter bench's jobs" in error_line(capsys, argv)
    assert not (tmp_path / "new").exists()

    # An --out-dir that was there stays, with nothing made in it.
    out.mkdir(parents=True)
    argv = ["tune", ENV, "--total-steps", "2048", "--storage", url, "--study", "s", "--out-dir", str(out)]
    assert "was run with --total-steps 1024" in error_line(capsys, argv)
    assert out.is_dir() and _listing(out) == []


def test_bench_refuses_a_study_folder_of_tune_and_tunes_out_dir(tmp_path, capsys, monkeypatch):
    out = tmp_path / "tune"
    assert _tune_without_trials(monkeypatch, ["--total-steps", "1024", "--out-dir", str(out)]) == 0
    study_dir = out / f"{ENV}__ppo"
    assert study_files_in(study_dir) == ["study.db"]
    before = _listing(out)

    err = error_line(capsys, [*BENCH, "--out", str(study_dir)])
    assert err == (
        f"--out {study_dir} is a study folder of canter tune (it holds study.db), not a bench folder; give a new "
        f"--out, in which the bench makes a run folder for each cell and seed"
    )
    err = error_line(capsys, [*BENCH, "--out", str(out)])
    assert err.startswith(f"--out {out} is an --out-dir of canter tune (it holds the study folder {ENV}__ppo/), "), err
    assert err.endswith("give a new --out, in which the bench makes a run folder for each cell and seed")
    assert _listing(out) == before

    # The study re-run with the same settings is tune's own folder, taken again.
    assert _tune_without_trials(monkeypatch, ["--total-steps", "1024", "--out-dir", str(out)]) == 0
    capsys.readouterr()

    # A study kept in a shared --storage leaves no database in its folder: its trial folders tell it.
    shared = tmp_path / "shared"
    (shared / "trials" / "trial_00000").mkdir(parents=True)
    with pytest.raises(CanterError, match=r"is a study folder of canter tune \(it holds trials/\)"):
        refuse_run_or_study_folder(shared)


def test_bench_takes_its_own_folder_whatever_tune_like_files_it_holds(tmp_path):
    bench_dir = tmp_path / "bench"
    (bench_dir / ".cells").mkdir(parents=True)
    # A bench that shares its grid through a SQLite --storage in its own folder may name it as tune names its own.
    storage = f"sqlite:///{bench_dir / 'study.db'}"
    claim_study(optuna.create_study(storage=storage, study_name="bench"), "bench")
    # Copies of a study's outputs, and a trials/ folder of the user's, are no study folder.
    (bench_dir / "best.toml").write_text("# canter tune: best trial 0\n[ppo]\nlr = 0.001\n")
    (bench_dir / "summary.md").write_text("study 'x': 1 complete\n")
    (bench_dir / "trials").mkdir()
    (bench_dir / "trials" / "notes.txt").write_text("")
    assert study_files_in(bench_dir) == []
    refuse_run_or_study_folder(bench_dir)
    refuse_run_or_study_folder(tmp_path)  # a folder holding a bench folder is no --out-dir of tune
    (bench_dir / "study.db").write_bytes(b"not a database")
    refuse_run_or_study_folder(bench_dir)


def test_tune_refuses_a_bench_folder_as_its_out_dir_or_study_folder(tmp_path, capsys, monkeypatch):
    bench_dir = tmp_path / "bench"
    (bench_dir / ".cells" / f"{ENV}__ppo").mkdir(parents=True)
    (bench_dir / f"{ENV}__ppo__s0").mkdir()
    for name in ("results.md", "results.csv"):
        (bench_dir / name).write_text("")
    before = _listing(bench_dir)
    tune = ["tune", ENV, "--total-steps", "1024", "--trials", "1"]

    err = error_line(capsys, [*tune, "--out-dir", str(bench_dir)])
    assert err == (
        f"--out-dir {bench_dir} is a folder of canter bench (it holds .cells/, results.md and results.csv), not a "
        f"folder for tune studies; give another --out-dir"
    )
    err = error_line(capsys, [*tune, "--out-dir", str(tmp_path), "--study", "bench"])
    assert err == (
        f"the study folder {bench_dir} (--out-dir/--study) is a folder of canter bench (it holds .cells/, "
        f"results.md and results.csv); give another --out-dir or --study"
    )
    assert _listing(bench_dir) == before

    # A bench stopped before its first job holds only its writer lock, which names the bench.
    stopped = tmp_path / "stopped"
    stopped.mkdir()
    (stopped / ".writer.lock").write_text(json.dumps({"pid": 1, "host": "h", "command": "canter bench --out x"}))
    assert bench_files_in(stopped) == ["a bench's .writer.lock"]
    assert "is a folder of canter bench (it holds a bench's .writer.lock)" in error_line(
        capsys, [*tune, "--out-dir", str(stopped)]
    )

    # The user's own notes, or a run's lock, make no bench folder.
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "results.md").write_text("# my results\n")
    (mine / ".writer.lock").write_text(json.dumps({"pid": 1, "host": "h", "command": "canter train Pendulum-v1"}))
    assert bench_files_in(mine) == []
    assert _tune_without_trials(monkeypatch, ["--total-steps", "1024", "--out-dir", str(mine)]) == 0
    assert study_files_in(mine / f"{ENV}__ppo") == ["study.db"]


def test_tune_help_shows_the_heartbeat_default(capsys):
    with pytest.raises(SystemExit) as exited:
        main(["tune", "--help"])
    assert exited.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--heartbeat SECONDS trial heartbeat interval (default 60);" in text
