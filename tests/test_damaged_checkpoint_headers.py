"""A checkpoint whose header parses but is not what canter writes (another JSON value, a config that is no text, a
missing config or env), a checkpoint path that is empty or no regular file, and an empty run folder path: each is
one line that names the problem and its fix, and leaves the run folder as it was."""

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from canter.errors import CanterError
from canter.training import checkpoint
from conftest import ARCHIVED_RUN, error_line


def _newest(run: Path) -> Path:
    return sorted((run / "checkpoints").glob("ckpt_*.npz"))[-1]


def _rewrite_header(path: Path, header: object, rehash: bool) -> None:
    """Replace a checkpoint's header entry, as a tool or a hand edit would; `rehash` gives a dict header a content
    hash that matches it, so that only its fields are wrong."""
    with np.load(path, allow_pickle=False) as data:
        payload = {name: data[name] for name in data.files}
    if rehash:
        assert isinstance(header, dict)
        arrays = {name[5:]: value for name, value in payload.items() if name.startswith("leaf:")}
        whole = header.get("format_version") in checkpoint.WHOLE_FILE_HASH_VERSIONS  # else it holds each array's
        header = dict(header, sha256=checkpoint._digest(arrays, header) if whole else checkpoint._header_digest(header))
    payload["header"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
    with path.open("wb") as f:
        np.savez(f, **payload)


def _saved_header(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as data:
        header = json.loads(bytes(data["header"]).decode())
    header.pop("sha256")
    return header


def _damage(run: Path, kind: str) -> Path:
    """Damage the run's newest checkpoint as `kind` says, its older ones moved away so that none is used instead."""
    newest = _newest(run)
    for older in (run / "checkpoints").glob("ckpt_*.npz"):
        if older != newest:
            older.unlink()
    header = _saved_header(newest)
    if kind == "list":  # no hash needed: a header that is no object has no place for one
        _rewrite_header(newest, [1, 2], rehash=False)
    elif kind == "text":
        _rewrite_header(newest, "str", rehash=False)
    elif kind == "config is a number":
        _rewrite_header(newest, dict(header, config=5), rehash=True)
    elif kind == "config is null":
        _rewrite_header(newest, dict(header, config=None), rehash=True)
    elif kind == "no config":
        _rewrite_header(newest, {k: v for k, v in header.items() if k != "config"}, rehash=True)
    elif kind == "no env":
        _rewrite_header(newest, {k: v for k, v in header.items() if k != "env"}, rehash=True)
    return newest


def _files(folder: Path) -> dict[Path, bytes]:
    """The folder's files, but the writer lock that a resume takes before it reads the checkpoint, and keeps."""
    return {p: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file() and p.name != ".writer.lock"}


KINDS = {
    "list": "is corrupt (its header is not a JSON object)",
    "text": "is corrupt (its header is not a JSON object)",
    "config is a number": "is corrupt (its header's config is not text)",
    "config is null": "is corrupt (its header's config is not text)",
    "no config": "is corrupt (its header holds no config)",
    "no env": "is corrupt (its header lacks the env facts of its policy)",
}
COMMANDS = {
    "eval": lambda run, ckpt: ["eval", str(run), "--episodes", "1"],
    "export": lambda run, ckpt: ["export", str(run), "--out", "x.onnx"],
    "resume": lambda run, ckpt: ["train", "--resume", str(run)],
    "video": lambda run, ckpt: ["video", str(run), "--out", "x.gif"],
    "report": lambda run, ckpt: ["report", str(run), "--out", "r.html", "--episodes", "1"],
    "eval --checkpoint": lambda run, ckpt: ["eval", str(ARCHIVED_RUN), "--checkpoint", str(ckpt), "--episodes", "1"],
}


@pytest.mark.parametrize(("kind", "command"), [(kind, command) for kind in KINDS for command in COMMANDS])
def test_a_header_canter_did_not_write_is_one_line_naming_the_damaged_file(
    archived_run, tmp_path, capsys, kind, command
):
    damaged = _damage(archived_run, kind)
    before = _files(archived_run)
    message = error_line(capsys, COMMANDS[command](archived_run, damaged))
    assert message.startswith(f"checkpoint {damaged} {KINDS[kind]}; "), message
    assert "move it away" in message, message  # the run's only checkpoint: what to do about it
    assert _files(archived_run) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no output file begun


@pytest.mark.parametrize("header", [[1, 2], "str", 7, None])
def test_reading_a_header_that_is_no_object_is_a_damaged_checkpoint(archived_run, header):
    damaged = _newest(archived_run)
    _rewrite_header(damaged, header, rehash=False)
    for read in (checkpoint.read, checkpoint.read_header):
        with pytest.raises(checkpoint.DamagedCheckpoint, match=r"is corrupt \(its header is not a JSON object\)"):
            read(damaged)


def test_a_header_field_of_another_type_is_refused_even_with_a_matching_hash(archived_run):
    damaged = _newest(archived_run)
    _rewrite_header(damaged, dict(_saved_header(damaged), global_step="many"), rehash=True)
    with pytest.raises(checkpoint.DamagedCheckpoint, match=r"its header's global_step is not a whole number"):
        checkpoint.read(damaged)


def test_a_checkpoint_that_is_no_regular_file_is_told_as_such(tmp_path, capsys):
    message = error_line(capsys, ["eval", str(ARCHIVED_RUN), "--checkpoint", os.devnull])
    assert message == (
        f"checkpoint {os.devnull} is not a regular file (a device, pipe or socket); --checkpoint (checkpoint= from "
        f"Python) takes last, best or a .npz file"
    )
    pipe = tmp_path / "c.npz"
    os.mkfifo(pipe)  # reading it would wait for a writer
    assert "is not a regular file" in error_line(capsys, ["eval", str(ARCHIVED_RUN), "--checkpoint", str(pipe)])


def test_a_pipe_named_best_in_a_run_folder_says_to_move_it(archived_run, capsys):
    best = archived_run / "checkpoints" / "best.npz"
    os.mkfifo(best)
    message = error_line(capsys, ["eval", str(archived_run), "--checkpoint", "best"])
    assert message == (
        f"checkpoint {best} is not a regular file (a device, pipe or socket); move it out of {best.parent}"
    )


def test_an_empty_checkpoint_path_is_refused_as_empty(capsys):
    message = error_line(capsys, ["eval", str(ARCHIVED_RUN), "--checkpoint", ""])
    assert message.startswith("the checkpoint given is an empty path; pass last, best or a checkpoint file"), message
    with pytest.raises(CanterError, match="empty path"):
        checkpoint.resolve(ARCHIVED_RUN, " ")


def _a_bench_folder(folder: Path, runs: int) -> None:
    for i in range(runs):
        shutil.copytree(ARCHIVED_RUN, folder / f"seed{i}")


@pytest.mark.parametrize(
    ("argv", "what"),
    [
        (["eval", ""], "eval: an empty path was given as a run folder"),
        (["eval", "seed0", ""], "eval: an empty path was given as a run folder"),
        (["plot", ""], "plot: an empty path was given as a run folder"),
        (["report", "", "--out", "r.html"], "report: an empty path was given as a run folder"),
        (["export", "", "--out", "x.onnx"], "export: an empty path was given as the run folder"),
        (["video", "", "--out", "x.gif"], "video: an empty path was given as the run folder"),
        (["train", "--resume", ""], "train: an empty path was given to --resume"),
    ],
)
def test_an_empty_run_folder_path_is_refused_as_empty_not_read_as_the_working_folder(tmp_path, capsys, argv, what):
    _a_bench_folder(tmp_path, 2)  # the working folder, which '' would have been read as
    before = _files(tmp_path)
    assert error_line(capsys, argv) == f"{what}; give the run folder's path"
    assert _files(tmp_path) == before


@pytest.mark.parametrize("command", [["eval"], ["plot"], ["train", "--resume"]])
@pytest.mark.parametrize(("runs", "held"), [(2, "2 run folders"), (1, "1 run folder")])
def test_a_folder_of_runs_names_what_it_holds(tmp_path, capsys, command, runs, held):
    bench = tmp_path / "bench"
    _a_bench_folder(bench, runs)
    assert error_line(capsys, [*command, str(bench)]) == (
        f"{bench} is not a run folder but holds {held} (a bench's?): pass them, such as {bench / 'seed0'}"
    )
