"""The report pages' timed runs carry on across working sessions: a process stopped before its budget resumes from
its checkpoint on the next call, on a fresh clone too (from the page's in-flight pack), and the archived wall time is
the sum of its processes; a page's --max-minutes stops its processes with SIGTERM; two page commands share the runs
(each claims the run it trains); the cores other work took while a run trained are recorded. Real `canter train`
processes on InvertedPendulum-v4, 1024 steps in iterations of about 500."""

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks" / "reports"))

import timed
from archive import inflight_pack

TINY = ["--set", "net.hidden=16,16", "--set", "run.tensorboard=false", "--set", "env.num_envs=4"]
TINY += ["--set", "ppo.n_steps=128", "--set", "ppo.minibatch_size=256", "--set", "ppo.epochs=2"]
# run.max_minutes under a second: each process stops after its first iteration, checkpointed (a resume keeps it).
ARGS = ["InvertedPendulum-v4", "--algo", "ppo", "--seed", "0", "--total-steps", "1024", *TINY]
ARGS += ["--set", "run.max_minutes=0.0001"]


@pytest.mark.slow  # trains in child processes
def test_a_run_stopped_before_its_budget_is_carried_on_and_its_processes_times_summed(tmp_path, capsys):
    page, work = tmp_path / "page", tmp_path / "work"
    assert timed.timed_train(page, "run", ARGS, work, episodes=1) is None
    out = work / "run"
    [first] = json.loads((out / timed.SESSIONS_FILE).read_text())
    assert first["command"][1:3] == ["train", "InvertedPendulum-v4"] and first["wall_seconds"] > 0
    assert "the same command carries it on" in capsys.readouterr().out
    assert timed.archived(page, "run") is None
    assert inflight_pack(page, "run").is_file()
    shutil.rmtree(work)  # a fresh clone: the page's in-flight pack is all that is left of the run

    found = None
    for _ in range(6):  # each process gets at least one iteration in
        found = found or timed.timed_train(page, "run", ARGS, work, episodes=1)
    assert found is not None
    sessions = found["timing"]["sessions"]
    assert sessions[0] == first  # the process before the fresh clone counts: carried on, not started again
    assert sessions[0]["command"][1:3] == ["train", "InvertedPendulum-v4"]
    assert len(sessions) >= 2 and all(s["command"][1:3] == ["train", "--resume"] for s in sessions[1:])
    assert found["timing"]["wall_seconds"] == pytest.approx(sum(s["wall_seconds"] for s in sessions), abs=0.2)
    assert found["timing"]["command"] == sessions[0]["command"]
    other = sum(s["other_cpu_seconds"] for s in sessions) / found["timing"]["wall_seconds"]
    assert found["timing"]["other_cores"] == pytest.approx(other, abs=0.01)
    assert found["summary"]["global_step"] >= 1024 and found["summary"]["stop_reason"] == "budget"
    assert found["eval"]["episodes"] == 1
    assert not inflight_pack(page, "run").exists()
    inflight_pack(page, "run").write_bytes(b"stale")  # e.g. committed from another clone before this one archived
    assert timed.timed_train(page, "run", ARGS, work, episodes=1) == found  # archived: not trained again
    assert not inflight_pack(page, "run").exists()


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


SLEEPER = """
import signal, sys, time
signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # as canter train: checkpoint, then a clean exit
print("sleeping", flush=True)
time.sleep(60)
"""


def test_the_deadline_stops_a_process_with_sigterm(monkeypatch):
    monkeypatch.setattr(timed.DEADLINE, "at", time.monotonic() + 1.0)
    started = time.monotonic()
    assert timed.run_to_deadline([sys.executable, "-c", SLEEPER]) == (0, True)
    assert time.monotonic() - started < 30
    monkeypatch.setattr(timed.DEADLINE, "at", None)
    assert timed.run_to_deadline([sys.executable, "-c", "raise SystemExit(3)"]) == (3, False)


PAGE_COMMAND = f"""
import sys
sys.path[:0] = [{str(Path(timed.__file__).parent)!r}, {str(Path(timed.__file__).parents[1])!r}]
import timed
timed.stop_on_sigterm()
print(timed.run_to_deadline([sys.executable, "-c", {SLEEPER!r}]), flush=True)
print(timed.out_of_time("next"), flush=True)
"""


def test_sigterm_to_a_page_command_stops_its_training_process_as_its_deadline_would():
    started = time.monotonic()
    with subprocess.Popen([sys.executable, "-c", PAGE_COMMAND], stdout=subprocess.PIPE, text=True) as page:
        assert page.stdout is not None
        # The sleeper is running, with its handler (a loaded machine may take seconds to get there).
        assert page.stdout.readline() == "sleeping\n"
        page.send_signal(signal.SIGTERM)
        out, _ = page.communicate(timeout=30)
    assert page.returncode == 0 and time.monotonic() - started < 30
    # The child stopped cleanly, by the deadline, and nothing new starts.
    assert out.splitlines() == ["(0, True)", "next: past this command's --max-minutes; not started", "True"]


def test_nothing_starts_past_the_deadline(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(timed.DEADLINE, "at", time.monotonic() - 1.0)
    assert timed.timed_train(tmp_path / "page", "run", ARGS, tmp_path / "work") is None
    assert not (tmp_path / "work").exists()
    assert "past this command's --max-minutes; not started" in capsys.readouterr().out


HOLD_LOCK = """
import sys
from canter.training import run_lock
run_lock.acquire(sys.argv[1])
print("held", flush=True)
sys.stdin.read()
"""


def _holder(folder: Path) -> subprocess.Popen:
    """Another process that holds `folder`'s writer lock until it is killed."""
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD_LOCK, str(folder)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_claim_is_refused_while_another_process_holds_it_and_taken_over_when_it_dies(tmp_path):
    folder = timed.claim_dir(tmp_path / "work", "run")
    holder = _holder(folder)
    try:
        assert not timed.claim(folder)
    finally:
        holder.kill()  # SIGKILL: the holder cannot release anything itself
        holder.wait()
    assert timed.claim(folder)
    timed.run_lock.release(folder)


def test_a_run_another_page_command_trains_is_skipped(tmp_path, capsys):
    work = tmp_path / "work"
    holder = _holder(timed.claim_dir(work, "run"))
    try:
        assert timed.timed_train(tmp_path / "page", "run", ARGS, work) is None
    finally:
        holder.kill()
        holder.wait()
    assert f"another process is training it ({holder.pid})" in capsys.readouterr().out
    assert not (work / "run").exists()


def test_other_work_is_the_machines_busy_time_less_the_childrens(monkeypatch):
    machine, children = iter([100.0, 110.0]), iter([5.0, 8.0])
    monkeypatch.setattr(timed, "_busy_cpu_seconds", lambda: next(machine))
    monkeypatch.setattr(timed, "_children_cpu_seconds", lambda: next(children))
    with timed.OtherWork() as other:
        pass
    assert other.cpu_seconds == 7.0


def test_the_machines_busy_time_counts_a_childs_cpu_time():
    # The two sources OtherWork subtracts agree in their units: a child's CPU seconds show in the machine's.
    machine, children = timed._busy_cpu_seconds(), timed._children_cpu_seconds()
    subprocess.run(
        [sys.executable, "-c", "import time\nend = time.process_time() + 1.0\nwhile time.process_time() < end: pass"]
    )
    used = timed._children_cpu_seconds() - children
    assert used >= 0.9
    assert timed._busy_cpu_seconds() - machine >= 0.9 * used
