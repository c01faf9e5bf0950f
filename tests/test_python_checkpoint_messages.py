"""A refusal that a caller of the Python API reaches names its fix for that caller too: the command line's form
first, then "(... from Python)", in one line. None of these trains."""

import re
from collections.abc import Callable
from pathlib import Path

import pytest

import canter
from canter.errors import CanterError, DoesNotFitError
from canter.training import checkpoint, run_folder


def refusal(call: Callable[[], object]) -> str:
    with pytest.raises(CanterError) as caught:
        call()
    message = str(caught.value)
    assert "\n" not in message, message
    return message


def resumed_in_python(run: Path) -> str:
    return f"canter train --resume {run} (canter.resume_seeds({[str(run)]!r}) from Python)"


def only_checkpoint_cut_short(run: Path) -> None:
    *older, newest = run_folder.list_checkpoints(run)
    for path in older:
        path.unlink()
    newest.write_bytes(newest.read_bytes()[:1000])


def test_a_folder_given_as_the_checkpoint_names_the_keyword(archived_run, tmp_path):
    message = refusal(lambda: canter.load(archived_run, tmp_path))
    assert message.startswith(
        f"checkpoint {tmp_path} is a folder; --checkpoint (checkpoint= from Python) takes last, best or a .npz file"
    ), message


def test_a_checkpoint_name_that_is_neither_last_nor_best_names_the_keyword(archived_run):
    message = refusal(lambda: canter.load(archived_run, "LAST"))
    assert (
        message == "checkpoint not found: LAST; --checkpoint (checkpoint= from Python) takes last, best or a .npz file"
    )


def test_a_finished_run_s_only_damaged_checkpoint_names_a_new_run_from_python(archived_run):
    only_checkpoint_cut_short(archived_run)
    config = archived_run / "config.toml"
    message = refusal(lambda: canter.load(archived_run))
    assert message.endswith(
        f"start the run again with canter train --config {config} (canter.train(canter.build_config(None, "
        f"config_file={str(config)!r})) from Python)"
    ), message


@pytest.mark.parametrize("call", ["load", "resume_seeds"])
def test_an_unfinished_run_s_only_damaged_checkpoint_names_its_resume_from_python(archived_run, call):
    only_checkpoint_cut_short(archived_run)
    (archived_run / "summary.json").unlink()  # stopped before its budget
    reader = {"load": lambda: canter.load(archived_run), "resume_seeds": lambda: canter.resume_seeds([archived_run])}
    message = refusal(reader[call])
    assert f"{resumed_in_python(archived_run)} trains the run again from step 0" in message, message


def test_a_run_stopped_before_its_first_checkpoint_names_its_resume_from_python(archived_run):
    for path in run_folder.list_checkpoints(archived_run):
        path.unlink()
    (archived_run / "summary.json").unlink()
    message = refusal(lambda: canter.load(archived_run))
    assert f"{resumed_in_python(archived_run)} trains one stopped before that again from step 0" in message, message


def test_a_damaged_best_checkpoint_names_the_last_one_from_python(archived_run):
    checkpoint.best_path(archived_run).write_bytes(b"not a zip")
    message = refusal(lambda: canter.load(archived_run, "best"))
    assert message.endswith("can take --checkpoint last (checkpoint='last' from Python) instead"), message


def test_a_damaged_newest_checkpoint_names_another_file_from_python(archived_run):
    newest = checkpoint.latest(archived_run)
    newest.write_bytes(newest.read_bytes()[:1000])
    message = refusal(lambda: canter.load(archived_run))
    assert message.endswith("take another as --checkpoint FILE (checkpoint=FILE from Python)"), message


def test_an_invalid_value_in_an_edited_config_toml_names_the_resume_that_writes_it_again(archived_run):
    config = archived_run / "config.toml"
    config.write_text(config.read_text().replace("lr = 0.0003", "lr = -1.0", 1))
    edited = config.read_text()
    message = refusal(lambda: canter.resume_seeds([archived_run], total_steps=5000))
    assert message.startswith("ppo.lr must be > 0"), message
    assert message.endswith(
        f"move config.toml away and let {resumed_in_python(archived_run)} write it again from the newest checkpoint"
    ), message
    assert config.read_text() == edited  # edited, so not overwritten unasked


@pytest.mark.parametrize("call", ["load", "resume_seeds"])
def test_a_changed_setting_in_config_toml_names_the_budget_keys_from_python(archived_run, call):
    config = archived_run / "config.toml"
    config.write_text(config.read_text().replace("clip = 0.2", "clip = 0.3", 1))
    reader = {"load": lambda: canter.load(archived_run), "resume_seeds": lambda: canter.resume_seeds([archived_run])}
    message = refusal(reader[call])
    assert " in ppo.clip: if config.toml was edited, put back what the checkpoint holds" in message, message
    assert (
        "a resume changes only the budget: --total-steps, --max-minutes, --stop-at-return (run.total_steps, "
        "run.max_minutes, run.stop_at_return from Python); if the checkpoint came from another run"
    ) in message, message


def test_a_resumed_run_too_large_names_a_new_run_from_its_config_from_python():
    refused = DoesNotFitError("the train state needs about 9.0 GiB", "lower env.num_envs").for_a_resume("r/config.toml")
    assert str(refused).endswith(
        "or lower env.num_envs in a new run from its config: canter train --config r/config.toml "
        "(canter.train(canter.build_config(None, config_file='r/config.toml')) from Python)"
    )


def test_a_divergence_hint_names_the_new_run_from_python():
    from canter.training.seed_run import divergence_hint

    hint = divergence_hint(canter.build_config("Pendulum-v1"))
    assert "(canter train --config, canter.build_config(None, config_file=...) from Python)" in hint, hint


def test_another_algorithm_in_config_toml_is_named_before_the_keys_it_changes(archived_run):
    """With run.algo edited, dozens of the other algorithm's keys differ too; the message shows only three."""
    config = archived_run / "config.toml"
    config.write_text(config.read_text().replace('algo = "ppo"', 'algo = "sac"', 1))
    message = refusal(lambda: canter.load(archived_run))
    assert re.search(r" in run\.algo, sac\.\w+, sac\.\w+ and \d+ more: if config\.toml was edited", message), message
