"""A bench run's eval.json: the final deterministic evaluation, with every episode's return and length."""

import json
import shutil

import numpy as np
import pytest

import canter.use.evaluate
from canter.orchestrate.jobs import write_final_eval
from canter.training import checkpoint, run_folder

pytestmark = pytest.mark.slow  # tiny_run trains


@pytest.fixture
def run_copy(tiny_run, tmp_path):
    run = tmp_path / tiny_run.run_dir.name
    shutil.copytree(tiny_run.run_dir, run)
    return run


def test_eval_json_holds_every_episodes_return_and_length(run_copy):
    from canter.use.evaluate import evaluate
    from canter.use.policy import load

    written = write_final_eval(run_copy, 3)
    stored = json.loads((run_copy / "eval.json").read_text())
    assert stored == written
    again = evaluate(load(run_copy), episodes=3, deterministic=True, seed=0)
    assert stored["returns"] == pytest.approx(list(again.returns))
    assert stored["lengths"] == [int(n) for n in again.lengths] == [200, 200, 200]  # Pendulum's time limit
    assert stored["mean"] == pytest.approx(again.mean) and stored["std"] == pytest.approx(again.std)
    assert stored["checkpoint"] == checkpoint.latest(run_copy).name and stored["episodes"] == 3
    assert stored["deterministic"] is True and stored["seed"] == 0 and stored["backend"] == "envpool"


def test_a_cached_evaluation_is_kept_unless_it_lacks_lengths(run_copy, monkeypatch):
    first = write_final_eval(run_copy, 2)

    def no_second_evaluation(*args, **kwargs):
        raise AssertionError("evaluated again")

    monkeypatch.setattr(canter.use.evaluate, "evaluate", no_second_evaluation)
    assert write_final_eval(run_copy, 2) == first
    monkeypatch.undo()

    # An eval.json written before lengths were kept, for the same checkpoint, is evaluated again.
    old = {key: first[key] for key in ("checkpoint", "episodes", "mean", "std", "returns")}
    (run_copy / "eval.json").write_text(json.dumps(old))
    assert write_final_eval(run_copy, 2) == first
    assert json.loads((run_copy / "eval.json").read_text())["lengths"] == first["lengths"]


def test_concurrent_jobs_share_a_gpus_memory(monkeypatch):
    from canter.orchestrate.job_resources import gpu_memory_env, job_layout

    monkeypatch.delenv("XLA_PYTHON_CLIENT_MEM_FRACTION", raising=False)
    assert gpu_memory_env(1) == {}  # one job keeps JAX's default
    assert gpu_memory_env(4) == {"XLA_PYTHON_CLIENT_MEM_FRACTION": "0.225"}
    assert all(slot["XLA_PYTHON_CLIENT_MEM_FRACTION"] == "0.450" for slot in job_layout(2))
    monkeypatch.setenv("XLA_PYTHON_CLIENT_MEM_FRACTION", "0.3")
    assert gpu_memory_env(4) == {}  # the user's own setting wins


@pytest.mark.parametrize(
    ("summary", "target", "status"),
    [
        ({"global_step": 10_000, "stop_reason": "budget"}, None, "done"),
        ({"global_step": 4_000, "stop_reason": "stop_at_return", "recent_return": 310.0}, 300.0, "done"),
        ({"global_step": 4_000, "stop_reason": "stop_at_return", "recent_return": 310.0}, 400.0, "partial"),
        ({"global_step": 4_000, "stop_reason": "stop_at_return", "recent_return": 310.0}, None, "partial"),
        ({"global_step": 4_000, "stop_reason": "max_minutes", "recent_return": 310.0}, 300.0, "partial"),
    ],
)
def test_a_run_stopped_at_its_target_return_counts_as_done(tmp_path, summary, target, status):
    """A bench or tune job must not resume a seed that stopped because it reached the target it still has; one that
    stopped on the clock, or whose target was raised since, goes on from its checkpoint."""
    from canter.orchestrate.run_status import run_status

    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "ckpt_000000004000.npz").write_bytes(b"")
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    assert run_status(tmp_path, 10_000, target) == status
    assert run_status(tmp_path / "missing", 10_000, target) == "new"


