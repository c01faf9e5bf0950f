"""Bad input at the edges of what a command takes: absurd numbers, a renderer with no display, a user's env module
that fails, degenerate env spaces, a --set key given twice, a config path that is no file. Each is one line naming
the problem and the fix, exit 2, no traceback."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from canter.cli.main import main
from canter.config.build import build_config
from canter.errors import CanterError
from conftest import error_line

# ------------------------------------------------------------------------------------------------- --smooth


def test_a_window_longer_than_the_series_averages_the_whole_series():
    from canter.use.bands import moving_average

    y = np.array([1.0, 2.0, np.nan, 4.0])
    expected = [1.0, 1.5, 1.5, 7.0 / 3.0]  # every row so far, as a window of exactly len(y) gives
    np.testing.assert_allclose(moving_average(y, 99_999_999_999), expected)
    np.testing.assert_allclose(moving_average(y, len(y)), expected)
    assert moving_average(np.array([]), 10**12).shape == (0,)


@pytest.mark.parametrize("command", ["plot", "report"])
def test_an_absurd_smoothing_window_still_draws(command, archived_run, tmp_path, capsys):
    out = tmp_path / ("curves.png" if command == "plot" else "report.html")
    assert main([command, str(archived_run), "--smooth", "99999999999", "--out", str(out)]) == 0
    assert out.stat().st_size > 0 and "Traceback" not in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------- video


def test_glfw_without_a_display_is_one_line(archived_run, tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "PYOPENGL_PLATFORM")}
    env["MUJOCO_GL"] = "glfw"
    argv = [sys.executable, "-m", "canter.cli", "video", str(archived_run), "--out", str(tmp_path / "g.mp4")]
    done = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr
    assert "MUJOCO_GL=glfw needs a display" in done.stderr and "set egl or osmesa" in done.stderr
    assert not (tmp_path / "g.mp4").exists()


@pytest.mark.parametrize(
    "value, system, environ, problem",
    [
        ("glfw", "Linux", {}, "MUJOCO_GL=glfw needs a display, and DISPLAY is not set"),
        ("1", "Linux", {}, "MUJOCO_GL=1 needs a display"),
        ("glfw", "Linux", {"DISPLAY": ":0"}, None),
        ("glfw", "Linux", {"WAYLAND_DISPLAY": "wayland-0"}, None),
        ("glfw", "Darwin", {}, None),
        ("egl", "Linux", {}, None),
        ("OFF", "Linux", {}, "MUJOCO_GL=OFF turns MuJoCo's rendering off"),
        ("cgl", "Linux", {}, "MUJOCO_GL=cgl is MuJoCo's renderer on Darwin, not Linux"),
        ("egl", "Darwin", {}, "MUJOCO_GL=egl is MuJoCo's renderer on Linux, not Darwin"),
    ],
)
def test_a_renderer_this_machine_cannot_use_is_named(value, system, environ, problem):
    from canter.use.renderer import renderer_problem

    found = renderer_problem(value, system, environ)
    if problem is None:
        assert found is None
    else:
        # What to set instead is what works there: EGL or OSMesa headless on Linux, cgl on macOS.
        fix = "set egl or osmesa (headless)" if system == "Linux" else "set MUJOCO_GL=cgl, or glfw with a display"
        assert found is not None and found.startswith(problem) and found.endswith(fix), found


def test_a_failed_gl_context_names_glfw_s_own_reason():
    from canter.use.renderer import gl_failure

    fatal = "an OpenGL platform library has not been loaded into this process, this most likely means that ..."
    assert gl_failure("Hopper-v5", "glfw", fatal, ["(65550) b'X11: Failed to open display :1'"]) == (
        "cannot render Hopper-v5 with MUJOCO_GL=glfw: X11: Failed to open display :1; unset MUJOCO_GL to let canter "
        "choose, or set egl or osmesa (headless)"
    )
    assert "an OpenGL platform library has not been loaded into this process;" in gl_failure("E", "glx", fatal, [])


def test_a_gl_context_that_fails_at_the_first_frame_is_one_line(monkeypatch, recwarn):
    """A display that is set but cannot be opened passes the check before rendering; MuJoCo fails at the first
    frame, after the glfw package warned of the cause."""
    import warnings

    import mujoco

    from canter.use.video_players import GymnasiumPlayer

    class GLFWError(UserWarning):
        pass

    class Env:
        def render(self):
            warnings.warn("(65550) b'X11: Failed to open display :1'", GLFWError, stacklevel=1)
            raise mujoco.FatalError("an OpenGL platform library has not been loaded into this process, this ...")

    player = object.__new__(GymnasiumPlayer)
    player.env, player.env_id, player.size, player._rendered = Env(), "Hopper-v5", (16, 16), False
    monkeypatch.setenv("MUJOCO_GL", "glfw")
    with pytest.raises(CanterError) as caught:
        player._frame()
    assert str(caught.value) == (
        "cannot render Hopper-v5 with MUJOCO_GL=glfw: X11: Failed to open display :1; unset MUJOCO_GL to let canter "
        "choose, or set egl or osmesa (headless)"
    )
    assert not [w for w in recwarn if w.category is GLFWError]  # held back: the error says it


def test_an_empty_video_out_says_it_is_empty(archived_run, capsys):
    line = error_line(capsys, ["video", str(archived_run), "--out", ""])
    assert line.startswith("--out is empty; give the file to write"), line


# ------------------------------------------------------------------------------------------------- custom envs

NO_ACTIONS = """
import gymnasium as gym
import numpy as np

