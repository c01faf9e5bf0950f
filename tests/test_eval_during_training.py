"""Evaluation during training (run.eval_every): the eval/* columns at the right steps with `canter eval`'s
protocol, the best checkpoint (kept through pruning and resume, loaded with checkpoint="best", scored on held-out
seeds), `--checkpoint` on eval, video, export and report, the plot panel, and the bad-input one-liners."""

import csv
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import canter
from canter.cli.main import main
from canter.config.build import build_config
from canter.core.seeding import HELD_OUT
from canter.errors import CanterError
from canter.training import checkpoint, run_folder
from canter.training.evaluation import EVAL_COLUMNS, EvalResult, run_episodes
from canter.training.loop import train
from canter.use.bands import EVAL_PREFIX, experiment_band
from canter.use.curves import RunCurves, load_run
from canter.use.evaluate import seed_stream
from canter.use.experiments import experiments_of
from canter.use.plot import available_metrics, panel_labels
from conftest import TINY

EVERY = 1500  # not a multiple of the 1024-step iterations, so evaluations fall on the first row past each multiple
EPISODES = 3


def eval_config(out, **run_values):
    config = build_config(
        "Pendulum-v1",
        preset="fast",
        total_steps=4096,
        sets=TINY
        + [
            f"run.out_dir={out}",
            "env.num_envs=4",
            "ppo.n_steps=256",
            "ppo.minibatch_size=256",
            "ppo.epochs=2",
            f"run.eval_every={EVERY}",
            f"run.eval_episodes={EPISODES}",
            f"run.checkpoint_every={EVERY}",
            "run.keep_checkpoints=2",
        ],
    )
    return replace(config, run=replace(config.run, **run_values)) if run_values else config


def read_rows(run_dir):
    with open(run_dir / "metrics.csv", newline="") as f:
        reader = csv.DictReader(f)
        return list(reader.fieldnames or []), list(reader)


@pytest.fixture(scope="module")
def eval_run(tmp_path_factory):
    return train(eval_config(tmp_path_factory.mktemp("eval_runs")))