def test_a_run_that_reached_its_target_toward_another_budget_is_not_this_budgets_result(tmp_path):
    from canter.config.build import build_config
    from canter.config.serialize import to_toml
    from canter.errors import CanterError
    from canter.orchestrate.run_status import run_status

    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "ckpt_000000004000.npz").write_bytes(b"")
    (tmp_path / "config.toml").write_text(to_toml(build_config("Hopper-v5", total_steps=50_000)))
    summary = {"global_step": 4_000, "stop_reason": "stop_at_return", "recent_return": 310.0}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    assert run_status(tmp_path, 50_000, 300.0) == "done"
    with pytest.raises(CanterError, match="toward a budget of 50,000 steps, not this one's 10,000; give --total-steps"):
        run_status(tmp_path, 10_000, 300.0)


def test_a_run_whose_summary_is_missing_or_older_than_its_final_checkpoint(tmp_path):
    """The final checkpoint saved and summary.json not (a full disk, a kill between the two writes): the bench
    writes the summary from the checkpoint rather than failing on a run that has its budget. A run trained on past
    the bench's budget since it finished is refused: the checkpoint at the budget is gone."""
    from canter.config.build import build_config
    from canter.config.serialize import to_toml
    from canter.errors import CanterError
    from canter.orchestrate.run_status import run_status
    from canter.training.resume import summarize_ended_run

    def saved(step, budget):
        config = build_config("Hopper-v5", total_steps=budget)
        totals = {"wall_seconds": 30.0, "train_seconds": 20.0, "episodes": 7, "recent_returns": [1.0, 3.0]}
        header = {"global_step": step, "config": to_toml(config), "totals": totals | {"compile_seconds": 5.0}}
        checkpoint.save(run_folder.checkpoint_path(tmp_path, step), {"x": np.zeros(1)}, header)

    saved(1000, 2000)
    assert run_status(tmp_path, 2000) == "partial"
    saved(2000, 2000)
    assert run_status(tmp_path, 2000) == "ended"
    (tmp_path / "summary.json").write_text(json.dumps({"global_step": 1000, "stop_reason": "max_minutes"}))
    assert run_status(tmp_path, 2000) == "ended"  # stopped once, resumed, and cut before its summary
    result = summarize_ended_run(tmp_path)
    written = json.loads((tmp_path / "summary.json").read_text())
    assert written == {
        "run_dir": str(tmp_path),
        "global_step": 2000,
        "recent_return": 2.0,
        "episodes": 7,
        "wall_seconds": 30.0,
        "compile_seconds": 5.0,
        "sps": 100.0,
        "stop_reason": "budget",
        "trained_with": None,  # not known from a checkpoint
    }
    assert result.global_step == 2000 and run_status(tmp_path, 2000) == "done"

    saved(5000, 40_000)  # resumed by hand toward another budget, and stopped
    past = (
        r"trained on toward a budget of 40,000 steps \(to step 5,000\) after this one's 2,000; give --total-steps 40000"
    )
    with pytest.raises(CanterError, match=past):
        run_status(tmp_path, 2000)
    assert run_status(tmp_path, 40_000) == "partial"
    (tmp_path / "summary.json").write_text(json.dumps({"global_step": 5000, "stop_reason": "max_minutes"}))
    with pytest.raises(CanterError, match=past):  # stopped cleanly: its summary is current, and still not this budget
        run_status(tmp_path, 2000)


def test_a_damaged_newest_checkpoint_never_reads_as_done(tmp_path):
    """Its budget cannot be read, so it cannot be told apart from a run trained toward another: the resume that
    follows reads it and says what is wrong, rather than the bench reusing a cached evaluation."""
    from canter.orchestrate.run_status import run_status

    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "ckpt_000002000000.npz").write_bytes(b"garbage")
    (tmp_path / "summary.json").write_text(json.dumps({"global_step": 2_000_000, "stop_reason": "budget"}))
    assert run_status(tmp_path, 1_000_000) == "partial"
