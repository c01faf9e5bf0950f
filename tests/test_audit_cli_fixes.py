"""Refusals whose reason or fix an audit found wrong: a damaged only checkpoint beside a config.toml that cannot
start the run either, MLflow's refusal of a plain folder as its store, and a search space file or metrics.csv that
is a pipe (refused without waiting on it) or is not UTF-8. None of these trains."""

import os
import shutil
import threading
from pathlib import Path

import pytest

import canter
from canter.errors import CanterError
from canter.training import checkpoint, run_folder
from conftest import error_line

NEW_RUN = (
    "train a new run with the same settings: canter train ENV --set KEY=VALUE ... "
    "(canter.train(canter.build_config('ENV', sets=[...])) from Python)"
)


def _only_checkpoint_cut_short(run: Path, keep_best: bool = False) -> Path:
    """The run's newest checkpoint cut to 10 bytes, its older ones gone (with `keep_best`, the oldest is kept as
    best.npz, the best policy of an evaluation)."""
    *older, newest = run_folder.list_checkpoints(run)
    if keep_best:
        shutil.copy(older[0], checkpoint.best_path(run))
    for path in older:
        path.unlink()
    newest.write_bytes(newest.read_bytes()[:10])
    return newest


def _break_config(run: Path, how: str) -> None:
    config = run / "config.toml"
    if how == "missing":
        config.unlink()
    elif how == "corrupt":
        config.write_text("[ppo")
    else:  # edited to a value canter refuses: it parses, yet starts no run
        config.write_text(config.read_text().replace("lr = 0.0003", "lr = -1.0", 1))


FAULTS = {
    "missing": "its config.toml is missing",
    "corrupt": "its config.toml cannot be read as a config",
    "invalid": "its config.toml cannot be read as a config",
}


@pytest.mark.parametrize("finished", [True, False], ids=["finished", "stopped"])
@pytest.mark.parametrize("how", list(FAULTS))
def test_a_damaged_only_checkpoint_without_a_readable_config_says_nothing_can_be_restored(
    archived_run, capsys, how, finished
):
    newest = _only_checkpoint_cut_short(archived_run)
    _break_config(archived_run, how)
    if not finished:
        (archived_run / "summary.json").unlink()
    expected = (
        f"checkpoint {newest} is corrupt or truncated; it is the run's only one and {FAULTS[how]}, so nothing of "
        f"the run can be restored from its folder: restore the checkpoint or config.toml from a copy, or {NEW_RUN}"
    )
    assert error_line(capsys, ["eval", str(archived_run)]) == expected
    with pytest.raises(CanterError) as refused:  # the Python API's caller reads the same line
        canter.load(archived_run)
    assert str(refused.value) == expected


def test_a_config_restored_from_a_copy_brings_back_the_advice_that_uses_it(archived_run, capsys, tmp_path):
    saved = tmp_path / "config.toml"
    shutil.copy(archived_run / "config.toml", saved)
    newest = _only_checkpoint_cut_short(archived_run)
    _break_config(archived_run, "missing")
    assert "nothing of the run can be restored" in error_line(capsys, ["eval", str(archived_run)])
    shutil.copy(saved, archived_run / "config.toml")
    config = archived_run / "config.toml"
    assert error_line(capsys, ["eval", str(archived_run)]) == (
        f"checkpoint {newest} is corrupt or truncated; it is the run's only one, so move it away and start the run "
        f"again with canter train --config {config} (canter.train(canter.build_config(None, "
        f"config_file={str(config)!r})) from Python)"
    )


def test_a_best_checkpoint_is_named_where_the_only_one_and_config_toml_are_lost(archived_run, capsys):
    newest = _only_checkpoint_cut_short(archived_run, keep_best=True)
    _break_config(archived_run, "missing")
    # report reads config.toml too: only the commands that read the checkpoint alone are named.
    assert error_line(capsys, ["eval", str(archived_run)]) == (
        f"checkpoint {newest} is corrupt or truncated; it is the run's only one and its config.toml is missing, so "
        f"its training cannot go on from its folder: restore the checkpoint or config.toml from a copy, or {NEW_RUN}; "
        f"eval, video and export can take --checkpoint best (checkpoint='best' from Python) instead"
    )


