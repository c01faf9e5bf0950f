"""benchmarks/gpu/summarize.py: the figures a GPU part brings back, from hand-made run folders and Brax records. A
device session is too short to find a misleading table there."""

import json
from pathlib import Path

import pytest

from script_modules import BENCHMARKS, load_script

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def summarize():
    return load_script("gpu_summarize", BENCHMARKS / "gpu" / "summarize.py")


def make_run(folder: Path, *, steps: int, wall: float, compile_s: float, stop: str, iteration: int = 3) -> Path:
    run = folder / "run"
    run.mkdir(parents=True)
    summary = dict(
        global_step=steps, wall_seconds=wall, compile_seconds=compile_s, sps=steps / (wall - compile_s),
        recent_return=100.0, stop_reason=stop,
    )  # fmt: skip
    (run / "summary.json").write_text(json.dumps(summary))
    (run / "config.toml").write_text('[run]\nalgo = "ppo"\nseed = 0\n\n[env]\nnum_envs = 1024\nbackend = "mjx"\n')
    (run / "metrics.csv").write_text(f"global_step,iteration,wall_time,eval/return_mean\n{steps},{iteration},{wall},\n")
    return run


def test_the_seeds_ratio_divides_whole_runs_only(summarize, tmp_path):
    one = make_run(tmp_path / "runs" / "seeds-one", steps=500_000, wall=90.0, compile_s=30.0, stop="budget")
    # Whole runs count slightly different steps: autoreset steps are not counted.
    five = make_run(tmp_path / "runs" / "seeds-five", steps=500_032, wall=120.0, compile_s=40.0, stop="budget")
    text = "\n".join(summarize.seeds(tmp_path))
    assert "5 vmapped seeds / 1 seed: 1.33x (compile left out: 1.33x)" in text
    # Five seeds cut at half their budget: their wall time is not a whole run's.
    summary = json.loads((five / "summary.json").read_text())
    (five / "summary.json").write_text(json.dumps(summary | {"global_step": 250_000, "stop_reason": "signal"}))
    text = "\n".join(summarize.seeds(tmp_path))
    assert "Wall time of 5 vmapped seeds" not in text and "stopped: one seed budget, five seeds signal" in text
    assert "5 vmapped seeds / 1 seed: 2.67x" in text  # (80 s / 250k) / (60 s / 500k)
    assert "| signal |" in text and "| budget |" in text
    assert summarize.run_facts(one)["iterations"] == 3


def test_the_ppo_brax_table_names_iterations_stops_and_the_evaluation_kind(summarize, tmp_path):
    settings = dict(batch_size=1024, num_minibatches=32, unroll_length=10, action_repeat=1, deterministic_eval=True)
    record = dict(
        steps=5_242_880, settings=settings, training_walltime=100.0, training_sps=60_000.0, final_eval_return=6000.0,
        eval_episodes=128,
    )  # fmt: skip
    (tmp_path / "brax_humanoid.json").write_text(json.dumps(record))
    make_run(tmp_path / "runs" / "ppo-brax-humanoid", steps=5_306_818, wall=150.0, compile_s=50.0, stop="budget",
             iteration=17)  # fmt: skip
    times = [
        {"label": "brax-humanoid", "seconds": 160.0, "exit": 0, "stopped": False},
        {"label": "ppo-brax-humanoid", "seconds": 150.0, "exit": 0, "stopped": False},  # an earlier, whole run
        {"label": "ppo-brax-humanoid", "seconds": 170.0, "exit": 0, "stopped": True},
    ]
    (tmp_path / "ppo-brax.times").write_text("".join(json.dumps(t) + "\n" for t in times))
    rows = [line for line in summarize.ppo_brax(tmp_path) if line.startswith("| humanoid")]
    brax, canter = (row.split(" | ") for row in rows)
    assert brax[3] == "16" and "deterministic, 128 eps" in brax[7] and brax[4] == "160.0"
    assert canter[3] == "17" and canter[-1] == "budget |"
    assert canter[4] == "-"  # stopped at its limit: no whole-process figure
