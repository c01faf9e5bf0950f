"""Damage inside a run folder, and outputs that cannot go where asked: the error names the damaged file, a resume
repairs what it can with a one-line note, and a folder of a newer canter is refused by every reader alike."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from canter.cli.main import main
from canter.config.serialize import from_toml_text
from canter.errors import CanterError
from canter.training import run_folder
from canter.training.logger import MetricsLogger, read_rows
from canter.training.run_folder import RUN_FORMAT, read_config, run_format
from conftest import ARCHIVED_RUN
from test_damaged_run_files import _one_line_error


def _bad_lr(run: Path) -> None:
    config = run / "config.toml"
    text = config.read_text()
    assert "\nlr = 0.0003\n" in text
    config.write_text(text.replace("\nlr = 0.0003\n", "\nlr = -1\n"))


# ------------------------------------------------------------------------------------ a bad value in config.toml


@pytest.mark.parametrize(
    "command",
    [
        ["plot", "{run}", "--out", "p.png"],
        ["report", "{run}", "--out", "r.html"],
        ["train", "--resume", "{run}", "--total-steps", "4000", "--quiet"],
    ],
    ids=["plot", "report", "resume"],
)
def test_a_bad_value_in_a_run_folders_config_names_the_file(archived_run, capsys, command):
    _bad_lr(archived_run)
    err = _one_line_error(capsys, main([part.format(run=archived_run) for part in command]))
    assert f"ppo.lr must be > 0, got -1.0 (in {archived_run / 'config.toml'})" in err


def test_an_error_that_names_the_file_already_names_it_once(archived_run):
    (archived_run / "config.toml").write_text("[ppo]\nlr = \n")
    with pytest.raises(CanterError) as caught:
        read_config(archived_run)
    assert str(caught.value).count(str(archived_run / "config.toml")) == 1


# -------------------------------------------------------------------------------------- a damaged versions.json


def _damage(run: Path, how: str) -> None:
    path = run / "versions.json"
    if how == "missing":
        path.unlink()
    else:
        cut = path.read_text()[:120]  # ends inside the sixth entry
        path.write_text({"truncated": cut, "empty": "", "list": "[]"}[how])


@pytest.mark.parametrize("how", ["truncated", "empty", "list", "missing"])
def test_a_resume_rewrites_a_damaged_versions_json_with_this_sessions_versions(archived_run, capsys, how):
    _damage(archived_run, how)
    damaged = None if how == "missing" else (archived_run / "versions.json").read_text()
    run_folder.migrate(archived_run)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("canter: note: "), err
    written = json.loads((archived_run / "versions.json").read_text())
    assert written["run_format"] == RUN_FORMAT == run_format(archived_run)
    current = run_folder.versions()
    assert {key: written[key] for key in current} == current
    assert written["repaired"]["text"] == damaged if damaged is not None else "text" not in written["repaired"]
    if how == "missing":  # a folder without the file is format 1, as one without run_format is, and is migrated
        assert "had no versions.json, so it is run format 1" in err
    else:  # nothing is lost: the old text is kept whole
        assert '"repaired"' in err
    assert "[sac]" not in (archived_run / "config.toml").read_text()


def test_a_whole_versions_json_is_kept_without_a_note(archived_run, capsys):
    original = json.loads((archived_run / "versions.json").read_text())
    run_folder.migrate(archived_run)
    assert capsys.readouterr().err == ""
    assert json.loads((archived_run / "versions.json").read_text()) == dict(original, run_format=RUN_FORMAT)


def test_reading_a_damaged_versions_json_writes_nothing(archived_run):
    _damage(archived_run, "truncated")
    before = (archived_run / "versions.json").read_bytes()
    assert run_format(archived_run) == 1 and read_config(archived_run).run.algo == "ppo"
    assert (archived_run / "versions.json").read_bytes() == before


@pytest.mark.slow
def test_a_resume_notes_a_damaged_versions_json_and_a_half_written_row(archived_run, capsys):
    _damage(archived_run, "truncated")
    (archived_run / "checkpoints" / "ckpt_000000001190.npz").unlink()  # killed while it logged the row after 714
    metrics = archived_run / "metrics.csv"
    metrics.write_bytes(metrics.read_bytes()[:-40])
    assert main(["train", "--resume", str(archived_run), "--total-steps", "1600", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert f"canter: note: {archived_run / 'versions.json'} was cut short or not JSON; wrote it" in err
    assert f"canter: note: dropped the half-written last row of {metrics}" in err
    assert json.loads((archived_run / "versions.json").read_text())["run_format"] == RUN_FORMAT


# ------------------------------------------------------------------------------------ metrics.csv cut mid-row


def test_a_half_written_last_row_is_dropped_with_a_note(archived_run, capsys):
    metrics = archived_run / "metrics.csv"
    whole = metrics.read_bytes()
    metrics.write_bytes(whole[:-40])
    steps = [row["global_step"] for row in read_rows(ARCHIVED_RUN / "metrics.csv")[1]]
    # Killed while logging the row after its checkpoint at step 714 (steps: 240, 477, 714, 954, 1190).
    MetricsLogger(archived_run, (), (), tensorboard=False, resume_step=714).close()
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"canter: note: dropped the half-written last row of {metrics}")
    assert "no training is lost: the run goes on from its checkpoint" in err
    assert [row["global_step"] for row in read_rows(metrics)[1]] == steps[:3]  # and the rows after 714 are redone


@pytest.mark.parametrize("cut", ["mid_row", "at_a_row"])
def test_a_file_cut_back_past_its_checkpoints_row_is_refused_untouched(archived_run, cut):
    """Only outside damage cuts the row of the checkpoint a run goes on from: those rows are not logged again, and
    appending after them would hide the gap."""
    metrics = archived_run / "metrics.csv"
    lines = metrics.read_bytes().splitlines(keepends=True)
    metrics.write_bytes(b"".join(lines[:3]) + (lines[3][:20] if cut == "mid_row" else b""))  # rows 240 and 477
    before = metrics.read_bytes()
    with pytest.raises(CanterError) as refused:
        MetricsLogger(archived_run, (), (), tensorboard=False, resume_step=1190)
    assert str(refused.value) == (
        f"{metrics} ends at step 477, before the row of step 1,190 that the checkpoint the run goes on from follows: "
        f"the file was cut back; restore it from a copy, or move it away to resume with rows from step 1,190 on"
    )
    assert metrics.read_bytes() == before


@pytest.mark.parametrize(
    "command", [["train", "--resume", "{run}", "--total-steps", "12000", "--quiet"], ["eval", "{run}"]]
)
def test_a_checkpoint_renamed_to_another_step_is_refused_not_resumed_from(archived_run, capsys, command):
    """Checkpoints are found and ordered by their names: taken as the newest, the step-714 state named as step 9,999
    would be resumed from in silence, its run's rows after 714 dropped, and the real newest pruned later."""
    folder = archived_run / "checkpoints"
    (folder / "ckpt_000000000714.npz").rename(folder / "ckpt_000000009999.npz")
    kept = [*folder.iterdir(), archived_run / "metrics.csv"]
    before = {path: path.read_bytes() for path in kept}
    err = _one_line_error(capsys, main([arg.format(run=archived_run) for arg in command]))
    assert err == (
        f"canter: error: checkpoint {folder / 'ckpt_000000009999.npz'} holds step 714, not the step 9999 its name "
        f"says (renamed or copied over?); rename it to ckpt_000000000714.npz, or move it out of {folder}\n"
    )
    assert {path: path.read_bytes() for path in kept} == before and sorted(folder.iterdir()) == sorted(kept[:-1])


