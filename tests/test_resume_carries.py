"""What a resume carries over besides the learner's state: the recent episode returns that run.stop_at_return and
summary.json's recent_return are computed from, and the best checkpoint's score. (A non-finite stop keeping the
exact checkpoint before it: tests/test_offpolicy.py.)"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from canter.config.build import build_config
from canter.errors import CanterError
from canter.training import checkpoint
from canter.training.loop import train
from canter.training.resume import resume_config
from canter.training.seed_run import RECENT_EPISODES
from conftest import TINY

# Pendulum's episodes are 200 steps and never end early: 4 envs finish about 2.5 episodes per 512-step iteration,
# so 4096 steps hold the 20 that run.stop_at_return needs, and one more iteration does not.
PENDULUM = TINY + ["env.num_envs=4", "ppo.n_steps=128", "ppo.minibatch_size=256", "ppo.epochs=1"]


@pytest.mark.slow
def test_a_run_that_reached_its_return_target_stops_after_one_resumed_iteration_unless_given_a_higher_one(
    tmp_path, capsys
):
    """Every return passes the target, so the run stops once it has its 20 episodes. Its last 20 returns are carried
    in the checkpoint: a resume with the same target stops after one iteration, as the uncut run would have, and
    says so first; a resume without a target trains on to the budget."""
    sets = PENDULUM + [f"run.out_dir={tmp_path}", "run.stop_at_return=-1e9"]
    first = train(build_config("Pendulum-v1", sets=sets, total_steps=8192))
    assert first.stop_reason == "stop_at_return" and first.global_step < 8192
    header = checkpoint.read_header(checkpoint.latest(first.run_dir))
    recent = header["totals"]["recent_returns"]
    assert len(recent) == RECENT_EPISODES and first.recent_return == pytest.approx(np.mean(recent))

    capsys.readouterr()
    again = train(resume_config(first.run_dir, None), resume=first.run_dir)
    assert again.stop_reason == "stop_at_return" and again.global_step <= first.global_step + 512
    assert (
        f"canter: note: {first.run_dir} has reached its return target run.stop_at_return=-1e+09 already (the mean "
        f"of its last training episodes is {np.mean(recent):.1f}), so it stops after one iteration; to train it on, "
        "pass --stop-at-return with a higher target, or inf for none\n"
    ) in capsys.readouterr().err
    resumed = train(resume_config(first.run_dir, None, stop_at_return=None), resume=first.run_dir)
    assert resumed.stop_reason == "budget" and resumed.global_step >= 8192


@pytest.mark.slow
def test_a_best_checkpoint_without_a_score_is_refused_in_one_line_on_resume(tmp_path):
    config = build_config("Pendulum-v1", sets=PENDULUM + [f"run.out_dir={tmp_path}"], total_steps=1024)
    run = train(config).run_dir
    shutil.copy(checkpoint.latest(run), checkpoint.best_path(run))  # a checkpoint copied in by hand
    evaluating = resume_config(run, 2048)
    evaluating = evaluating.with_values("run", eval_every=512, eval_episodes=1)
    with pytest.raises(CanterError, match=r"best.npz holds no evaluation score, so it is not a best checkpoint"):
        train(evaluating, resume=run)


@pytest.mark.slow
def test_a_resume_with_a_config_that_differs_in_what_is_learned_is_refused(tmp_path):
    config = build_config("Pendulum-v1", sets=PENDULUM + [f"run.out_dir={tmp_path}"], total_steps=512)
    run = train(config).run_dir
    other = resume_config(run, 1024).with_values("ppo", lr=1e-2)
    with pytest.raises(CanterError, match=r"differs from the run's in ppo.lr; a resume may change only its budget"):
        train(other, resume=run)
    assert train(resume_config(run, 1024), resume=run).global_step >= 1024  # the budget alone may change


@pytest.mark.slow
def test_a_resume_on_another_backend_than_the_run_started_on_says_so(tmp_path, monkeypatch, capsys):
    """env.backend = auto picks what the machine has: a run started on EnvPool and resumed where only Gymnasium
    is installed goes on there (the same MuJoCo physics), with one line that says so."""
    import canter.envs

    config = build_config("Pendulum-v1", sets=PENDULUM + [f"run.out_dir={tmp_path}"], total_steps=512)
    run = train(config).run_dir
    assert checkpoint.read_header(checkpoint.latest(run))["env"]["backend"] == "envpool"
    capsys.readouterr()
    monkeypatch.setattr(canter.envs, "resolve_backend", lambda env_id, backend: "gymnasium")
    assert train(resume_config(run, 1024), resume=run, quiet=True).global_step >= 1024
    notes = [line for line in capsys.readouterr().err.splitlines() if "canter: note:" in line]
    assert notes == [
        f"canter: note: {run} was trained on envpool up to step 512; env.backend=auto picks gymnasium here, which "
        f"steps it from now on (install envpool to keep one backend)"
    ]
    assert checkpoint.read_header(checkpoint.latest(run))["env"]["backend"] == "gymnasium"
