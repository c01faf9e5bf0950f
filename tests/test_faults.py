"""Faults lose nothing: a full or read-only disk gives one line and keeps the run resumable, and readers skip a
half-written last line of metrics.csv.

The disk tests write to a real, small tmpfs mounted in a private mount namespace (`unshare -m`, which needs root or
user namespaces); where that is not allowed they skip.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import io
import os
import shutil
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from canter.files import WriteError
from canter.training import checkpoint, run_folder
from canter.training.logger import MetricsLogger, Totals, read_rows, totals_until
from canter.training.loop import training_write_error
from conftest import ARCHIVED_RUN
from signals import with_sigint

RUN_SETS = [
    "net.hidden=16,16",  # TINY's, with TensorBoard on: its event files fill the disk too
    "env.num_envs=4",
    "ppo.n_steps=256",
    "ppo.minibatch_size=256",
    "ppo.epochs=2",
    "run.checkpoint_every=1024",
    "run.tensorboard=true",
]
CANTER = f"{sys.executable} -m canter.cli"


def _namespace_script(script: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """Run a shell script in a mount namespace of its own, where it may mount a tmpfs that vanishes with it."""
    probe = subprocess.run(
        ["unshare", "-m", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt"], capture_output=True, text=True
    )
    if probe.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here (unshare -m: {probe.stderr.strip()}); needs root")
    return subprocess.run(
        ["unshare", "-m", "sh", "-c", "set -e\n" + script], capture_output=True, text=True, timeout=timeout
    )


def _one_line_error(stderr: str) -> str:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("canter: error: "), stderr
    return lines[0]


def _whole_csv(path: Path) -> list[dict[str, str]]:
    text = path.read_text()
    assert text.endswith("\n"), f"{path} ends in a half-written line"
    rows = list(csv.DictReader(io.StringIO(text)))
    assert all(None not in row and all(v is not None for v in row.values()) for row in rows)
    return rows


@pytest.mark.slow
def test_a_disk_that_fills_during_training_stops_with_one_line_and_the_run_resumes(tmp_path):
    """96 KiB hold the run's small files and two checkpoints (7 pages each) but not a third: the third periodic
    checkpoint fails with ENOSPC. Growing the tmpfs is the "free space" of the fix; the resume then finishes."""
    disk, saved = tmp_path / "disk", tmp_path / "saved"
    disk.mkdir()
    sets = " ".join(f"--set {s}" for s in RUN_SETS)
    result = _namespace_script(
        f"""
        mount -t tmpfs -o size=96k tmpfs {disk}
        cd {tmp_path}
        rc=0; {CANTER} train Pendulum-v1 --total-steps 4096 {sets} --out-dir {disk} --quiet 2> fail.err || rc=$?
        echo $rc > fail.rc
        cp -a {disk} {saved}
        mount -o remount,size=10m {disk}
        run=$(ls -d {disk}/*)
        rc=0; {CANTER} train --resume $run --quiet > resume.out 2> resume.err || rc=$?
        echo $rc > resume.rc
        cp -a $run {tmp_path}/resumed
        """
    )
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "fail.rc").read_text().strip() == "2"
    warning, error = (tmp_path / "fail.err").read_text().splitlines()
    # Warned at the start: 96 KiB cannot hold keep_checkpoints + 1 checkpoints of this run.
    assert warning.startswith("canter: warning: a checkpoint of this run takes ") and "free space" in warning
    line = _one_line_error(error)
    run = next(saved.iterdir())
    assert "No space left on device" in line and f"free space in {disk}" in line
    assert f"`canter train --resume {disk / run.name}`" in line
    kept = run_folder.list_checkpoints(run)
    assert kept, "the scenario needs a checkpoint written before the disk filled"
    for path in kept:
        checkpoint.read(path)  # whole and passing its hash
    assert not [p for p in run.rglob("*") if p.name.endswith(".tmp")], "no partial file remains"
    _whole_csv(run / "metrics.csv")

    assert (tmp_path / "resume.rc").read_text().strip() == "0", (tmp_path / "resume.err").read_text()
    resumed = tmp_path / "resumed"
    rows = _whole_csv(resumed / "metrics.csv")
    steps = [int(r["global_step"]) for r in rows]
    assert steps == sorted(set(steps)) and steps[-1] >= 4096
    assert (resumed / "summary.json").is_file()


@pytest.mark.slow
def test_metrics_and_tensorboard_keep_whole_records_when_the_disk_fills(tmp_path):
    """Rows go to a 16 KiB tmpfs until a write fails: the error names metrics.csv or the event file, and both keep
    only whole records (the CSV parses to the rows logged before it; TensorBoard reads every event)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    program = f"""
import sys
from pathlib import Path
from canter.errors import CanterError
from canter.training.logger import MetricsLogger
logger = MetricsLogger(Path("{disk}"), ("policy_loss",), (), tensorboard=True)
logged = 0
try:
    for i in range(1, 100000):
        logger.log(dict(global_step=i * 100, iteration=i, wall_time=0.5 * i, sps=1.0, episodes=1,
                        episodic_return=-1.0 * i, episodic_length=200.0, policy_loss=0.125))
        logged = i
except CanterError as exc:
    print(exc, file=sys.stderr)
logger.close()
print(logged)
"""
    (tmp_path / "fill.py").write_text(program)
    result = _namespace_script(
        f"mount -t tmpfs -o size=16k tmpfs {disk}\n{sys.executable} {tmp_path / 'fill.py'}\n"
        f"cp -a {disk} {tmp_path / 'saved'}"
    )
    assert result.returncode == 0, result.stderr
    error = result.stderr.strip()
    assert error.startswith("cannot write ") and "No space left on device" in error, error
    assert "metrics.csv" in error or "tfevents" in error
    logged = int(result.stdout.strip())
    saved = tmp_path / "saved"
    rows = _whole_csv(saved / "metrics.csv")
    # A row whose TensorBoard events did not fit stays in metrics.csv; a resume drops it with the lost work.
    assert logged <= len(rows) <= logged + 1 and [int(r["iteration"]) for r in rows] == list(range(1, len(rows) + 1))
    (events,) = saved.glob("tb/events.out.tfevents.*")
    returns = [(step, value) for tag, step, value in _event_records(events) if tag == "charts/episodic_return"]
    assert len(returns) == logged and all(value == -step / 100 for step, value in returns)


def _event_records(path: Path) -> list[tuple[str, int, float]]:
    """(tag, step, value) of every scalar of an event file, checking that each record is whole (both CRCs)."""
    import struct

    from tensorboardX.proto import event_pb2
    from tensorboardX.record_writer import masked_crc32c

    data, offset, found = path.read_bytes(), 0, []
    while offset < len(data):
        head = data[offset : offset + 8]
        (length,) = struct.unpack("<Q", head)
        assert struct.unpack("<I", data[offset + 8 : offset + 12])[0] == masked_crc32c(head)
        body = data[offset + 12 : offset + 12 + length]
        assert struct.unpack("<I", data[offset + 12 + length : offset + 16 + length])[0] == masked_crc32c(body)
        event = event_pb2.Event.FromString(body)
        found += [(v.tag, event.step, v.simple_value) for v in event.summary.value]
        offset += 16 + length
    return found


@pytest.mark.slow
def test_export_to_a_read_only_disk_is_one_line(tmp_path):
    disk, run = tmp_path / "disk", ARCHIVED_RUN
    disk.mkdir()
    result = _namespace_script(
        f"mount -t tmpfs -o size=1m,ro tmpfs {disk}\n"
        f"rc=0; {CANTER} export {run} --out {disk / 'policy.onnx'} 2> {tmp_path / 'err'} || rc=$?\n"
        f"echo $rc > {tmp_path / 'rc'}; ls -A {disk} > {tmp_path / 'left'}"
    )
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "rc").read_text().strip() == "2"
    line = _one_line_error((tmp_path / "err").read_text())
    assert f"cannot write {disk / 'policy.onnx'}: Read-only file system" in line
    assert (tmp_path / "left").read_text() == ""


def test_readers_skip_a_half_written_last_line_and_the_next_logger_cuts_it(tmp_path):
    metrics = tmp_path / "metrics.csv"
    metrics.write_text(
        "global_step,iteration,wall_time,sps,episodes,episodic_return,episodic_length\n"
        "100,1,1.0,100.0,1,-5.0,100\n"
        "200,2,2.0,100.0,2,-4.0,100\n"
        "30"  # a process killed while writing the third row
    )
    header, rows = read_rows(metrics)
    assert header[0] == "global_step" and [r["global_step"] for r in rows] == ["100", "200"]
    assert totals_until(metrics, 10_000) == Totals(wall_seconds=2.0, train_seconds=2.0, episodes=3)

    from canter.use.curves import read_metrics

    assert list(read_metrics(metrics)["global_step"]) == [100.0, 200.0]

    logger = MetricsLogger(tmp_path, (), (), tensorboard=False, resume_step=200)
    logger.log(dict(global_step=300, iteration=3, wall_time=3.0, sps=100.0, episodes=1, episodic_return=-3.0))
    logger.close()
    assert [r["global_step"] for r in _whole_csv(metrics)] == ["100", "200", "300"]


@pytest.mark.slow
def test_a_video_that_does_not_fit_is_one_line_and_leaves_no_file(tmp_path):
    """ffmpeg reports a failed write only on its stderr; the video is checked before it is renamed into place."""
    disk, run = tmp_path / "disk", ARCHIVED_RUN
    disk.mkdir()
    script = f"mount -t tmpfs -o size=4k tmpfs {disk}\n"
    for name in ("a.mp4", "a.gif"):
        script += (
            f"rc=0; {CANTER} video {run} --episodes 1 --out {disk / name} 2> {tmp_path / name}.err || rc=$?\n"
            f"echo $rc > {tmp_path / name}.rc\n"
        )
    result = _namespace_script(script + f"ls -A {disk} > {tmp_path / 'left'}")
    assert result.returncode == 0, result.stderr
    for name in ("a.mp4", "a.gif"):
        assert (tmp_path / f"{name}.rc").read_text().strip() == "2"
        errors = [line for line in (tmp_path / f"{name}.err").read_text().splitlines() if "canter: error" in line]
        assert errors == [_one_line_error("\n".join(errors))]
        assert f"cannot write {disk / name}" in errors[0] and f"free space in {disk}" in errors[0]
    assert (tmp_path / "left").read_text() == ""


@pytest.mark.parametrize("algo", ["ppo", "td3", "sac"])
def test_a_checkpoints_size_is_known_from_the_state_before_it_is_written(algo, tmp_path):
    """The warning's estimate: a checkpoint file is the state's bytes plus a header of less than HEADER_BYTES."""
    from canter.training.disk_room import HEADER_BYTES, state_bytes
    from canter.training.restore import load_state

    run = Path(__file__).parent / "fixtures" / "runs-v1" / algo
    _, facts, state, header = load_state(run)
    written = tmp_path / "ckpt_000000000001.npz"  # in this canter's format, which the estimate is of
    checkpoint.save(written, state, header)
    assert written.stat().st_size <= state_bytes(state)  # a part-filled buffer is written as far as it is filled
    # The estimate is of the largest file the state gives: with no trailing rows of zeros to leave out.
    checkpoint.save(written, jax.tree_util.tree_map(np.ones_like, state), header)
    size = written.stat().st_size
    assert state_bytes(state) - HEADER_BYTES <= size <= state_bytes(state)
    if algo != "ppo":  # the replay buffer: 4 * (2 * obs_dim + act_dim + 2) bytes per transition of its capacity
        buffer = state.buffer.data
        per_transition = 4 * (2 * facts.obs_dim + facts.act_dim + 2)
        assert sum(leaf.nbytes for leaf in buffer) == per_transition * buffer.reward.shape[0]


def test_damaged_or_foreign_files_in_a_run_folder_are_one_line_errors_or_skipped_with_a_notice(tmp_path, capsys):
    from canter.cli.main import main

    fixtures = Path(__file__).parent / "fixtures" / "runs-v1"

    def folder(name):
        run = tmp_path / name
        shutil.copytree(fixtures / "ppo", run)
        return run

    def one_line(argv, expected):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("canter: error: ") and expected in err, err

    empty = folder("empty_config")
    (empty / "config.toml").write_text("")
    one_line(["plot", str(empty), "--out", str(tmp_path / "a.png")], "config.toml is empty")

    edited = folder("edited_config")
    text = (edited / "config.toml").read_text()
    (edited / "config.toml").write_text(text.replace("num_envs = ", 'num_envs = "sixteen" #', 1))
    refused = (
        f"env.num_envs: expected an integer, got 'sixteen' (in {edited / 'config.toml'}); correct it, or move "
        f"config.toml away and let canter train --resume {edited} (canter.resume_seeds({[str(edited)]!r}) from "
        f"Python) write it again from the newest checkpoint"
    )
    one_line(["plot", str(edited), "--out", str(tmp_path / "a.png")], refused)
    one_line(["train", "--resume", str(edited), "--total-steps", "1e6"], refused)  # edited: not overwritten unasked
    for path in run_folder.list_checkpoints(edited):
        path.unlink()
    one_line(
        ["plot", str(edited), "--out", str(tmp_path / "a.png")], "; correct it, or restore config.toml from a copy"
    )

    folder_named = folder("checkpoint_is_a_folder")
    newest = checkpoint.latest(folder_named)
    newest.unlink()
    newest.mkdir()
    for argv in (["video", str(folder_named), "--out", str(tmp_path / "v.gif")], ["eval", str(folder_named)]):
        one_line(argv, f"checkpoint {newest} is a folder")

    foreign = folder("foreign")
    shutil.copy(checkpoint.latest(fixtures / "rpo"), run_folder.checkpoint_path(foreign, 10**6))
    one_line(["export", str(foreign), "--out", str(tmp_path / "b.onnx")], "if the checkpoint came from another run")

    corrupt = folder("corrupt")
    newest = checkpoint.latest(corrupt)
    newest.write_bytes(newest.read_bytes()[:1000])
    one_line(["export", str(corrupt), "--out", str(tmp_path / "c.onnx")], "move it out of its folder")
    # The fix depends on where the damaged file is: given from elsewhere, or the run's only checkpoint.
    elsewhere = tmp_path / "elsewhere.npz"
    elsewhere.write_bytes(b"not a checkpoint")
    one_line(["eval", str(corrupt), "--checkpoint", str(elsewhere)], "corrupt or truncated; pass a sound one")
    for older in run_folder.list_checkpoints(corrupt)[:-1]:
        older.unlink()
    one_line(["eval", str(corrupt)], "it is the run's only one, so move it away and start the run again with")
    (corrupt / "summary.json").unlink()  # a run stopped before it finished: its resume trains it again in place
    one_line(
        ["eval", str(corrupt)],
        f"it is the run's only one: restore it from a copy, or move it away with the run's metrics.csv, and canter "
        f"train --resume {corrupt} (canter.resume_seeds({[str(corrupt)]!r}) from Python) trains the run again from "
        f"step 0",
    )

    truncated = folder("truncated_metrics")
    (truncated / "metrics.csv").write_text("global_step,iter")
    newest = run_folder.step_of(checkpoint.latest(truncated))
    one_line(
        ["plot", str(truncated), "--out", str(tmp_path / "d.png")],
        f"metrics.csv has no logged rows, though the run has a checkpoint at step {newest:,}: the file was emptied "
        "or damaged; restore it from a copy",
    )
    for path in run_folder.list_checkpoints(truncated):  # a run stopped before its first iteration has none
        path.unlink()
    one_line(
        ["plot", str(truncated), "--out", str(tmp_path / "d.png")],
        "metrics.csv has no logged rows: the run has not finished an iteration (it is compiling, or it stopped "
        "before its first one); leave it out, or train it again",
    )
    renamed = folder("renamed_header")  # once told to "train for at least one iteration"
    text = (renamed / "metrics.csv").read_text()
    (renamed / "metrics.csv").write_text(text.replace("global_step,", "step,", 1))
    one_line(["plot", str(renamed), "--out", str(tmp_path / "d.png")], "has no global_step column in its first line")
    appended = folder("appended_junk")  # once said the file had no global_step column
    with open(appended / "metrics.csv", "a") as f:
        f.write("abc,def,###\n")
    one_line(["plot", str(appended), "--out", str(tmp_path / "d.png")], "has a row whose global_step is 'abc'")
    not_finite = folder("nan_step")
    lines = (not_finite / "metrics.csv").read_text().splitlines(keepends=True)
    lines[2] = "nan" + lines[2][lines[2].index(",") :]
    (not_finite / "metrics.csv").write_text("".join(lines))
    one_line(
        ["plot", str(not_finite), "--out", str(tmp_path / "d.png")], "has a row whose global_step is 'nan' (line 3)"
    )

    locked = folder("lock_is_a_folder")
    (locked / ".writer.lock").mkdir()
    one_line(["train", "--resume", str(locked), "--total-steps", "5000"], "where canter needs a file; move it out")
    no_tb = folder("tb_is_a_file")
    shutil.rmtree(no_tb / "tb", ignore_errors=True)
    (no_tb / "tb").write_text("mine")
    one_line(["train", "--resume", str(no_tb), "--total-steps", "5000"], "where canter needs a folder; move it out")
    assert (no_tb / "tb").read_text() == "mine"

    unknown = folder("unknown_file")
    (unknown / "checkpoints" / "notes.txt").write_text("mine")
    assert main(["export", str(unknown), "--out", str(tmp_path / "e.onnx")]) == 0
    assert capsys.readouterr().err.count("canter: note: skipping ") == 1


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["", "[run\nalgo = 'ppo'\n", None])
def test_a_resume_writes_a_damaged_config_toml_again_from_the_checkpoint(archived_run, capsys, damage):
    """Each checkpoint holds the run's whole config, so an empty, truncated or missing config.toml loses nothing: the
    resume says so in a note, trains from the config of its newest checkpoint and writes config.toml again. (The
    archived run is of format 1, so its migration runs after config.toml is written back.)"""
    from canter.cli.main import main
    from canter.config.serialize import from_toml_text
    from canter.training.run_folder import read_config

    newest = checkpoint.latest(archived_run)
    saved = from_toml_text(checkpoint.read_header(newest)["config"], str(newest))
    path = archived_run / "config.toml"
    path.unlink() if damage is None else path.write_text(damage)
    assert main(["train", "--resume", str(archived_run), "--total-steps", "2048", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert f"canter: note: {path} cannot be read (" in err and f"the config saved in {newest.name}" in err, err
    resumed = read_config(archived_run)
    assert resumed.run.total_steps == 2048 and resumed.replace(run=saved.run) == saved.replace(run=saved.run)
    assert resumed.run.seed == saved.run.seed and resumed.run.algo == saved.run.algo


def test_a_finished_run_s_damaged_config_toml_is_written_again_by_the_resume_its_error_names(archived_run, capsys):
    """plot and report read config.toml, and their error names the resume that repairs it; for a run that has its
    budget, writing it again is all that resume does, and it succeeds."""
    from canter.cli.main import main
    from canter.config.serialize import from_toml_text
    from canter.training.run_folder import read_config

    newest = checkpoint.latest(archived_run)
    saved = from_toml_text(checkpoint.read_header(newest)["config"], str(newest))
    (archived_run / "config.toml").write_text("[run\nalgo = 'ppo'\n")
    assert main(["plot", str(archived_run), "--out", "curves.png"]) == 2
    resume = f"canter train --resume {archived_run} (canter.resume_seeds({[str(archived_run)]!r}) from Python)"
    assert f"let {resume} write it again" in capsys.readouterr().err
    assert main(["train", "--resume", str(archived_run)]) == 0
    assert "so nothing is trained: its config.toml is written again" in capsys.readouterr().err
    assert read_config(archived_run) == saved
    assert main(["plot", str(archived_run), "--out", "curves.png"]) == 0


def test_a_damaged_config_toml_without_a_checkpoint_is_not_sent_to_the_resume(archived_run, capsys):
    from canter.cli.main import main

    shutil.rmtree(archived_run / "checkpoints")
    (archived_run / "config.toml").write_text("[run\n")
    assert main(["plot", str(archived_run), "--out", "curves.png"]) == 2
    err = capsys.readouterr().err
    assert "has no checkpoint that holds its config; restore config.toml from a copy" in err and "--resume" not in err


def test_a_write_error_in_training_names_the_fix_that_continues_the_run(tmp_path):
    run = tmp_path / "run"
    (run / "tb").mkdir(parents=True)  # a training run's folders exist when its writes fail
    full = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    error = training_write_error(OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(run / "config.toml")), [run])
    assert error is not None and str(error) == (
        f"cannot write {run / 'config.toml'}: No space left on device; free space in {run}, then train again "
        f"(no checkpoint was written to resume from)"
    )
    (run / "config.toml").write_text("")  # its resume trains the run again in its folder, not in a new one
    error = training_write_error(OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(run / "metrics.csv")), [run])
    assert error is not None and str(error) == (
        f"cannot write {run / 'metrics.csv'}: No space left on device; free space in {run}, then `canter train "
        f"--resume {run}` (canter.resume_seeds({[str(run)]!r}) from Python), which trains a run without a checkpoint "
        f"again from step 0 in its folder"
    )
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "ckpt_000000001000.npz").write_bytes(b"")
    error = training_write_error(full, [run])
    assert error is not None and str(error).endswith(
        f"then `canter train --resume {run}` (canter.resume_seeds({[str(run)]!r}) from Python)"
    )
    error = training_write_error(WriteError(run / "summary.json", full), [run])
    assert error is not None and "training finished and its last checkpoint is saved" in str(error)
    read_only = OSError(errno.EROFS, os.strerror(errno.EROFS), str(run / "tb" / "events"))
    error = training_write_error(read_only, [run])
    assert error is not None and f"make {run / 'tb'} writable (or pick another path)" in str(error)
    assert training_write_error(ValueError("a bug"), [run]) is None


def test_the_disk_warning_counts_best_and_snapshots_without_the_fields_they_leave_out(tmp_path, monkeypatch, capsys):
    from collections import namedtuple

    import numpy as np

    from canter.config.build import build_config
    from canter.training import disk_room

    State = namedtuple("State", "buffer policy")
    state = State(np.zeros(250_000, np.float32), np.zeros(2_500, np.float32))
    sets = ["run.keep_checkpoints=2", "run.eval_every=1000", "run.video_every=0"]
    config = build_config("Pendulum-v1", algo="td3", sets=sets)
    full, policy = disk_room.state_bytes(state), disk_room.state_bytes({"policy": state.policy})
    # two kept, the next one written before the oldest goes, best.npz and the one it replaced (kept until a checkpoint)
    needed = 3 * full + 2 * policy
    Usage = namedtuple("Usage", "total used free")
    for free, warns in ((needed, False), (needed - 1, True)):
        monkeypatch.setattr(disk_room.shutil, "disk_usage", lambda _, free=free: Usage(0, 0, free))
        assert disk_room.warn_if_checkpoints_will_not_fit([tmp_path], [state], config, ("buffer",)) is warns
    warning = capsys.readouterr().err
    assert warning.count("canter: warning:") == 1
    # The key that sizes the field best.npz leaves out, as td3's size_keys names it, is the other way to make room.
    assert "free space, lower run.keep_checkpoints or td3.buffer_size\n" in warning  # deflating saves little
    assert "a checkpoint of this run takes 990.3 KiB and it needs room for 2.9 MiB of them" in warning
    # A state whose best.npz holds everything needs room for five whole ones.
    monkeypatch.setattr(disk_room.shutil, "disk_usage", lambda _: Usage(0, 0, needed))
    assert disk_room.warn_if_checkpoints_will_not_fit([tmp_path], [state], config)

    # A checkpoint written before training began leaves the buffer out: it takes none of a whole one's room.
    from canter.training import checkpoint

    (tmp_path / "checkpoints").mkdir()
    checkpoint.save(run_folder.checkpoint_path(tmp_path, 0), state, {"global_step": 0}, leave_out=("buffer",))
    monkeypatch.setattr(disk_room.shutil, "disk_usage", lambda _: Usage(0, 0, needed - 1))
    assert disk_room.warn_if_checkpoints_will_not_fit([tmp_path], [state], config, ("buffer",))


def test_the_disk_warning_counts_every_seed_of_a_group_on_one_disk(tmp_path, monkeypatch, capsys):
    """The seeds of a group write their checkpoints side by side: room for one seed's is not room for the group's."""
    from collections import namedtuple

    import numpy as np

    from canter.config.build import build_config
    from canter.training import disk_room

    State = namedtuple("State", "buffer policy")
    state = State(np.zeros(250_000, np.float32), np.zeros(2_500, np.float32))
    config = build_config("Pendulum-v1", algo="td3", sets=["run.keep_checkpoints=2", "run.eval_every=0"])
    one_seed = 3 * disk_room.state_bytes(state)
    run_dirs = [tmp_path / f"s{seed}" for seed in range(4)]
    for run_dir in run_dirs:
        run_dir.mkdir()
    Usage = namedtuple("Usage", "total used free")
    monkeypatch.setattr(disk_room.shutil, "disk_usage", lambda _: Usage(0, 0, 2 * one_seed))
    assert not disk_room.warn_if_checkpoints_will_not_fit(run_dirs[:1], [state], config, ("buffer",))
    assert disk_room.warn_if_checkpoints_will_not_fit(run_dirs, [state] * 4, config, ("buffer",))
    assert capsys.readouterr().err == (
        f"canter: warning: a checkpoint of each of the 4 seeds of this group takes 990.3 KiB and they need room for "
        f"11.6 MiB of them, but {tmp_path} has 5.8 MiB free; free space, lower run.keep_checkpoints or "
        f"td3.buffer_size\n"
    )


def test_the_disk_warning_counts_the_buffer_rows_a_run_can_fill(tmp_path, monkeypatch, capsys):
    """A checkpoint leaves out a buffer's unfilled rows, so a run whose budget is below the buffer's capacity never
    writes a full one: a 10,000-step Humanoid td3 run was warned about room for three 2.66 GiB checkpoints."""
    from collections import namedtuple

    from canter.algos.registry import get_algorithm
    from canter.config.build import build_config
    from canter.training import disk_room
    from canter.training.host_memory import size_text

    State = namedtuple("State", "buffer policy")
    rows, filled = 50_000, 12_345
    empty = State({"obs": np.zeros((rows, 17), np.float32), "done": np.zeros(rows, np.float32)}, np.ones(2_500))
    part = State({name: array.copy() for name, array in empty.buffer.items()}, empty.policy)
    for array in part.buffer.values():
        array[:filled] = 1.0
    written = tmp_path / "part.npz"
    checkpoint.save(written, part, {"global_step": filled})
    # The estimate for `filled` rows is the file a buffer filled that far makes; the whole buffer is 4 times that.
    assert abs(disk_room.state_bytes(empty, {"buffer": filled}) / written.stat().st_size - 1) < 0.01
    assert disk_room.state_bytes(empty) > 3.9 * written.stat().st_size
    # An array under checkpoint.ZERO_TAIL_MIN_BYTES is written whole, and a field without a bound counts whole.
    small = {"obs": np.zeros((100, 17), np.float32)}
    assert disk_room.state_bytes(small, {"obs": 1}) == disk_room.state_bytes(small)
    assert disk_room.state_bytes(empty, {"policy": 1}) == disk_room.state_bytes(empty)

    # td3 counts one row per env step, up to the end of the iteration that reaches the budget.
    td3 = get_algorithm("td3")
    sets = ["run.keep_checkpoints=2", "run.eval_every=0", "td3.steps_per_call=1000", "td3.buffer_size=50000"]
    short = build_config("Pendulum-v1", algo="td3", total_steps=10_000, sets=sets)
    assert td3.filled_rows is not None and td3.filled_rows(short) == {"buffer": 10_000 - 1 + 1000}
    assert td3.filled_rows(short.with_values("run", total_steps=200_000)) == {"buffer": 50_000}
    Usage = namedtuple("Usage", "total used free")
    reached = 3 * disk_room.state_bytes(empty, {"buffer": 10_999})
    monkeypatch.setattr(disk_room.shutil, "disk_usage", lambda _: Usage(0, 0, reached))
    assert not disk_room.warn_if_checkpoints_will_not_fit([tmp_path], [empty], short, ("buffer",))
    long = short.with_values("run", total_steps=200_000)
    assert disk_room.warn_if_checkpoints_will_not_fit([tmp_path], [empty], long, ("buffer",))
    assert f"a checkpoint of this run takes {size_text(disk_room.state_bytes(empty))}" in capsys.readouterr().err


def test_a_second_ctrl_c_during_compilation_exits_130_not_by_a_crash(tmp_path):
    """The first Ctrl-C in a run's compilation is held until it ends; a second one means now, and lands inside the
    compile. The interpreter's shutdown after it could then segfault (exit -11, about half the runs here), or end by
    a further Ctrl-C (exit -2), so an interrupted process skips that shutdown."""
    import signal
    import time

    command = [sys.executable, "-m", "canter.cli", "train", "Hopper-v5", "--total-steps", "1e5"]
    process = subprocess.Popen(
        with_sigint([*command, "--out-dir", str(tmp_path), "--quiet"]), stderr=subprocess.PIPE, text=True
    )
    deadline = time.monotonic() + 120
    while not any(tmp_path.glob("*/metrics.csv")) and time.monotonic() < deadline:  # the compile begins after it
        time.sleep(0.02)
    # Ctrl-C again and again, as a user does: signals that arrive while native code runs are handled once, when
    # Python runs again, so a second one counts only once the first was handled.
    time.sleep(0.5)
    while process.poll() is None and time.monotonic() < deadline:
        process.send_signal(signal.SIGINT)
        time.sleep(0.1)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130 and err.splitlines()[-1] == "canter: interrupted", err[-2000:]
    # The first one said at once what it does (the compile can take many seconds more), and only the first.
    notice = "canter: SIGINT: stopping at the next safe point, with a checkpoint to resume from; Ctrl-C again stops"
    assert err.count(notice) == 1, err[-2000:]


def test_a_stop_flag_says_once_what_the_first_signal_does(capfd):
    import signal

    from canter.signals import StopFlag

    with StopFlag(notice="stopping soon") as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGTERM)
    assert stop.signal == signal.SIGTERM
    assert capfd.readouterr().err == "canter: SIGTERM: stopping soon\n"  # no Ctrl-C hint for a SIGTERM
    with StopFlag() as quiet:
        os.kill(os.getpid(), signal.SIGTERM)
    assert quiet.signal == signal.SIGTERM and capfd.readouterr().err == ""
    # Where stderr is no file (redirected to a StringIO), the notice is dropped and the stop still held.
    with contextlib.redirect_stderr(io.StringIO()), StopFlag(notice="stopping soon") as redirected:
        os.kill(os.getpid(), signal.SIGTERM)
    assert redirected.signal == signal.SIGTERM


