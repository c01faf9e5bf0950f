"""The report pages' timed runs carry on across working sessions: a process stopped by --max-minutes resumes from
its checkpoint on the next call, and the archived wall time is the sum of its processes. Real `canter train`
processes on InvertedPendulum-v4, 1024 steps in iterations of about 500."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks" / "reports"))

import timed

TINY = ["--set", "net.hidden=16,16", "--set", "run.tensorboard=false", "--set", "env.num_envs=4"]
TINY += ["--set", "ppo.n_steps=128", "--set", "ppo.minibatch_size=256", "--set", "ppo.epochs=2"]
ARGS = ["InvertedPendulum-v4", "--algo", "ppo", "--seed", "0", "--total-steps", "1024", *TINY]


@pytest.fixture
def session_limit(monkeypatch):
    # Under a second: each process stops after its first iteration, checkpointed.
    monkeypatch.setattr(timed.SESSIONS, "max_minutes", 0.0001)


def test_a_run_stopped_by_its_session_limit_is_carried_on_and_its_processes_times_summed(
    tmp_path, session_limit, capsys
):
    page, work = tmp_path / "page", tmp_path / "work"
    assert timed.timed_train(page, "run", ARGS, work, episodes=1) is None
    out = work / "run"
    [first] = json.loads((out / timed.SESSIONS_FILE).read_text())
    assert "--max-minutes" in first["command"] and first["wall_seconds"] > 0
    assert "the same command carries it on" in capsys.readouterr().out
    assert timed.archived(page, "run") is None

    found = None
    for _ in range(6):  # each process gets at least one iteration in
        found = found or timed.timed_train(page, "run", ARGS, work, episodes=1)
    assert found is not None
    sessions = found["timing"]["sessions"]
    assert sessions[0]["command"][1:3] == ["train", "InvertedPendulum-v4"]
    assert len(sessions) >= 2 and all(s["command"][1:3] == ["train", "--resume"] for s in sessions[1:])
    assert found["timing"]["wall_seconds"] == pytest.approx(sum(s["wall_seconds"] for s in sessions), abs=0.2)
    assert found["timing"]["command"] == sessions[0]["command"]
    assert found["summary"]["global_step"] >= 1024 and found["summary"]["stop_reason"] == "budget"
    assert found["eval"]["episodes"] == 1
    assert timed.timed_train(page, "run", ARGS, work, episodes=1) == found  # archived: not trained again


def test_a_process_that_ended_without_its_time_recorded_is_not_carried_on(tmp_path):
    out = tmp_path / "run"
    (out / "InvertedPendulum-v4__ppo__s0" / "checkpoints").mkdir(parents=True)
    (out / "InvertedPendulum-v4__ppo__s0" / "checkpoints" / "ckpt_512.npz").write_bytes(b"")
    entry = {"command": ["canter", "train"], "wall_seconds": 12.0, "load_average_before": 0.1, "date": "d"}
    (out / timed.SESSIONS_FILE).write_text(json.dumps([entry]))
    assert timed._sessions(out) == [entry]
    (out / timed.SESSIONS_FILE).write_text(json.dumps([entry, entry | {"wall_seconds": None}]))
    assert timed._sessions(out) == []  # killed: its time is lost, so the run starts again
    assert timed._sessions(tmp_path / "absent") == []