def expected_evaluation_steps(steps, every, total):
    """The rule: the first row at or past each multiple of `every`, and the row that ends the budget."""
    chosen, next_step = [], every
    for step in steps:
        if step >= next_step or step >= total:
            chosen.append(step)
            next_step = (step // every + 1) * every
    return chosen


# ---------------------------------------------------------------------------------------------- the protocol


@pytest.mark.slow
def test_eval_columns_appear_at_the_right_steps(eval_run):
    header, rows = read_rows(eval_run.run_dir)
    assert header[-len(EVAL_COLUMNS) :] == list(EVAL_COLUMNS)
    steps = [int(r["global_step"]) for r in rows]
    evaluated = [int(r["global_step"]) for r in rows if r["eval/return_mean"]]
    assert evaluated == expected_evaluation_steps(steps, EVERY, 4096)
    assert len(evaluated) >= 3 and evaluated[-1] == steps[-1] >= 4096
    for r in rows:
        filled = [bool(r[c]) for c in EVAL_COLUMNS]
        assert all(filled) or not any(filled)  # empty in rows without an evaluation
        if r["eval/episodes"]:
            assert int(r["eval/episodes"]) == EPISODES
            assert float(r["eval/length_mean"]) == 200.0  # full-length Pendulum episodes


@pytest.mark.slow
def test_an_evaluation_during_training_is_canter_eval_of_that_checkpoint(eval_run):
    _, rows = read_rows(eval_run.run_dir)
    by_step = {int(r["global_step"]): r for r in rows if r["eval/return_mean"]}
    kept = run_folder.list_checkpoints(eval_run.run_dir)
    compared = 0
    for path in kept:
        step = int(path.stem.split("_")[1])
        if step not in by_step:
            continue
        policy = canter.load(eval_run.run_dir, checkpoint=path)
        assert seed_stream(policy) == "eval"
        result = canter.evaluate(policy, episodes=EPISODES, seed=0)
        row = by_step[step]
        assert float(row["eval/return_mean"]) == pytest.approx(result.mean, rel=1e-6)
        assert float(row["eval/return_std"]) == pytest.approx(result.std, rel=1e-6, abs=1e-6)
        assert float(row["eval/length_mean"]) == float(result.lengths.mean())
        assert int(row["eval/episodes"]) == result.returns.size
        compared += 1
    assert compared == 2  # an intermediate evaluation and the one at the end


@pytest.mark.slow
def test_evaluation_does_not_change_training(eval_run, tmp_path):
    plain = train(eval_config(tmp_path, eval_every=0))
    header_a, rows_a = read_rows(eval_run.run_dir)
    header_b, rows_b = read_rows(plain.run_dir)
    assert header_a == header_b + list(EVAL_COLUMNS)
    assert not checkpoint.best_path(plain.run_dir).exists()
    skip = {"wall_time", "sps", *EVAL_COLUMNS}
    assert [{k: v for k, v in r.items() if k not in skip} for r in rows_a] == [
        {k: v for k, v in r.items() if k not in skip} for r in rows_b
    ]


# ---------------------------------------------------------------------------------------------- the best state


@pytest.mark.slow
def test_best_checkpoint_survives_pruning_and_loads(eval_run):
    _, rows = read_rows(eval_run.run_dir)
    evaluations = [(int(r["global_step"]), float(r["eval/return_mean"])) for r in rows if r["eval/return_mean"]]
    best_step, best_return = max(evaluations, key=lambda e: e[1])
    assert len(run_folder.list_checkpoints(eval_run.run_dir)) == 2  # keep_checkpoints pruned the older ones
    path = checkpoint.best_path(eval_run.run_dir)
    _, header = checkpoint.read(path)  # atomic and hashed like every checkpoint
    assert header["global_step"] == best_step
    assert header["evaluation"]["return_mean"] == pytest.approx(best_return, rel=1e-9)
    assert header["evaluation"]["episodes"] == EPISODES
    policy = canter.load(eval_run.run_dir, checkpoint="best")
    assert policy.facts.global_step == best_step and policy.checkpoint == "best"
    assert seed_stream(policy) == "held-out"
    assert canter.load(eval_run.run_dir).facts.global_step == evaluations[-1][0]  # load(run) is still the newest


@pytest.mark.slow
def test_a_best_checkpoint_is_scored_on_held_out_seeds(eval_run):
    policy = canter.load(eval_run.run_dir, checkpoint="best")
    result = canter.evaluate(policy, episodes=EPISODES, seed=0)
    by_hand = run_episodes(lambda obs: policy(obs), "Pendulum-v1", policy.facts.backend, EPISODES, 0, HELD_OUT, (3, 1))
    np.testing.assert_array_equal(result.returns, by_hand.returns)
    # Not the episodes that chose it: those gave the score in best.npz's header.
    assert result.mean != policy.selection["return_mean"]


@pytest.mark.slow
def test_resume_keeps_the_best_so_far(tmp_path):
    from canter.training.restore import load_state

    first = train(eval_config(tmp_path, total_steps=2048))
    path = checkpoint.best_path(first.run_dir)
    config, _, state, header = load_state(first.run_dir, "best")
    # A best score that no later evaluation can beat: the resumed run must keep this state and score.
    header = {k: v for k, v in header.items() if k not in ("sha256", "format_version", "leaves")}
    checkpoint.save(path, state, dict(header, evaluation=dict(header["evaluation"], return_mean=1e9)))
    before = path.read_bytes()
    train(replace(config, run=replace(config.run, total_steps=4096)), resume=first.run_dir)
    assert path.read_bytes() == before
    _, rows = read_rows(first.run_dir)
    assert any(r["eval/return_mean"] for r in rows if int(r["global_step"]) > 2048)  # it did evaluate again


@pytest.mark.slow
def test_a_best_saved_after_the_resumed_checkpoint_is_replaced_not_kept(tmp_path, capsys):
    """A process killed between an evaluation's best.npz and its iteration's checkpoint left a best state of training
    that the resume drops and does again: it kept serving --checkpoint best and set the bar for the run."""
    from canter.training.restore import load_state

    first = train(eval_config(tmp_path, total_steps=2048))
    path = checkpoint.best_path(first.run_dir)
    config, _, state, header = load_state(first.run_dir, "best")
    resumed_at = first.global_step
    header = {k: v for k, v in header.items() if k not in ("sha256", "format_version", "leaves")}
    orphan = dict(header, global_step=resumed_at + 512, evaluation=dict(header["evaluation"], return_mean=1e9))
    checkpoint.save(path, state, orphan)
    capsys.readouterr()
    train(replace(config, run=replace(config.run, total_steps=4096)), resume=first.run_dir)
    assert (
        f"canter: note: removed {path} (step {resumed_at + 512:,}, return 1000000000.0): it was saved after the "
        f"checkpoint this resume starts from (step {resumed_at:,})"
    ) in capsys.readouterr().err
    best = checkpoint.read_header(path)
    assert resumed_at < best["global_step"] <= 4096 + 2048 and best["evaluation"]["return_mean"] < 1e9


@pytest.mark.slow
def test_seeds_of_a_group_evaluate_each_on_their_own(tmp_path):
    results = canter.train_seeds(eval_config(tmp_path, total_steps=2048), [0, 1])
    means = []
    for result in results:
        _, rows = read_rows(result.run_dir)
        final = rows[-1]
        assert final["eval/return_mean"] and checkpoint.best_path(result.run_dir).is_file()
        last = canter.evaluate(canter.load(result.run_dir), episodes=EPISODES, seed=0)
        assert float(final["eval/return_mean"]) == pytest.approx(last.mean, rel=1e-6)
        means.append(float(final["eval/return_mean"]))
    assert means[0] != means[1]


# ------------------------------------------------------------------------------------- --checkpoint in commands


@pytest.mark.slow
def test_eval_checkpoint_option_and_json(eval_run, tmp_path, capsys):
    from canter.training.run_folder import read_config

    run = str(eval_run.run_dir)
    out = tmp_path / "eval.json"
    code = main(["eval", run, "--checkpoint", "best", "--episodes", "2", "--json", str(out)])
    printed, err = capsys.readouterr()
    assert code == 0, err
    row = json.loads(out.read_text())["runs"][0]
    assert row["checkpoint"] == "best" and row["seed_stream"] == "held-out"
    assert row["global_step"] == checkpoint.read_header(checkpoint.best_path(eval_run.run_dir))["global_step"]
    assert " best " in printed and "held-out env seeds" in printed
    assert row["eval_seed"] == 0 and row["seed"] == read_config(eval_run.run_dir).run.seed
    assert main(["eval", run, "--episodes", "2", "--seed", "5", "--json", str(out)]) == 0
    row = json.loads(out.read_text())["runs"][0]
    assert row["checkpoint"] == "last" and row["seed_stream"] == "eval" and row["eval_seed"] == 5
    older = run_folder.list_checkpoints(eval_run.run_dir)[0]
    assert main(["eval", run, "--checkpoint", str(older), "--episodes", "2", "--json", str(out)]) == 0
    row = json.loads(out.read_text())["runs"][0]
    assert row["checkpoint"] == str(older) and row["global_step"] == int(older.stem.split("_")[1])
    assert " file " in capsys.readouterr().out


@pytest.mark.slow
def test_export_and_report_take_the_best_checkpoint(eval_run, tmp_path, capsys):
    from canter.use.report import build_report

    run = str(eval_run.run_dir)
    best_step = checkpoint.read_header(checkpoint.best_path(eval_run.run_dir))["global_step"]
    assert main(["export", run, "--checkpoint", "best", "--out", str(tmp_path / "p.npz")]) == 0
    with np.load(tmp_path / "p.npz") as data:
        assert str(data["meta_checkpoint"]) == "best" and int(str(data["meta_global_step"])) == best_step
    page = build_report([run], episodes=1, which="best")
    assert "Best checkpoints (checkpoints/best.npz), on held-out env seeds" in page
    assert f"{best_step:,}" in page or str(best_step) in page
    assert main(["report", run, "--checkpoint", "best", "--episodes", "1", "--out", str(tmp_path / "r.html")]) == 0
    capsys.readouterr()


@pytest.mark.slow
def test_video_of_the_best_checkpoint(eval_run, tmp_path, capsys):
    out = tmp_path / "best.gif"
    argv = ["video", str(eval_run.run_dir), "--checkpoint", "best", "--out", str(out)]
    code = main(argv + ["--width", "32", "--height", "32", "--max-steps", "3"])
    _, err = capsys.readouterr()
    assert code == 0, err
    assert out.stat().st_size > 0


@pytest.mark.slow
def test_best_for_a_run_that_never_evaluated_is_one_line(tiny_run, tmp_path, capsys):
    run = str(tiny_run.run_dir)
    with pytest.raises(CanterError, match="never evaluated during training"):
        canter.load(run, checkpoint="best")
    for argv in (
        ["eval", run, "--checkpoint", "best"],
        ["video", run, "--checkpoint", "best", "--out", str(tmp_path / "a.gif")],
        ["export", run, "--checkpoint", "best", "--out", str(tmp_path / "a.npz")],
        ["report", run, "--checkpoint", "best", "--out", str(tmp_path / "a.html")],
    ):
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2 and "has no best checkpoint" in err and "--eval-every" in err, (argv, err)
        assert err.count("\n") == 1, err


def test_bad_input_is_one_line(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.toml").touch()
    for argv, message in [
        (["train", "Pendulum-v1", "--eval-episodes", "3"], "also pass --eval-every N"),
        (["train", "Pendulum-v1", "--set", "run.eval_backend=auto"], "run.eval_backend sets where the evaluations"),
        (["train", "Pendulum-v1", "--set", "run.eval_episodes=3"], "--set run.eval_episodes sets the episodes of each"),
        (["train", "Pendulum-v1", "--set", "run.eval_every=-1"], "run.eval_every must be >= 0"),
        (["train", "Pendulum-v1", "--eval-every", "1000", "--eval-episodes", "0"], "run.eval_episodes must be >= 1"),
        (["train", "Pendulum-v1", "--eval-every", "0"], "expected a positive whole step count"),
        (
            ["train", "--resume", str(tmp_path), "--eval-every", "1000"],
            "only --total-steps, --max-minutes, --stop-at-return, --quiet,",
        ),
        (["bench", "--envs", "Pendulum-v1", "--eval-episodes", "2"], "final evaluation with --episodes"),
        (["eval", str(tmp_path / "a"), str(tmp_path / "b"), "--checkpoint", "x.npz"], "pass one run folder"),
        (["eval", str(run), "--checkpoint", str(tmp_path / "x.npz")], "checkpoint not found"),
        (["export", str(tmp_path / "none"), "--checkpoint", "best", "--out", "a.npz"], "run folder not found"),
        (["train", "Pendulum-v1", "--set", "run.eval_backend=cpu"], "run.eval_backend must be empty (the run's own)"),
        (["train", "ant", "--backend", "brax", "--set", "run.eval_backend=auto"], "brax runs evaluate on the brax"),
        (
            ["train", "Pendulum-v1", "--eval-every", "1000", "--set", "run.eval_backend=mjx", "--out-dir", "x"],
            "run.eval_backend=mjx cannot play Pendulum-v1 (MJX has no such env)",
        ),
    ]:
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2 and message in err and err.count("\n") == 1, (argv, err)
    assert not Path("x").exists()  # a backend that cannot evaluate the env stops the run before its folder is made


# --------------------------------------------------------------------------------------------------- the plot


def test_eval_columns_become_labelled_panels_after_the_training_return():
    nan = math.nan
    columns = {
        "global_step": np.array([100.0, 200, 300, 400]),
        "episodes": np.array([1.0, 1, 1, 1]),
        "episodic_return": np.array([1.0, 2, 3, 4]),
        "episodic_length": np.array([10.0, 10, 10, 10]),
        "sps": np.array([5.0, 5, 5, 5]),
        "policy_loss": np.array([0.1, 0.2, 0.3, 0.4]),
        "eval/return_mean": np.array([nan, 20, nan, 40]),
        "eval/return_std": np.array([nan, 1, nan, 2]),
        "eval/length_mean": np.array([nan, 200, nan, 200]),
        "eval/episodes": np.array([nan, 10, nan, 10]),
    }
    run = RunCurves(Path("run"), build_config("Pendulum-v1"), columns)
    assert available_metrics([run]) == [
        "episodic_return",
        "eval/return_mean",
        "episodic_length",
        "eval/length_mean",
        "sps",
        "policy_loss",
    ]
    assert panel_labels("eval/return_mean")[0] == "Evaluation return"
    assert panel_labels("eval/length_mean")[0] == "Evaluation episode length"
    # Evaluations are drawn unsmoothed, at their own steps.
    (group,) = experiments_of([run])
    band = experiment_band(group, "eval/return_mean", smooth=3)
    assert band is not None and band.x.tolist() == [200.0, 400.0] and band.mean.tolist() == [20.0, 40.0]
    assert EVAL_PREFIX == "eval/"


@pytest.mark.slow
def test_plot_draws_the_evaluation_return(eval_run, tmp_path, capsys):
    run = load_run(eval_run.run_dir)
    assert "eval/return_mean" in available_metrics([run])
    out = tmp_path / "curves.png"
    assert main(["plot", str(eval_run.run_dir), "--out", str(out), "--metrics", "eval/return_mean"]) == 0
    assert out.stat().st_size > 0
    capsys.readouterr()


def test_eval_result_columns_are_the_eval_columns():
    result = EvalResult(np.array([1.0, 3.0]), np.array([10, 20]), 0.5, "envpool")
    assert result.columns() == {
        "eval/return_mean": 2.0,
        "eval/return_std": 1.0,
        "eval/length_mean": 15.0,
        "eval/episodes": 2,
    }


def _tensorboard_scalars(folder):
    """(tag, step, value) of every scalar in the event files of `folder` (TFRecord framing: length, its CRC, the
    record, its CRC)."""
    import struct

    from tensorboardX.proto import event_pb2

    found = []
    for path in sorted(folder.glob("events.out.tfevents.*")):
        data = path.read_bytes()
        offset = 0
        while offset < len(data):
            (length,) = struct.unpack("<Q", data[offset : offset + 8])
            event = event_pb2.Event.FromString(data[offset + 12 : offset + 12 + length])
            offset += 12 + length + 4
            found += [(v.tag, event.step, v.simple_value) for v in event.summary.value]
    return found


def test_eval_columns_go_to_tensorboard_only_where_there_is_an_evaluation(tmp_path):
    from canter.training.logger import MetricsLogger

    logger = MetricsLogger(tmp_path, ("policy_loss",), (), tensorboard=True, evaluates=True)
    logger.log({"global_step": 100, "iteration": 1, "episodic_return": 1.0, "policy_loss": 0.5})
    logger.log(
        {
            "global_step": 200,
            "iteration": 2,
            "policy_loss": 0.4,
            **EvalResult(np.array([3.0]), np.array([7]), 0, "envpool").columns(),
        }
    )
    logger.close()
    scalars = _tensorboard_scalars(tmp_path / "tb")
    assert [(tag, step) for tag, step, _ in scalars if tag.startswith("eval/")] == [
        ("eval/return_mean", 200),
        ("eval/return_std", 200),
        ("eval/length_mean", 200),
        ("eval/episodes", 200),
    ]
    _, rows = read_rows(tmp_path)
    assert [r["eval/return_mean"] for r in rows] == ["", "3.0"]