def test_the_console_entry_ends_an_interrupted_process_without_the_interpreters_shutdown(monkeypatch):
    """An interrupted process ignores further stop signals as it ends: a Ctrl-C pressed again in its last lines would
    end it by a traceback. So does one whose command returned its code."""
    import signal

    from canter import signals
    from canter.cli import main as cli

    handlers = {sig: signal.getsignal(sig) for sig in signals.STOP_SIGNALS}
    ended = []
    monkeypatch.setattr(cli, "main", lambda: 130)
    monkeypatch.setattr(signals.os, "_exit", lambda code: ended.append(code))
    try:
        with pytest.raises(SystemExit):  # os._exit returned here, so entry goes on to sys.exit
            cli.entry()
        assert ended == [130]
        assert all(signal.getsignal(sig) == signal.SIG_IGN for sig in signals.STOP_SIGNALS)
    finally:  # this process goes on to other tests
        for sig, handler in handlers.items():
            signal.signal(sig, handler)

    monkeypatch.setattr(cli, "main", lambda: 2)
    try:
        with pytest.raises(SystemExit) as exited:
            cli.entry()
        assert exited.value.code == 2 and ended == [130]
        # The code a command returned is the process's: a stop signal in the interpreter's shutdown cannot change it.
        assert all(signal.getsignal(sig) == signal.SIG_IGN for sig in signals.STOP_SIGNALS)
        for sig, handler in handlers.items():  # as a command starts (a test worker may ignore SIGINT)
            signal.signal(sig, signal.default_int_handler if sig == signal.SIGINT else handler)
        signals.interrupt_once()
        # The first Ctrl-C interrupts, as Python's own handler does, and stops the ones after it at that moment: one
        # landing between the interrupt and the process's end cannot end it by a traceback.
        with pytest.raises(KeyboardInterrupt):
            signal.getsignal(signal.SIGINT)(signal.SIGINT, None)
        assert all(signal.getsignal(sig) == signal.SIG_IGN for sig in signals.STOP_SIGNALS)
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a job a script starts with `&`: SIGINT stays ignored
        signals.interrupt_once()
        assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)


