"""The one-line errors of damaged run folders name the damage and the fix that works for it, not advice for another
case (a --checkpoint that was never given, a run folder that is one)."""

from __future__ import annotations

import shutil

import jax
import numpy as np
import pytest

from canter.errors import CanterError
from canter.training import checkpoint, run_folder
from conftest import ARCHIVED_RUN, error_line


@pytest.mark.parametrize("command", [["plot", "--out", "curves.png"], ["report", "--episodes", "0"]])
def test_a_run_that_lost_its_config_is_told_how_to_get_it_back(command, archived_run, capsys):
    """Each checkpoint holds the run's config, so a resume writes config.toml again; the message once asked whether
    the folder is a run folder at all."""
    (archived_run / "config.toml").unlink()
    line = error_line(capsys, [command[0], str(archived_run), *command[1:]])
    assert line.startswith(f"{archived_run} has no config.toml: the run folder is damaged; restore config.toml"), line
    assert f"let canter train --resume {archived_run} (canter.resume_seeds(" in line
    assert ") from Python) write it again from the newest checkpoint" in line
    assert "is it a canter run folder" not in line


def test_a_run_without_config_or_checkpoints_is_sent_to_a_copy(archived_run, capsys):
    (archived_run / "config.toml").unlink()
    shutil.rmtree(archived_run / "checkpoints")
    line = error_line(capsys, ["plot", str(archived_run), "--out", "curves.png"])
    assert line == (
        f"{archived_run} has no config.toml: the run folder is damaged and has no checkpoint that holds its config; "
        f"restore config.toml from a copy"
    )
    # Nor is it asked whether it is a run where a reader needs its checkpoints too.
    line = error_line(capsys, ["report", str(archived_run), "--episodes", "0"])
    assert line == (
        f"{archived_run} has metrics.csv, summary.json, versions.json but no config.toml and no checkpoint: the run "
        f"folder is damaged; restore its config.toml and checkpoints/ from a copy"
    )


def test_a_folder_with_no_run_file_is_still_asked_whether_it_is_a_run(tmp_path):
    with pytest.raises(CanterError, match=r"has no config.toml; is it a canter run folder\?$"):
        run_folder.read_config(tmp_path)


def test_a_metrics_file_that_is_a_folder_is_named_as_one(archived_run, capsys):
    metrics = archived_run / "metrics.csv"
    metrics.unlink()
    metrics.mkdir()
    line = error_line(capsys, ["plot", str(archived_run), "--out", "curves.png"])
    assert line == f"{metrics} is a folder, not a file; move it away and restore metrics.csv from a copy"


def test_a_folder_with_a_checkpoints_name_is_not_blamed_on_a_checkpoint_flag(archived_run, capsys):
    newest = checkpoint.latest(archived_run)
    newest.unlink()
    newest.mkdir()
    line = error_line(capsys, ["eval", str(archived_run), "--episodes", "1"])  # no --checkpoint given
    assert line == (
        f"checkpoint {newest} is a folder where a checkpoint file should be; move it out of {newest.parent}"
    )
    # best.npz the same, where the run's missing best once read as a run that never evaluated
    checkpoint.best_path(archived_run).mkdir()
    with pytest.raises(CanterError, match="is a folder where a checkpoint file should be"):
        checkpoint.resolve(archived_run, checkpoint.BEST)


def test_a_checkpoint_that_is_a_broken_link_says_so(archived_run, tmp_path, capsys):
    newest = checkpoint.latest(archived_run)
    gone = tmp_path / "elsewhere" / newest.name
    newest.unlink()
    newest.symlink_to(gone)
    line = error_line(capsys, ["eval", str(archived_run), "--episodes", "1"])
    assert line == f"checkpoint {newest} is a link to a missing file ({gone}); remove the link, or restore its target"


@pytest.mark.parametrize("algo", ["ppo", "td3"])
def test_the_disk_warnings_checkpoint_size_is_the_size_written(algo, tmp_path):
    """The estimate once added a 64 KiB header allowance that no file has: 169 KiB quoted for files of 122 KiB."""
    from canter.training.disk_room import state_bytes
    from canter.training.restore import load_state

    run = ARCHIVED_RUN.parent / algo
    _, _, state, _ = load_state(run)
    saved = checkpoint.read_header(checkpoint.latest(run))
    header = {key: value for key, value in saved.items() if key not in ("format_version", "leaves", "sha256")}
    written = tmp_path / "ckpt_000000000001.npz"
    full = jax.tree_util.tree_map(np.ones_like, state)  # the largest file: no trailing zero rows to leave out
    checkpoint.save(written, full, header)
    size = written.stat().st_size
    assert abs(state_bytes(state) / size - 1) < 0.03, (state_bytes(state), size)


@pytest.mark.slow
def test_the_disk_warning_counts_the_episodes_in_flight_of_a_jax_env(tmp_path):
    """A checkpoint of an mjx run also holds its envs' physics state, which on a GPU's thousands of envs outweighs
    the train state: the estimate counts it from the env's shapes."""
    from canter.envs import make_vec_env
    from canter.envs.episodes import init_env_carry
    from canter.training.disk_room import state_bytes
    from canter.training.restore import load_state

    env = make_vec_env("InvertedPendulum-v5", "mjx", 64, list(range(64)))
    carry = init_env_carry(env.initial_state(), env.reset(), env.spec.info_keys)
    _, _, state, _ = load_state(ARCHIVED_RUN)
    saved = checkpoint.read_header(checkpoint.latest(ARCHIVED_RUN))
    header = {key: value for key, value in saved.items() if key not in ("format_version", "leaves", "sha256")}
    written = tmp_path / "ckpt_000000000001.npz"
    checkpoint.save(written, state, header, env_carry=carry)
    estimate = state_bytes(state) + state_bytes(env.state_shapes())
    assert env.state_bytes() > state_bytes(state)  # 64 envs' physics already outweigh a small policy
    assert abs(estimate / written.stat().st_size - 1) < 0.1, (estimate, written.stat().st_size)