def test_a_whole_metrics_file_gives_no_note(archived_run, capsys):
    MetricsLogger(archived_run, (), (), tensorboard=False, resume_step=1190).close()
    assert capsys.readouterr().err == ""


# ------------------------------------------------------------------------------------ a newer canter's folder


def _future(run: Path) -> None:
    versions = json.loads((run / "versions.json").read_text())
    (run / "versions.json").write_text(json.dumps(dict(versions, run_format=9)))


@pytest.mark.parametrize(
    "command",
    [
        ["eval", "{run}", "--episodes", "1"],
        ["export", "{run}", "--out", "p.npz"],
        ["video", "{run}", "--out", "v.gif"],
        ["eval", "{run}", "--checkpoint", "{run}/checkpoints/ckpt_000000000714.npz", "--episodes", "1"],
    ],
    ids=["eval", "export", "video", "eval-checkpoint-file"],
)
def test_every_reader_refuses_a_folder_of_a_newer_format(archived_run, tmp_path, capsys, command):
    _future(archived_run)
    err = _one_line_error(capsys, main([part.format(run=archived_run) for part in command]))
    assert f"{archived_run} has run-folder format 9, this canter reads up to {RUN_FORMAT}; use a newer canter" in err
    assert not [p for p in tmp_path.iterdir() if p.name != "run"]


