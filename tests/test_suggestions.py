"""The hints of one-line refusals: canter's key for a hyperparameter named as Stable-Baselines3 or CleanRL name it
(in --set, a --config file, a --grid axis and a --space file alike), the closest command to a mistyped one, and
comma lists that refuse an empty entry rather than drop it."""

import argparse

import pytest

from canter.cli.args import comma_entries, seeds_arg
from canter.cli.main import main
from canter.config.build import build_config
from canter.config.overrides import all_keys, key_suggestion, unknown_key_error
from canter.config.peer_names import PEER_NAMES, peer_keys
from canter.errors import CanterError
from canter.orchestrate.bench_grid import parse_grid_arg
from canter.orchestrate.search_space import parse_space
from conftest import ARCHIVED_RUN


def _cli_error(argv, capsys) -> str:
    code = main(argv)
    _out, err = capsys.readouterr()
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, (argv, err)
    return lines[0]


@pytest.mark.parametrize(
    ("key", "suggestion"),
    [
        ("ppo.learning_rate", "did you mean ppo.lr? (Stable-Baselines3's and CleanRL's learning_rate)"),
        ("ppo.learning-rate", "did you mean ppo.lr?"),  # as CleanRL's flag spells it
        ("ppo.n_epochs", "did you mean ppo.epochs? (Stable-Baselines3's n_epochs)"),
        ("ppo.update_epochs", "did you mean ppo.epochs? (CleanRL's update_epochs)"),
        # SB3's PPO batch is one minibatch, as canter's ppo.minibatch_size.
        ("ppo.batch_size", "did you mean ppo.minibatch_size? (Stable-Baselines3's batch_size)"),
        ("ppo.clip_range", "did you mean ppo.clip? (Stable-Baselines3's clip_range)"),
        ("ppo.clip_coef", "did you mean ppo.clip? (CleanRL's clip_coef)"),
        ("ppo.num_steps", "did you mean ppo.n_steps? (CleanRL's num_steps)"),
        ("ppo.total_timesteps", "did you mean run.total_steps?"),
        ("total_timesteps", "did you mean run.total_steps?"),
        ("ppo.num_envs", "did you mean env.num_envs? (CleanRL's num_envs)"),
        ("rpo.learning_rate", "did you mean ppo.lr?"),
        ("trpo.target_kl", "did you mean trpo.max_kl? (SB3-Contrib's target_kl)"),
        ("td3.learning_rate", "did you mean td3.actor_lr and td3.critic_lr? "),
        ("sac.learning_rate", "did you mean sac.actor_lr, sac.critic_lr and sac.alpha_lr?"),
        ("td3.policy_frequency", "did you mean td3.policy_delay? (CleanRL's policy_frequency)"),
        ("td3.policy_noise", "did you mean td3.target_noise? (CleanRL's policy_noise)"),
        ("td3.exploration_noise", "did you mean td3.noise_std? (CleanRL's exploration_noise)"),
        ("sac.ent_coef", "did you mean sac.alpha? (Stable-Baselines3's ent_coef"),
    ],
)
def test_a_peer_libraries_name_suggests_canters_key(key, suggestion):
    assert suggestion in str(unknown_key_error(key, "--set"))


def test_a_peer_name_is_suggested_before_keys_spelled_alike(capsys):
    """ppo.learning_rate was matched by spelling to the off-policy learning_starts keys."""
    line = _cli_error(["train", "Hopper-v5", "--set", "ppo.learning_rate=abc"], capsys)
    assert line == (
        "canter: error: unknown config key 'ppo.learning_rate' in --set (sets= from Python); did you mean ppo.lr? "
        "(Stable-Baselines3's and CleanRL's learning_rate)"
    )


def test_a_peer_name_in_a_config_file_suggests_canters_key(tmp_path):
    path = tmp_path / "config.toml"
    path.write_text("[ppo]\nupdate_epochs = 4\n")
    with pytest.raises(CanterError, match=r"'ppo.update_epochs' in .*; did you mean ppo.epochs\? \(CleanRL's"):
        build_config("Hopper-v5", config_file=str(path))


def test_a_peer_name_in_a_search_space_suggests_canters_key():
    space = {"ppo": {"learning_rate": {"low": 1e-5, "high": 1e-3, "log": True}}}
    with pytest.raises(CanterError) as info:
        parse_space(space, "space.toml")
    assert str(info.value) == (
        "space.toml: unknown hyperparameter 'ppo.learning_rate'; did you mean ppo.lr? "
        "(Stable-Baselines3's and CleanRL's learning_rate)"
    )