def test_a_stopped_run_s_restart_moves_its_best_checkpoint_away_too(archived_run, capsys):
    # A resume that starts over refuses a best.npz without the rows of its evaluation: the fix moves it as well.
    newest = _only_checkpoint_cut_short(archived_run, keep_best=True)
    (archived_run / "summary.json").unlink()
    assert error_line(capsys, ["eval", str(archived_run)]) == (
        f"checkpoint {newest} is corrupt or truncated; it is the run's only one: restore it from a copy, or move it "
        f"away with the run's metrics.csv and best.npz, and canter train --resume {archived_run} "
        f"(canter.resume_seeds([{str(archived_run)!r}]) from Python) trains the run again from step 0; eval, video, "
        f"export and report can take --checkpoint best (checkpoint='best' from Python) instead"
    )


def test_a_damaged_best_checkpoint_without_periodic_ones_is_the_run_s_only_one(archived_run, capsys):
    best = checkpoint.best_path(archived_run)
    shutil.copy(run_folder.list_checkpoints(archived_run)[0], best)
    for path in run_folder.list_checkpoints(archived_run):
        path.unlink()
    best.write_bytes(best.read_bytes()[:10])
    (archived_run / "summary.json").unlink()
    _break_config(archived_run, "corrupt")
    assert error_line(capsys, ["eval", str(archived_run), "--checkpoint", "best"]) == (
        f"checkpoint {best} is corrupt or truncated; it is the run's only one and its config.toml cannot be read as "
        f"a config, so nothing of the run can be restored from its folder: restore the checkpoint or config.toml "
        f"from a copy, or {NEW_RUN}"
    )


def test_a_run_without_checkpoints_and_a_readable_config_is_not_sent_to_a_resume(archived_run, capsys):
    for path in run_folder.list_checkpoints(archived_run):
        path.unlink()
    (archived_run / "summary.json").unlink()
    _break_config(archived_run, "corrupt")
    assert error_line(capsys, ["eval", str(archived_run)]) == (
        f"no checkpoint in {archived_run} and its config.toml cannot be read as a config, so the run cannot be "
        f"trained again from its folder: restore config.toml or its checkpoints from a copy, or {NEW_RUN}"
    )


# --------------------------------------------------------------------------------------------------------- MLflow

TRAIN = ["train", "InvertedPendulum-v4", "--total-steps", "64", "--out-dir", "runs", "--track", "mlflow"]
FILE_STORE_REFUSED = (
    "cannot be opened (MLflow no longer writes to a plain folder, a file store, unless MLFLOW_ALLOW_FILE_STORE=true "
    "is set); pass e.g. --mlflow-uri sqlite:///mlflow.db"
)


@pytest.mark.parametrize("form", ["path", "file URI"])
def test_a_plain_folder_as_the_mlflow_store_names_mlflow_s_refusal(form, tmp_path, capsys, monkeypatch):
    pytest.importorskip("mlflow")
    monkeypatch.delenv("MLFLOW_ALLOW_FILE_STORE", raising=False)
    uri = str(tmp_path / "mlf") if form == "path" else (tmp_path / "mlf").as_uri()
    assert error_line(capsys, [*TRAIN, "--mlflow-uri", uri]) == f"--mlflow-uri {uri} {FILE_STORE_REFUSED}"
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize("where", ["/proc/canter-no-store", "under-a-file/store"])
def test_a_folder_mlflow_cannot_make_shows_its_own_error(where, tmp_path, capsys, monkeypatch):
    """With file stores allowed, a path MLflow refuses for another reason says that reason."""
    pytest.importorskip("mlflow")
    monkeypatch.setenv("MLFLOW_ALLOW_FILE_STORE", "true")
    (tmp_path / "under-a-file").write_text("")
    uri = where if where.startswith("/") else str(tmp_path / where)
    line = error_line(capsys, [*TRAIN, "--mlflow-uri", uri])
    cause = "No such file or directory" if where.startswith("/") else "Not a directory"
    assert line.startswith(f"--mlflow-uri {uri} cannot be opened (") and cause in line, line
    assert "file store" not in line and line.endswith("); pass e.g. --mlflow-uri sqlite:///mlflow.db"), line