def test_canter_load_refuses_a_folder_of_a_newer_format(archived_run):
    import canter

    _future(archived_run)
    with pytest.raises(CanterError, match="run-folder format 9"):
        canter.load(archived_run)


# ---------------------------------------------------------------------------------- outputs that cannot be made


def test_an_export_under_a_file_says_that_it_is_a_file(archived_run, tmp_path, capsys):
    (tmp_path / "exp").mkdir()
    (tmp_path / "exp" / "p.npz").write_bytes(b"kept")
    out = tmp_path / "exp" / "p.npz" / "x.onnx"
    err = _one_line_error(capsys, main(["export", str(archived_run), "--out", str(out)]))
    assert f"cannot write {out}: {tmp_path / 'exp' / 'p.npz'} is a file, not a folder" in err
    assert (tmp_path / "exp" / "p.npz").read_bytes() == b"kept"


def test_an_eval_json_under_a_file_says_that_it_is_a_file(archived_run, tmp_path, capsys):
    (tmp_path / "a").write_text("kept")
    err = _one_line_error(capsys, main(["eval", str(archived_run), "--json", str(tmp_path / "a" / "e.json")]))
    assert f"{tmp_path / 'a'} is a file, not a folder" in err


@pytest.mark.parametrize(
    "argv, flag",
    [(["eval", "{run}", "--json", ""], "--json"), (["export", "{run}", "--out", ""], "--out")],
    ids=["eval-json", "export-out"],
)
def test_an_empty_output_path_is_refused(archived_run, capsys, argv, flag):
    err = _one_line_error(capsys, main([part.format(run=archived_run) for part in argv]))
    assert f"{flag} is empty; give the file to write" in err


def test_a_damaged_versions_json_of_a_newer_canter_stays_refused(archived_run):
    """Cut short, the file of a newer canter read as format 1, and a resume would have migrated its folder."""
    text = f'{{"run_format": {RUN_FORMAT + 1}, "canter": "9.0", "python": "3.1'
    (archived_run / "versions.json").write_text(text)
    with pytest.raises(CanterError, match=f"has run-folder format {RUN_FORMAT + 1}, this canter reads up to"):
        run_folder.migrate(archived_run)
    assert (archived_run / "versions.json").read_text() == text


def test_a_damaged_versions_json_keeps_the_format_it_names(archived_run, capsys):
    (archived_run / "versions.json").write_text(f'{{"run_format": {RUN_FORMAT}, "canter": "0.1')
    assert run_format(archived_run) == RUN_FORMAT
    run_folder.migrate(archived_run)
    assert json.loads((archived_run / "versions.json").read_text())["run_format"] == RUN_FORMAT
    assert "was cut short or not JSON" in capsys.readouterr().err


def test_a_versions_json_of_another_json_type_is_named_as_json_names_it(archived_run, capsys):
    (archived_run / "versions.json").write_text("null")
    run_folder.migrate(archived_run)
    assert "was a JSON null, not an object" in capsys.readouterr().err