def test_a_peer_name_on_a_grid_axis_suggests_canters_key(capsys):
    line = _cli_error(["bench", "--envs", "Hopper-v5", "--grid", "ppo.clip_coef=0.1,0.2"], capsys)
    assert "unknown config key 'ppo.clip_coef' in --grid; did you mean ppo.clip? (CleanRL's clip_coef)" in line


def test_every_peer_name_gives_its_hint():
    """A row whose keys were renamed, or whose name became a canter key, would never give its hint."""
    known = set(all_keys())
    for peer in PEER_NAMES:
        sections = peer.written_under()
        written = [f"{section}.{peer.name}" for section in sections] if sections else [peer.name]
        assert not any(key in known for key in written), peer
        assert any((found := peer_keys(key, known)) is not None and found[0] is peer for key in written), peer


def test_a_key_no_library_names_still_gets_the_closest_keys():
    assert (key_suggestion("ppo.n_step") or "").startswith("did you mean ppo.n_steps,")
    # CleanRL's sac takes policy_frequency actor steps at once, which sac.policy_delay does not: no peer hint.
    assert "CleanRL" not in (key_suggestion("sac.policy_frequency") or "")


@pytest.mark.parametrize(
    ("word", "hint"),
    [
        ("trian", "invalid choice of command: 'trian'; did you mean train? (see --help)"),
        ("evl", "did you mean eval?"),
        ("Bench", "did you mean bench?"),
        ("frobnicate", "commands are train, eval, video, plot, export, report, tune, bench (see --help)"),
    ],
)
def test_a_mistyped_command_gets_the_closest_one(word, hint, capsys):
    assert hint in _cli_error([word, "Hopper-v5"], capsys)


@pytest.mark.parametrize("text", ["0,", ",0", "0,,1", ","])
def test_seeds_refuse_an_empty_entry(text, capsys):
    line = _cli_error(["bench", "--envs", "Hopper-v5", "--seeds", text], capsys)
    assert f"argument --seeds: {text!r} has an empty entry; drop the stray comma" in line


def test_comma_entries_refuse_an_empty_entry_and_keep_the_rest():
    assert comma_entries(" a , b ") == ["a", "b"]
    assert seeds_arg("0, 1") == (0, 1)
    for text in ("a,", "a,,b", ",", " , "):
        with pytest.raises(argparse.ArgumentTypeError, match="has an empty entry"):
            comma_entries(text)


@pytest.mark.parametrize("text", ["ppo.clip=0.1,", "ppo.clip=0.1,,0.2", "ppo.clip=,"])
def test_a_grid_axis_refuses_an_empty_value(text):
    with pytest.raises(CanterError, match=r"has an empty value; drop the stray comma"):
        parse_grid_arg(text)


def test_a_grid_axis_keeps_its_values():
    assert parse_grid_arg(" ppo.clip = 0.1, 0.2 ") == ("ppo.clip", ("0.1", "0.2"))


@pytest.mark.parametrize(
    "argv",
    [
        ["bench", "--envs", "Hopper-v5,"],
        ["bench", "--algos", "ppo,,td3"],
        ["plot", str(ARCHIVED_RUN), "--metrics", ","],
        ["plot", str(ARCHIVED_RUN), "--metrics", "episodic_return,,value_loss"],
    ],
)
def test_name_lists_refuse_an_empty_entry(argv, capsys):
    """Dropped, an entry lost in editing would bench one cell or draw one panel fewer, or fall back to the default."""
    assert "has an empty entry; drop the stray comma or fill in the entry" in _cli_error(argv, capsys)


def test_an_empty_metrics_list_is_refused(capsys):
    line = _cli_error(["plot", str(ARCHIVED_RUN), "--metrics", ""], capsys)
    assert "--metrics is empty; give metrics.csv columns" in line


def test_a_new_algorithm_reading_ppos_rollout_keys_is_told_them_by_peer_name(monkeypatch):
    """The peer names follow what each algorithm reads: a new one that reuses the on-policy rollout, as trpo does,
    is told ppo's keys for CleanRL's names without a line of its own here."""
    import dataclasses

    from canter.config import algorithms

    a2c = dataclasses.replace(algorithms.algorithm_spec("trpo"), name="a2c", reads=("net", "ppo.gamma", "ppo.n_steps"))
    monkeypatch.setitem(algorithms._REGISTERED, "a2c", a2c)
    assert key_suggestion("a2c.gamma") == (
        "did you mean ppo.gamma? (CleanRL's and SB3-Contrib's gamma; a2c reads it from ppo)"
    )
    assert key_suggestion("a2c.num_steps") == "did you mean ppo.n_steps? (CleanRL's num_steps)"
    assert not (key_suggestion("a2c.clip_coef") or "").startswith("did you mean ppo.clip?")  # a2c reads no ppo.clip
