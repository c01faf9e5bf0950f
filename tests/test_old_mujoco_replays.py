"""A run of a mujoco-py MuJoCo id (Hopper-v3), which EnvPool trains on its own port, replayed where canter makes
Gymnasium's env of that id, which Gymnasium no longer makes: one line naming the problem and the fix, exit 2, and
nothing written."""

from __future__ import annotations

from pathlib import Path

import pytest

from canter.cli.main import main
from conftest import error_line

ENV_ID = "Hopper-v3"
PROBLEM = f"{ENV_ID} is an old MuJoCo version that needs mujoco-py, which Gymnasium no longer runs"
TINY_V3 = ["--set", "net.hidden=8,8", "--set", "run.tensorboard=false", "--set", "env.num_envs=2"]


def _envpool_runs_it() -> bool:
    from canter.envs.registry import get_backend

    envpool = get_backend("envpool")
    return envpool.available() and ENV_ID in envpool.supported_ids()


pytestmark = [
    pytest.mark.slow,  # trains, and renders in a subprocess
    pytest.mark.skipif(not _envpool_runs_it(), reason=f"EnvPool does not run {ENV_ID} here"),
]


@pytest.fixture(scope="module")
def v3_run(tmp_path_factory) -> Path:
    """A tiny Hopper-v3 run trained on EnvPool."""
    out = tmp_path_factory.mktemp("v3_runs")
    assert main(["train", ENV_ID, "--total-steps", "512", "--out-dir", str(out), "--quiet", *TINY_V3]) == 0
    (run,) = [folder for folder in out.iterdir() if folder.is_dir()]
    return run


@pytest.mark.parametrize(
    "command, fix",
    [
        (
            ["video", "{run}", "--out", "x.gif", "--max-steps", "5"],
            ", and canter renders its videos there; render a run of Hopper-v5 (or Hopper-v4) instead "
            "(canter eval --backend envpool scores this one)",
        ),
        (
            ["eval", "{run}", "--vary", "gravity=1"],
            ", and --vary sweeps its MuJoCo model there; vary a run of Hopper-v5 (or Hopper-v4) instead "
            "(canter eval without --vary scores this one on envpool)",
        ),
        (
            ["report", "{run}", "--video", "--out", "report.html"],
            ", and report --video renders its video there; drop --video, or report a run of Hopper-v5 (or Hopper-v4)",
        ),
        (
            ["eval", "{run}", "--backend", "gymnasium", "--json", "results.json"],
            "; pass --backend envpool (backend= for evaluate), which runs its own Hopper-v3",
        ),
    ],
)
def test_a_replay_on_gymnasium_is_refused_in_one_line(v3_run, command, fix, capsys):
    before = sorted(v3_run.rglob("*"))
    argv = [str(v3_run) if word == "{run}" else word for word in command]
    assert error_line(capsys, argv) == PROBLEM + fix
    assert list(Path.cwd().iterdir()) == []  # no video, page or results, and no MuJoCo log
    assert sorted(v3_run.rglob("*")) == before  # no robustness folder in the run


def test_evaluate_from_python_on_gymnasium_names_the_backend_that_plays_it(v3_run):
    from canter import evaluate
    from canter.errors import CanterError
    from canter.use.policy import load

    with pytest.raises(CanterError, match=r"pass --backend envpool \(backend= for evaluate\)"):
        evaluate(load(v3_run), episodes=1, backend="gymnasium")


def test_the_run_s_own_backend_still_evaluates_it(v3_run, capsys):
    assert main(["eval", str(v3_run), "--episodes", "1"]) == 0
    assert "Traceback" not in capsys.readouterr().err


def test_videos_during_training_are_refused_before_a_run_folder_is_made(capsys):
    line = error_line(capsys, ["train", ENV_ID, "--total-steps", "512", "--video-every", "256", *TINY_V3])
    assert line == (
        f"{PROBLEM}, and run.video_every renders its videos there; drop --video-every (run.video_every), or train "
        "Hopper-v5 (or Hopper-v4) instead"
    )
    assert not Path("runs").exists()


def test_run_video_every_from_python_is_refused_before_a_run_folder_is_made():
    import canter
    from canter.errors import CanterError

    config = canter.build_config(
        ENV_ID, total_steps=512, sets=["net.hidden=8,8", "run.tensorboard=false", "run.video_every=256"]
    )
    with pytest.raises(CanterError, match=r"drop --video-every \(run.video_every\)"):
        canter.train(config)
    assert not Path("runs").exists()