@pytest.mark.parametrize("summary", ["missing", "stale"])
def test_a_resume_of_a_run_stopped_before_its_summary_writes_it_and_trains_nothing(archived_run, capsys, summary):
    """A kill between the final checkpoint and summary.json leaves a finished run that job scripts never see finish:
    its resume writes the summary, rather than refusing a run that has its budget."""
    path = archived_run / "summary.json"
    if summary == "missing":
        path.unlink()
    else:  # a summary of an earlier stop, before a resume trained the rest
        path.write_text(json.dumps({**json.loads(path.read_text()), "global_step": 714, "stop_reason": "signal"}))
    checkpoints = sorted((archived_run / "checkpoints").iterdir())
    assert main(["train", "--resume", str(archived_run), "--quiet"]) == 0
    assert (
        f"canter: note: {archived_run} had trained its budget (1,190 steps) but stopped before writing its "
        "summary.json, which is written now from its final checkpoint"
    ) in capsys.readouterr().err
    written = json.loads(path.read_text())
    assert written["global_step"] == 1190 and written["stop_reason"] == "budget" and written["episodes"] == 91
    assert sorted((archived_run / "checkpoints").iterdir()) == checkpoints  # nothing trained
    # With its summary written it is a finished run, which a resume refuses as before.
    assert main(["train", "--resume", str(archived_run), "--quiet"]) == 2
    assert "already has 1190 of run.total_steps=1024 steps; pass a --total-steps" in capsys.readouterr().err


@pytest.mark.parametrize("damage", ["malformed", "missing", "cut", "cut_in_a_number"])
def test_a_resume_of_a_finished_run_with_a_damaged_config_writes_it_again_and_trains_nothing(
    archived_run, capsys, damage
):
    """Every reader of such a config.toml advises `canter train --resume RUN` to write it again: for a finished run
    that is all the resume does, and it succeeds, saying so once. A file cut short at a line's end still reads: its
    lost keys (the budget among them) would take canter's defaults, and the resume would train on to 1M steps."""
    config = archived_run / "config.toml"
    kept = config.read_text()
    if damage == "missing":
        config.unlink()
    elif damage == "cut":
        config.write_text(kept[: kept.index("\ntotal_steps = ") + 1])
    elif damage == "cut_in_a_number":  # `total_steps = 1` of 1024 still parses; the missing newline shows the cut
        config.write_text(kept[: kept.index("\ntotal_steps = ") + len("\ntotal_steps = 1")])
    else:
        config.write_text("[broken")
    summary = (archived_run / "summary.json").read_text()
    checkpoints = sorted((archived_run / "checkpoints").iterdir())
    assert main(["train", "--resume", str(archived_run)]) == 0
    captured = capsys.readouterr()
    told = f"{config} lacks run.total_steps, " if damage.startswith("cut") else "cannot be read"
    assert captured.err.count(told) == 1, captured.err
    assert (
        f"canter: note: {archived_run} has trained its budget (1,190 steps), so nothing is trained: its config.toml "
        "is written again from ckpt_000000001190.npz (pass a larger --total-steps, total_steps= from Python, to train "
        "it on)"
    ) in captured.err
    assert "steps 1,190 |" in captured.out and "stopped: budget" in captured.out
    assert read_config(archived_run) == from_toml_text(kept, "kept")
    assert (archived_run / "summary.json").read_text() == summary
    assert sorted((archived_run / "checkpoints").iterdir()) == checkpoints
    assert main(["plot", str(archived_run), "--out", str(archived_run.parent / "p.png")]) == 0


def test_a_group_resume_writes_the_missing_summaries_of_its_finished_seeds(tmp_path, capsys):
    import shutil

    folders = []
    for seed in (0, 1):
        folder = tmp_path / f"s{seed}"
        shutil.copytree(ARCHIVED_RUN.parent / f"ppo-group-s{seed}", folder)
        (folder / "summary.json").unlink()
        folders.append(str(folder))
    assert main(["train", "--resume", *folders, "--quiet"]) == 0
    err = capsys.readouterr().err
    for folder in folders:
        assert f"canter: note: {folder} had trained its budget" in err
        assert json.loads((Path(folder) / "summary.json").read_text())["stop_reason"] == "budget"


@pytest.mark.parametrize("damage", ["emptied", "header_cut", "rows_gone"])
def test_a_resume_notes_a_metrics_csv_without_rows_and_logs_on_from_its_checkpoint(archived_run, capsys, damage):
    """Logging on after an emptied file without a word would let plot draw the run as if it had begun at its
    checkpoint. Refusing it would refuse a file canter leaves itself (a resume killed before its first row, after the
    file was moved away), so it is a note."""
    metrics = archived_run / "metrics.csv"
    header = metrics.read_text().splitlines()[0]
    metrics.write_text({"emptied": "", "header_cut": header[:20], "rows_gone": header + "\n"}[damage])
    argv = ["train", "--resume", str(archived_run), "--total-steps", "1500", "--quiet"]
    assert main(argv) == 0
    assert (
        f"canter: note: {metrics} has no logged rows, though the run has a checkpoint at step 1,190: the file was "
        f"emptied or damaged; restore it from a copy to keep the rows before step 1,190; the resume logs its rows "
        f"from there"
    ) in capsys.readouterr().err
    steps = [int(row["global_step"]) for row in read_rows(metrics)[1]]
    assert steps and min(steps) > 1190