@pytest.mark.slow
def test_a_slow_call_is_noted_once_and_a_stop_then_says_how_long_it_waits(tmp_path, monkeypatch, capfd):
    """A call of the jitted program can take minutes (a td3 batch of 100,000), and a signal only waits for it: the
    first slow call says so and names the keys that shorten it, and a later stop says how long each call takes."""
    import signal

    from canter.config.build import build_config
    from canter.training import loop
    from conftest import TINY

    monkeypatch.setattr(loop, "SLOW_CALL_SECONDS", 0.0)
    calls = []

    def progress_then_a_signal(progress, runs, sps):
        calls.append(sps)
        if len(calls) == 1:  # after the stop checks of call 1: the run stops after call 2
            os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(loop, "_show_progress", progress_then_a_signal)
    config = build_config(
        "Pendulum-v1",
        preset="fast",
        total_steps=4096,
        sets=TINY + [f"run.out_dir={tmp_path}", "env.num_envs=4", "ppo.n_steps=64", "ppo.minibatch_size=256"],
    )
    result = loop.train(config)
    err = capfd.readouterr().err
    assert result.stop_reason == "signal" and len(calls) == 2
    notes = [line for line in err.splitlines() if "one call of the training program took" in line]
    assert len(notes) == 1, err
    assert notes[0].startswith("canter: note: ") and notes[0].endswith(
        "give a smaller env.num_envs / ppo.n_steps (now env.num_envs=4, ppo.n_steps=64)"
    )
    assert "canter: SIGTERM: stopping when the current call ends (each takes about " in err
    assert run_folder.list_checkpoints(result.run_dir)  # it stopped with a checkpoint to resume from


