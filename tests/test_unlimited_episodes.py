"""An env whose episodes never end and that has no step limit (max_episode_steps None) trains, but an evaluation of
it would never end: canter eval, evaluations during training, videos and tune's and bench's checks refuse it up front,
with one line."""

import os
import subprocess
import sys
import textwrap

import pytest

from canter.errors import CanterError
from conftest import TINY, error_line

ENV = "unlimited_forever:Forever-v0"
MODULE = textwrap.dedent(
    """
    import gymnasium as gym
    import numpy as np

    class Forever(gym.Env):
        observation_space = gym.spaces.Box(-1, 1, (3,), np.float32)
        action_space = gym.spaces.Box(-1, 1, (1,), np.float32)

        def reset(self, *, seed=None, options=None):
            super().reset(seed=seed)
            return np.zeros(3, np.float32), {}

        def step(self, action):
            return np.zeros(3, np.float32), float(action[0]), False, False, {}

    gym.register("Forever-v0", entry_point=Forever)  # no max_episode_steps: its episodes never end
    """
)
REFUSAL = (
    f"{ENV} has no episode step limit, so an evaluation episode may never end; register it with max_episode_steps=N "
    "(gymnasium.register(..., max_episode_steps=N))"
)
pytestmark = pytest.mark.slow  # trains, and starts canter in subprocesses
SETS = [arg for key in TINY for arg in ("--set", key)] + ["--set", "env.num_envs=4", "--total-steps", "512"]


@pytest.fixture(scope="module")
def module_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("forever_module")
    (folder / "unlimited_forever.py").write_text(MODULE)
    sys.path.insert(0, str(folder))
    yield folder
    sys.path.remove(str(folder))


@pytest.fixture(scope="module")
def forever_run(module_dir, tmp_path_factory):
    """A run of the endless env: training needs no episode to end."""
    from canter.config.build import build_config
    from canter.training.loop import train

    out = tmp_path_factory.mktemp("forever_runs")
    config = build_config(ENV, preset="fast", total_steps=512, sets=TINY + ["env.num_envs=4", f"run.out_dir={out}"])
    return train(config).run_dir


def _env(module_dir):
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(module_dir), *sys.path])}


def test_eval_is_refused_with_one_line(forever_run, capsys):
    assert error_line(capsys, ["eval", str(forever_run), "--episodes", "1"]) == REFUSAL


def test_evaluate_from_python_is_refused(forever_run):
    from canter.use.evaluate import evaluate
    from canter.use.policy import load

    with pytest.raises(CanterError, match="no episode step limit"):
        evaluate(load(forever_run), episodes=1)


def test_eval_in_a_subprocess_ends(forever_run, module_dir):
    """A regression would run forever: the timeout makes it a failure."""
    done = subprocess.run(
        [sys.executable, "-m", "canter.cli.main", "eval", str(forever_run), "--episodes", "1"],
        capture_output=True,
        text=True,
        timeout=120,
        env=_env(module_dir),
    )
    assert done.returncode == 2, done
    assert done.stderr == f"canter: error: {REFUSAL}\n"


def test_train_with_evaluations_is_refused_before_its_folder(module_dir, tmp_path):
    out = tmp_path / "runs"
    done = subprocess.run(
        [sys.executable, "-m", "canter.cli.main", "train", ENV, "--eval-every", "128", "--out-dir", str(out), *SETS],
        capture_output=True,
        text=True,
        timeout=120,
        env=_env(module_dir),
    )
    assert done.returncode == 2, done
    assert done.stderr == (f"canter: error: {REFUSAL}, or train without --eval-every (run.eval_every=0)\n"), done.stderr
    assert not out.exists() or not any(out.iterdir())


def test_train_with_evaluations_in_process(module_dir, tmp_path, capsys):
    out = tmp_path / "runs"
    line = error_line(capsys, ["train", ENV, "--eval-every", "128", "--out-dir", str(out), *SETS])
    assert line == f"{REFUSAL}, or train without --eval-every (run.eval_every=0)"
    assert not out.exists() or not any(out.iterdir())


def test_video_without_max_steps_is_refused(forever_run, tmp_path, capsys):
    line = error_line(capsys, ["video", str(forever_run), "--out", str(tmp_path / "v.mp4")])
    assert line == (
        f"{ENV} has no episode step limit, so a video episode may never end; register it with max_episode_steps=N "
        "(gymnasium.register(..., max_episode_steps=N)), or cut episodes with --max-steps N (max_steps=)"
    )
    assert not (tmp_path / "v.mp4").exists()


def test_tune_and_bench_checks_refuse_it(module_dir):
    from canter.orchestrate.env_check import check_continuous

    with pytest.raises(CanterError) as refused:
        check_continuous(ENV)
    assert str(refused.value) == REFUSAL


def test_an_env_with_a_limit_passes(module_dir):
    from canter.training.evaluation import check_episodes_end

    check_episodes_end("Pendulum-v1", "gymnasium")