class Env(gym.Env):
    observation_space = gym.spaces.Box(-1, 1, (3,), np.float32)
    action_space = gym.spaces.Box(-1, 1, ({act},), np.float32)

    def reset(self, *, seed=None, options=None):
        return np.zeros({obs}, np.float32), {{}}

    def step(self, action):
        return np.zeros(3, np.float32), 0.0, False, False, {{}}

gym.register("{env}", entry_point=Env, max_episode_steps=10)
"""

MODULES = {
    "edge_raises": 'raise ValueError("no license key")',
    "edge_syntax": "def broken(:\n    pass\n",
    "edge_ctor": textwrap.dedent(
        """
        import gymnasium as gym

        class Env(gym.Env):
            def __init__(self):
                raise RuntimeError("cannot reach the robot")

        gym.register("EdgeCtor-v0", entry_point=Env)
        """
    ),
    "edge_no_actions": NO_ACTIONS.format(act=0, obs=3, env="EdgeNoActions-v0"),
    "edge_wrong_obs": NO_ACTIONS.format(act=1, obs=5, env="EdgeWrongObs-v0"),
}


@pytest.fixture
def env_modules(tmp_path, monkeypatch):
    """The modules above, importable as PYTHONPATH would make them."""
    folder = tmp_path / "modules"
    folder.mkdir()
    for name, text in MODULES.items():
        (folder / f"{name}.py").write_text(text)
    monkeypatch.syspath_prepend(str(folder))
    for name in MODULES:
        monkeypatch.delitem(sys.modules, name, raising=False)
    return folder


@pytest.mark.parametrize(
    "env_id, message",
    [
        (
            "edge_raises:X-v0",
            "importing module 'edge_raises' for env 'edge_raises:X-v0' raised ValueError: no license key; see the full "
            'traceback with: python -c "import edge_raises"',
        ),
        (
            "edge_syntax:X-v0",
            "importing module 'edge_syntax' for env 'edge_syntax:X-v0' raised SyntaxError: invalid syntax "
            '(edge_syntax.py, line 1); see the full traceback with: python -c "import edge_syntax"',
        ),
        (
            "edge_ctor:EdgeCtor-v0",
            "edge_ctor:EdgeCtor-v0: making the env raised RuntimeError: cannot reach the robot; see the full traceback "
            "with: python -c \"import gymnasium as gym; env = gym.make('edge_ctor:EdgeCtor-v0'); env.reset(seed=0); "
            'env.step(env.action_space.sample())"',
        ),
        (
            "edge_no_actions:EdgeNoActions-v0",
            "edge_no_actions:EdgeNoActions-v0: the action space Box([], [], (0,), float32) has no dimensions; canter "
            "needs at least one action value (fix the env's action_space)",
        ),
        (
            "edge_wrong_obs:EdgeWrongObs-v0",
            "edge_wrong_obs:EdgeWrongObs-v0: reset returned an observation of shape (5,), but its observation space "
            "has shape (3,); make the env's observations match its observation_space",
        ),
    ],
)
def test_a_custom_env_that_fails_is_one_line(env_id, message, env_modules, tmp_path, capsys):
    # Gymnasium's own checker warns of the mismatched observation first; the error is the last line.
    code = main(["train", env_id, "--total-steps", "64", "--quiet", "--out-dir", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    assert err.splitlines()[-1] == f"canter: error: {message}"
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_an_observation_space_with_no_dimensions_is_refused():
    import gymnasium as gym

    from canter.envs.gymnasium.single import check_spaces

    box = gym.spaces.Box(-1, 1, (2,), np.float32)
    with pytest.raises(CanterError, match=r"^E-v0: the observation space .* has no dimensions"):
        check_spaces("E-v0", gym.spaces.Box(-1, 1, (0,), np.float32), box)
    check_spaces("E-v0", box, box)


def test_a_registered_env_that_raises_keeps_its_traceback():
    """Only a user's module:EnvId is their code to fix; Gymnasium's own envs raising would be a bug to report."""
    from canter.envs.gymnasium.single import user_code

    with pytest.raises(ZeroDivisionError), user_code("Hopper-v5", "reset"):
        1 / 0  # noqa: B018
    refused = pytest.raises(CanterError, match=r"^m:E-v0: reset raised ZeroDivisionError: division by zero; see")
    with refused, user_code("m:E-v0", "reset"):
        1 / 0  # noqa: B018


# ------------------------------------------------------------------------------------------------- config


def test_a_set_key_given_twice_takes_the_last_and_says_so(capsys):
    """A script that lays its own --set over a shared list means the last; a copied key may be a slip, so the note.
    (run.total_steps=0 stops the command before it trains.)"""
    sets = ["--set", "ppo.clip=0.1", "--set", "run.total_steps=0", "--set", " ppo.clip = 0.2", "--set", "ppo.lr=1e-4"]
    assert main(["train", "Hopper-v5", *sets, "--set", "ppo.lr=1e-4"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "canter: note: --set gives ppo.clip ('0.1', then '0.2'): the last of each is used", err
    assert err[1].startswith("canter: error: run.total_steps must be >= 1") and len(err) == 2, err
    assert build_config("Hopper-v5", sets=["ppo.clip=0.1", "ppo.clip=0.2"]).ppo.clip == 0.2


def test_a_huge_step_budget_is_shown_short(tmp_path, capsys):
    config = tmp_path / "c.toml"
    config.write_text("[run]\ntotal_steps = 1e300\n")
    line = error_line(capsys, ["train", "Hopper-v5", "--config", str(config)])
    assert line.startswith("run.total_steps must be below 9,007,199,254,740,992 in size, got 1e+300"), line
    assert len(line) < 200, line


@pytest.mark.parametrize("command", [["train", "Hopper-v5"], ["bench", "--envs", "Hopper-v5"], ["tune", "Hopper-v5"]])
def test_a_huge_step_flag_is_refused_naming_the_flag(command, capsys):
    line = error_line(capsys, [*command, "--total-steps", "1e300"])
    assert line == (
        f"{command[0]}: argument --total-steps: expected a step count below 2**53 (9,007,199,254,740,992), got "
        "'1e300' (see --help)"
    ), line


def test_short_int_keeps_readable_numbers_whole():
    from canter.config.values import short_int

    assert short_int(2**53) == "9,007,199,254,740,992"
    assert short_int(10**19) == "10,000,000,000,000,000,000"
    assert short_int(int(1e300)) == "1e+300"
    assert short_int(-(10**5000)) == "-1e+5000"
    assert short_int(19_990_000_000_000_000_000_000) == "2e+22"
    assert short_int(12_345_000_000_000_000_000_000) == "1.23e+22"


def test_a_config_path_that_is_no_regular_file_says_so(capsys):
    line = error_line(capsys, ["train", "Hopper-v5", "--config", "/dev/zero"])
    expected = "/dev/zero is not a regular file; --config (config_file= from Python) takes a TOML file"
    assert line.startswith(expected), line


# ------------------------------------------------------------------------------------------------- checkpoints


def test_a_corrupt_best_checkpoint_gets_advice_that_fits_resume(tmp_path):
    """train --resume reads best.npz for its score and takes no --checkpoint flag."""
    from canter.training import checkpoint

    best = Path(tmp_path / "run" / "checkpoints" / "best.npz")
    best.parent.mkdir(parents=True)
    best.write_bytes(b"not a zip")
    (best.parent / "ckpt_000000001000.npz").write_bytes(b"")  # the newest checkpoint, which --checkpoint last takes
    with pytest.raises(CanterError) as caught:
        checkpoint.read_header(best)
    message = str(caught.value)
    assert message.startswith(f"checkpoint {best} is corrupt or truncated; move it out of its folder"), message
    assert (
        "eval, video, export and report can take --checkpoint last (checkpoint='last' from Python) instead" in message
    )