def _killed_before_its_first_checkpoint(run: Path) -> None:
    """The folder of a run killed while it wrote its first checkpoint: its rows up to that iteration's (714, the first
    past run.checkpoint_every=512), no checkpoint and no summary."""
    import shutil

    shutil.rmtree(run / "checkpoints")
    (run / "summary.json").unlink()
    _killed_before_its_first_checkpoint_rows(run)


@pytest.mark.slow
def test_a_run_killed_before_its_first_checkpoint_resumes_by_training_again_in_its_folder(
    archived_run, tmp_path, capsys
):
    """Nothing of such a run is worth keeping but its config, so --resume trains it again where it is, rather than
    sending the user to another folder; so does a seed of a group killed between the seeds' first checkpoints."""
    _killed_before_its_first_checkpoint(archived_run)
    logged = len(read_rows(archived_run / "metrics.csv")[1])
    assert main(["train", "--resume", str(archived_run), "--quiet"]) == 0
    assert (
        f"canter: note: {archived_run} stopped before its first checkpoint, so it trains again from step 0 in its "
        f"folder (the {logged} metrics rows it had logged are dropped)"
    ) in capsys.readouterr().err
    assert json.loads((archived_run / "summary.json").read_text())["stop_reason"] == "budget"
    assert run_folder.list_checkpoints(archived_run)
    # It trained as it first started: the same rows as a run of its config in a new folder.
    fresh = tmp_path / "fresh"
    assert main(["train", "--config", str(archived_run / "config.toml"), "--out-dir", str(fresh), "--quiet"]) == 0
    [fresh_run] = fresh.iterdir()
    columns = ("global_step", "episodes", "episodic_return", "policy_loss")
    again, new = (read_rows(folder / "metrics.csv")[1] for folder in (archived_run, fresh_run))
    assert [[r[c] for c in columns] for r in again] == [[r[c] for c in columns] for r in new]


@pytest.mark.slow
def test_a_seed_of_a_group_with_no_checkpoint_trains_again_beside_the_others(tmp_path, capsys):
    import shutil

    folders = []
    for seed in (0, 1):
        folder = tmp_path / f"s{seed}"
        shutil.copytree(ARCHIVED_RUN.parent / f"ppo-group-s{seed}", folder)
        folders.append(folder)
    _killed_before_its_first_checkpoint(folders[1])
    steps = json.loads((folders[0] / "summary.json").read_text())["global_step"]
    argv = ["train", "--resume", *map(str, folders), "--total-steps", str(steps + 256), "--quiet"]
    assert main(argv) == 0
    assert f"canter: note: {folders[1]} stopped before its first checkpoint" in capsys.readouterr().err
    for folder in folders:
        assert json.loads((folder / "summary.json").read_text())["global_step"] >= steps + 256


def test_a_missing_summary_is_written_only_for_a_run_that_reached_its_own_budget_with_its_own_config(
    archived_run, capsys
):
    """A lower --total-steps than the run's own, or a Python config that differs from the run's, is refused as
    before: neither may pass for a finished run."""
    import canter

    (archived_run / "checkpoints" / "ckpt_000000001190.npz").unlink()  # killed at 714 on its way to 1024
    stale = {**json.loads((archived_run / "summary.json").read_text()), "global_step": 240, "stop_reason": "signal"}
    (archived_run / "summary.json").write_text(json.dumps(stale))
    assert main(["train", "--resume", str(archived_run), "--total-steps", "500", "--quiet"]) == 2
    assert "already has 714 of run.total_steps=500 steps" in capsys.readouterr().err
    assert json.loads((archived_run / "summary.json").read_text()) == stale
    from canter.training.resume import resume_config

    differing = resume_config(archived_run, 500).with_values("ppo", lr=0.1)
    with pytest.raises(CanterError, match=r"ppo\.lr"):
        canter.train(differing, resume=archived_run)
    assert json.loads((archived_run / "summary.json").read_text()) == stale