def test_a_long_mlflow_error_is_one_line_of_bounded_length():
    from canter.training.trackers.mlflow_tracker import REASON_CHARS, store_refusal

    reason = store_refusal(RuntimeError("a server said " + "very " * 200 + "much\n<html>a page</html>"))
    assert "\n" not in reason and len(reason) == REASON_CHARS and reason.endswith("..."), reason
    assert store_refusal(RuntimeError("(sqlite3.OperationalError) unable to open\n(Background: ...)")) == (
        "(sqlite3.OperationalError) unable to open"
    )


# ------------------------------------------------------------------------------- pipes and search space files


def _refused_at_once(call) -> CanterError:
    """The refusal `call` raises, which must come without waiting on a pipe."""
    caught: list[BaseException] = []

    def run() -> None:
        try:
            call()
        except BaseException as exc:  # handed back to the test
            caught.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(30)
    assert not thread.is_alive(), "blocked reading a pipe"
    assert len(caught) == 1 and isinstance(caught[0], CanterError), caught
    return caught[0]


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes")
def test_a_search_space_file_that_is_a_pipe_is_not_a_regular_file(capsys):
    os.mkfifo("fifo.toml")
    assert error_line(capsys, ["tune", "Hopper-v5", "--space", "fifo.toml"]) == (
        "search space file fifo.toml is not a regular file (a device, pipe or socket); --space takes a search space "
        "TOML file"
    )


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes")
def test_a_search_space_path_that_turns_into_a_pipe_is_refused_without_blocking(monkeypatch):
    from canter.orchestrate import search_space

    os.mkfifo("fifo.toml")
    monkeypatch.setattr(Path, "is_file", lambda self: True)  # as if it were a file when checked
    refused = _refused_at_once(lambda: search_space.load_space("fifo.toml", "ppo"))
    assert str(refused).startswith("search space file fifo.toml is not a regular file")


def test_a_search_space_file_that_is_not_utf8_is_named_as_one(capsys):
    Path("bin.toml").write_bytes(b"\xff\xfe[ppo.lr]\nlow = 1\n")
    assert error_line(capsys, ["tune", "Hopper-v5", "--space", "bin.toml"]) == (
        "search space file bin.toml is not UTF-8 text; save it as UTF-8, or pass another with --space"
    )


def test_a_malformed_search_space_file_is_still_named(capsys):
    Path("bad.toml").write_text("[ppo.lr\n")
    assert error_line(capsys, ["tune", "Hopper-v5", "--space", "bad.toml"]).startswith("malformed TOML in bad.toml: ")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes")
@pytest.mark.parametrize("command", [["plot", "--out", "curves.png"], ["report", "--episodes", "0"]])
def test_a_metrics_csv_that_is_a_pipe_is_not_a_regular_file(command, archived_run, capsys):
    from canter.use.curves import read_metrics

    metrics = archived_run / "metrics.csv"
    metrics.unlink()
    os.mkfifo(metrics)
    expected = (
        f"{metrics} is not a regular file (a device, pipe or socket); move it away and restore metrics.csv from a copy"
    )
    assert str(_refused_at_once(lambda: read_metrics(metrics))) == expected
    assert error_line(capsys, [command[0], str(archived_run), *command[1:]]) == expected