@pytest.mark.slow
def test_the_rows_before_a_checkpoint_reach_the_disk_before_it_does(tmp_path, monkeypatch):
    """A checkpoint is fsynced; rows appended without one could be lost to a machine crash while it survives, and the
    resume would then refuse the metrics as cut back before the checkpoint's own row."""
    from canter.config.build import build_config
    from canter.files import AppendFile
    from canter.training.loop import train
    from conftest import TINY

    events: list[str] = []
    synced = AppendFile.sync
    monkeypatch.setattr(AppendFile, "sync", lambda self: (events.append(f"sync {self.path.name}"), synced(self))[1])
    saved = checkpoint.save
    monkeypatch.setattr(
        checkpoint, "save", lambda path, *a, **k: (events.append(f"save {path.name}"), saved(path, *a, **k))[1]
    )
    sets = TINY + [f"run.out_dir={tmp_path}", "env.num_envs=4", "ppo.n_steps=64", "ppo.minibatch_size=256"]
    train(build_config("Pendulum-v1", preset="fast", total_steps=1024, sets=sets + ["run.checkpoint_every=256"]))
    saves = [i for i, event in enumerate(events) if event.startswith("save ckpt_")]
    assert len(saves) >= 2 and all(events[i - 1] == "sync metrics.csv" for i in saves), events


@pytest.mark.slow
def test_a_report_whose_videos_do_not_fit_in_the_temp_folder_names_tmpdir(tmp_path):
    """The report renders its videos in a temp folder under TMPDIR, removed before the error is read: the fix names
    TMPDIR's folder, not the removed one."""
    disk = tmp_path / "disk"
    disk.mkdir()
    script = (
        f"mount -t tmpfs -o size=4k tmpfs {disk}\n"
        f"rc=0; TMPDIR={disk} {CANTER} report {ARCHIVED_RUN} --episodes 0 --video --out {tmp_path / 'page.html'} "
        f"2> {tmp_path / 'err'} || rc=$?\necho $rc > {tmp_path / 'rc'}\nls -A {disk} > {tmp_path / 'left'}\n"
    )
    result = _namespace_script(script)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "rc").read_text().strip() == "2"
    error = _one_line_error((tmp_path / "err").read_text())
    assert f"cannot write the report's videos in {disk}, the temp folder (TMPDIR)" in error, error
    assert "canter-report-" not in error and "set TMPDIR to a folder with room" in error
    assert (tmp_path / "left").read_text() == "" and not (tmp_path / "page.html").exists()