def test_a_python_resume_with_another_config_is_refused_before_a_missing_summary_is_written(archived_run):
    import canter
    from canter.training.resume import resume_config

    (archived_run / "summary.json").unlink()
    with pytest.raises(CanterError, match=r"ppo\.lr"):
        canter.train(resume_config(archived_run, None).with_values("ppo", lr=0.1), resume=archived_run)
    assert not (archived_run / "summary.json").exists()


def test_a_resume_refuses_an_archive_of_a_finished_run_and_keeps_it_whole(archived_run, capsys):
    """A finished run kept without its checkpoints is no run stopped before its first: it is not trained again."""
    import shutil

    shutil.rmtree(archived_run / "checkpoints")
    (archived_run / "eval.json").write_text("{}")
    before = sorted(p.relative_to(archived_run) for p in archived_run.rglob("*"))
    assert main(["train", "--resume", str(archived_run), "--quiet"]) == 2
    assert _one_line_error(capsys, 2) == (
        f"canter: error: {archived_run} holds a finished run without its checkpoints (an archive?): it has no policy "
        f"to load or train on; plot reads its metrics, as report does with --episodes 0, and a new run trains it "
        f"again\n"
    )
    assert sorted(p.relative_to(archived_run) for p in archived_run.rglob("*") if p.name != ".writer.lock") == before


def test_a_restart_clears_only_what_canter_wrote_before_a_checkpoint(archived_run):
    import shutil

    shutil.rmtree(archived_run / "checkpoints")
    (archived_run / "summary.json").unlink()
    for name in ("checkpoints/best.npz", "checkpoints/my_notes.txt", "videos/step_000000000240.mp4", "videos/a.txt"):
        (archived_run / name).parent.mkdir(exist_ok=True)
        (archived_run / name).write_text("x")
    run_folder.clear_for_a_restart(archived_run)
    left = sorted(str(p.relative_to(archived_run)) for p in archived_run.rglob("*"))
    assert left == ["checkpoints", "checkpoints/my_notes.txt", "config.toml", "versions.json", "videos", "videos/a.txt"]


def test_a_seed_to_train_again_is_not_cleared_when_another_seed_of_its_group_is_refused(tmp_path, capsys):
    import shutil

    folders = [tmp_path / f"s{seed}" for seed in (0, 1)]
    for seed, folder in enumerate(folders):
        shutil.copytree(ARCHIVED_RUN.parent / f"ppo-group-s{seed}", folder)
    _killed_before_its_first_checkpoint(folders[0])
    newest = run_folder.list_checkpoints(folders[1])[-1]
    newest.write_bytes(newest.read_bytes()[:100])
    rows = (folders[0] / "metrics.csv").read_bytes()
    argv = ["train", "--resume", *map(str, folders), "--total-steps", "4096", "--quiet"]
    assert main(argv) == 2
    assert str(newest) in capsys.readouterr().err
    assert (folders[0] / "metrics.csv").read_bytes() == rows


@pytest.mark.parametrize("kept", ["rows", "best"])
def test_a_run_that_lost_its_checkpoints_is_refused_not_trained_again(archived_run, capsys, kept):
    """Its rows past the first checkpoint, or its best.npz, show that it had checkpoints: training it again would throw
    away what they held."""
    import shutil

    shutil.rmtree(archived_run / "checkpoints")
    (archived_run / "summary.json").unlink()
    if kept == "best":
        _killed_before_its_first_checkpoint_rows(archived_run)
        (archived_run / "checkpoints").mkdir()
        # Of step 1,190, past the rows that are left (up to step 714): training went on past them.
        shutil.copy(ARCHIVED_RUN / "checkpoints" / "ckpt_000000001190.npz", archived_run / "checkpoints" / "best.npz")
    before = {p: p.read_bytes() for p in archived_run.rglob("*") if p.is_file()}
    assert main(["train", "--resume", str(archived_run), "--quiet"]) == 2
    err = _one_line_error(capsys, 2)
    if kept == "rows":
        assert err == (
            f"canter: error: {archived_run} has no checkpoint but has logged rows up to step 1,190, past its first "
            f"checkpoint (run.checkpoint_every=512): its checkpoints were lost; restore them from a copy, or move its "
            f"metrics.csv away to train it again from step 0\n"
        )
    else:
        assert "has no checkpoint but has best.npz, the best policy its evaluations found" in err
    assert {p: p.read_bytes() for p in archived_run.rglob("*") if p.is_file() and p.name != ".writer.lock"} == before


