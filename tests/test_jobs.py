"""A bench run's eval.json: the final deterministic evaluation, with every episode's return and length."""

import json
import shutil

import pytest

import canter.use.evaluate
from canter.orchestrate.jobs import write_final_eval
from canter.training import checkpoint

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
    from canter.orchestrate.jobs import gpu_memory_env, job_layout

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
    from canter.orchestrate.jobs import run_status

    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "ckpt_000000004000.npz").write_bytes(b"")
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    assert run_status(tmp_path, 10_000, target) == status
    assert run_status(tmp_path / "missing", 10_000, target) == "new"