def test_a_best_evaluated_before_the_first_checkpoint_lets_the_run_start_again(archived_run):
    """`--eval-every` below run.checkpoint_every: a run killed after an evaluation, before its first checkpoint, has
    a best.npz of a step its rows reach, and nothing was lost that the restart does not do again."""
    import shutil

    from canter.training import resume

    shutil.rmtree(archived_run / "checkpoints")
    (archived_run / "summary.json").unlink()
    _killed_before_its_first_checkpoint_rows(archived_run)  # rows up to step 714, one past checkpoint_every=512
    (archived_run / "checkpoints").mkdir()
    shutil.copy(ARCHIVED_RUN / "checkpoints" / "ckpt_000000000714.npz", archived_run / "checkpoints" / "best.npz")
    resume._refuse_lost_checkpoints(archived_run, read_config(archived_run))  # not refused
    (archived_run / "metrics.csv").unlink()  # a best.npz with no rows to account for it: lost training
    with pytest.raises(CanterError, match=r"has no checkpoint but has best\.npz"):
        resume._refuse_lost_checkpoints(archived_run, read_config(archived_run))


def _killed_before_its_first_checkpoint_rows(run: Path) -> None:
    lines = (run / "metrics.csv").read_bytes().splitlines(keepends=True)
    (run / "metrics.csv").write_bytes(b"".join(lines[:4]))


def test_a_refused_new_run_keeps_a_users_own_files_in_its_tb_folder(tmp_path, capsys):
    import canter

    run = tmp_path / "project"
    (run / "tb").mkdir(parents=True)
    (run / "tb" / "notes.txt").write_text("mine")
    config = canter.build_config("Pendulum-v1", total_steps=2048, sets=["sym.coef=0.5", "sym.groups=0:1=3:4"])
    with pytest.raises(CanterError):
        canter.train(config, run_dir=run)
    assert (run / "tb" / "notes.txt").read_text() == "mine"


def test_only_a_summary_of_a_finished_run_marks_a_folder_without_checkpoints_as_an_archive(tmp_path):
    """A stop (a signal, even during the compile, or --max-minutes) writes a summary too: such a run can still be
    trained again once its only checkpoint is moved away."""
    from canter.run_layout import finished_without_checkpoints

    (tmp_path / "config.toml").write_text("")
    for reason, finished in [("signal", False), ("max_minutes", False), ("budget", True), ("stop_at_return", True)]:
        (tmp_path / "summary.json").write_text(json.dumps({"global_step": 0, "stop_reason": reason}))
        assert finished_without_checkpoints(tmp_path) is finished, reason
    (tmp_path / "summary.json").write_text("[not a summary")
    assert not finished_without_checkpoints(tmp_path)
    for reason in (["budget"], {"why": "budget"}, 3):  # hand-edited: not a reason canter writes
        (tmp_path / "summary.json").write_text(json.dumps({"global_step": 0, "stop_reason": reason}))
        assert not finished_without_checkpoints(tmp_path), reason
    (tmp_path / "eval.json").write_text("{}")  # only a bench evaluates a run that has finished
    assert finished_without_checkpoints(tmp_path)


@pytest.mark.parametrize(
    "text, read",
    [(None, None), ("{broken", None), ("[1, 2]", None), ("3", None), ('{"global_step": 5}', {"global_step": 5})],
)
def test_one_reader_gives_a_summary_only_when_it_is_a_json_object(tmp_path, text, read):
    """Every reader of summary.json (resume, the group's seeds, report, bench) treats a missing, damaged or
    hand-edited file alike: as none."""
    from canter.run_layout import read_summary

    if text is not None:
        (tmp_path / "summary.json").write_text(text)
    assert read_summary(tmp_path) == read
