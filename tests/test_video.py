"""Videos: decoded frame counts, sizes and content; GL selection; DM Control; the training hook; bad input."""

import json
import os
import re
import shutil
import subprocess
import sys

import imageio.v2 as imageio
import numpy as np
import pytest

from canter.cli.main import main
from canter.envs.registry import dm_control_task, get_backend
from canter.errors import CanterError
from canter.training import run_lock
from canter.training.videos import TrainingVideos, quiet_fork
from canter.use import renderer, video
from conftest import TINY, error_line


def frames_of(path) -> np.ndarray:
    if str(path).endswith(".gif"):
        return np.stack([f[..., :3] for f in imageio.mimread(path)])
    with imageio.get_reader(path, format="FFMPEG") as reader, quiet_fork():
        return np.stack([frame for frame in reader])  # noqa: C416  list(reader) would trust its len(), which is inf


def assert_real_video(frames: np.ndarray, count: int, width: int, height: int) -> None:
    assert frames.shape == (count, height, width, 3)
    assert frames.std() > 5  # not blank
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 0.5  # not a constant image


@pytest.mark.slow
def test_mp4_of_a_mujoco_run(tiny_hopper_run, capsys):
    code = main(
        [
            "video",
            str(tiny_hopper_run),
            "--out",
            "hopper.mp4",
            "--episodes",
            "2",
            "--max-steps",
            "8",
            "--width",
            "64",
            "--height",
            "48",
            "--fps",
            "10",
        ]
    )
    out, err = capsys.readouterr()
    assert code == 0, err
    assert re.findall(r"episode (\d)/2: return", out) == ["1", "2"] and out.startswith("rendering 2 episode(s) of")
    # Each episode: the reset frame plus one per step.
    assert_real_video(frames_of("hopper.mp4"), 2 * 9, 64, 48)


@pytest.mark.slow
def test_gif_of_a_non_mujoco_env_is_resized(tiny_run):
    told = []  # each episode is told as it ends, before the file is written

    def on_episode(index, value):
        told.append((index, value, os.path.exists("pendulum.gif")))

    returns = video.record_video(
        tiny_run.run_dir, "pendulum.gif", episodes=2, width=40, height=30, fps=20, max_steps=12, on_episode=on_episode
    )
    assert len(returns) == 2 and np.all(np.isfinite(returns))
    assert told == [(0, returns[0], False), (1, returns[1], False)]
    assert_real_video(frames_of("pendulum.gif"), 2 * 13, 40, 30)


@pytest.mark.slow
def test_video_returns_match_a_gymnasium_loop(tiny_hopper_run):
    """An EnvPool run replayed in Gymnasium scores what a plain loop with the same policy scores."""
    import gymnasium as gym

    from canter.use.policy import load

    policy = load(tiny_hopper_run)
    returns = video.record_video(tiny_hopper_run, "h.mp4", episodes=2, width=32, height=32, seed=5, max_steps=25)
    expected = []
    for seed in (5, 6):
        env = gym.make("Hopper-v5")
        obs, _ = env.reset(seed=seed)
        total, steps, done = 0.0, 0, False
        while not done and steps < 25:
            obs, reward, terminated, truncated, _ = env.step(policy(obs))
            total += reward
            steps += 1
            done = terminated or truncated
        expected.append(total)
    np.testing.assert_allclose(returns, expected, rtol=1e-6)


@pytest.mark.slow
# FingerSpin: EnvPool's finger observation has two entries more than the task's; its finger moves slowly.
@pytest.mark.parametrize("env_id, steps", [("WalkerWalk-v1", 6), ("FingerSpin-v1", 60)])
def test_dm_control_run_renders_through_dm_control(tmp_path, env_id, steps):
    pytest.importorskip("dm_control")
    from canter.config.build import build_config
    from canter.training.loop import train

    config = build_config(
        env_id,
        total_steps=128,
        sets=TINY
        + [f"run.out_dir={tmp_path}", "env.num_envs=2", "ppo.n_steps=64", "ppo.minibatch_size=128", "ppo.epochs=1"],
    )
    run = train(config).run_dir
    assert dm_control_task("WalkerWalk-v1") == ("walker", "walk")
    assert dm_control_task("Hopper-v5") is None
    returns = video.record_video(run, "dmc.mp4", width=48, height=32, max_steps=steps)
    assert len(returns) == 1
    assert_real_video(frames_of("dmc.mp4"), steps + 1, 48, 32)


@pytest.mark.parametrize("env_id", ["FingerSpin-v1", "QuadrupedRun-v1", "FishUpright-v1"])
def test_an_envpool_dm_control_task_observes_what_dm_controls_task_does(env_id):
    """EnvPool declares one observation space per domain; a task keeps only its own entries, as dm_control's."""
    suite = pytest.importorskip("dm_control.suite")
    from canter.envs.registry import get_backend

    env = get_backend("envpool").make(env_id, 1, [0])
    task = suite.load(*dm_control_task(env_id))
    own = task.reset().observation
    assert env.spec.obs_dim == sum(np.asarray(v).size for v in own.values())
    env.close()
    task.close()


def test_every_envpool_dm_control_id_maps_to_a_dm_control_task():
    suite = pytest.importorskip("dm_control.suite")
    from envpool.registration import registry

    tasks = {(domain.lower(), task.lower()) for domain, task in suite.ALL_TASKS}
    ids = [env_id for env_id, entry in registry.specs.items() if entry[0].endswith(".dmc")]
    assert len(ids) > 40 and "WalkerWalk-v1" in ids
    assert [env_id for env_id in ids if tuple(map(str.lower, dm_control_task(env_id))) not in tasks] == []


@pytest.mark.slow
def test_video_every_during_training(tmp_path):
    from canter.config.build import build_config
    from canter.training.loop import train

    config = build_config(
        "Pendulum-v1",
        total_steps=512,
        sets=TINY
        + [
            f"run.out_dir={tmp_path}",
            "env.num_envs=2",
            "ppo.n_steps=128",
            "ppo.minibatch_size=128",
            "ppo.epochs=1",
            "run.video_every=256",
        ],
    )
    run = train(config).run_dir
    videos = sorted(p.name for p in (run / "videos").iterdir() if not p.name.startswith("render"))
    assert len(videos) == 2 and all(re.fullmatch(r"step_\d{12}\.mp4", name) for name in videos), videos
    steps = [int(name[5:17]) for name in videos]  # the step of the first iteration past each multiple of 256
    assert 256 <= steps[0] < 512 <= steps[1]
    frames = frames_of(run / "videos" / videos[-1])
    assert frames.shape[1:] == (video.DEFAULT_HEIGHT, video.DEFAULT_WIDTH, 3) and len(frames) == 201


def test_a_resume_drops_the_videos_of_the_steps_it_trains_again(tmp_path):
    folder = tmp_path / "videos"
    folder.mkdir()
    for step in (100, 200, 300):
        (folder / f"step_{step:012d}.mp4").write_bytes(b"")
    TrainingVideos(tmp_path, every=100, start_step=200, resumed=True).close()
    assert sorted(p.name for p in folder.iterdir()) == ["step_000000000100.mp4", "step_000000000200.mp4"]
    TrainingVideos(tmp_path, every=100, start_step=0).close()  # a new run's folder is its own
    assert len(list(folder.iterdir())) == 2


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the parent-death signal is Linux's")
def test_a_renderer_ends_with_its_trainer(tmp_path):
    """Killed, a trainer leaves its run folder to the next resume: its renderer must not go on writing there."""
    import os
    import signal
    import subprocess
    import time

    child = (
        "import os, signal, sys, time; from canter.signals import die_with_parent; "
        "die_with_parent(signal.SIGKILL, int(sys.argv[1])); "
        "print(os.getpid(), flush=True); time.sleep(120)"
    )
    parent = (
        "import subprocess, sys, os, time; "
        f"subprocess.Popen([sys.executable, '-c', {child!r}, str(os.getpid())], start_new_session=True); "
        "time.sleep(120)"
    )
    trainer = subprocess.Popen([sys.executable, "-c", parent], stdout=subprocess.PIPE, text=True)
    renderer = int(trainer.stdout.readline())
    trainer.kill()
    trainer.wait()
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            os.kill(renderer, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        os.kill(renderer, signal.SIGKILL)
        pytest.fail("the renderer outlived its trainer")


@pytest.mark.slow
def test_a_crashing_renderer_does_not_stop_training(tmp_path, capsys):
    """The render subprocess dies (here: a snapshot it cannot read); training finishes and warns. The snapshot is
    kept, as the failure may pass (a full disk), and the next resume renders it once more; failing again, the video
    is given up."""
    hook = TrainingVideos(tmp_path, every=10, start_step=0)
    hook.snapshot_if_due(10, lambda path: path.write_bytes(b"not a checkpoint"))
    hook.render_snapshot()
    hook.close()
    log = tmp_path / "videos" / "render.log"
    failed = f"canter: warning: the video at step 10 failed (exit 2; see {log}); "
    assert capsys.readouterr().err == failed + "its snapshot is kept, and the run's next resume renders it again\n"
    assert [p.name for p in (tmp_path / "videos").glob("*.npz")] == [".snapshot_000000000010.npz"]
    TrainingVideos(tmp_path, every=10, start_step=20, resumed=True).close()
    assert capsys.readouterr().err == failed + "so it is given up\n"
    assert not list((tmp_path / "videos").glob("*.npz")) and not list((tmp_path / "videos").glob("*.mp4"))


def test_gl_selection(monkeypatch):
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.delitem(sys.modules, "mujoco", raising=False)
    monkeypatch.setattr(renderer, "_probe", lambda backend: backend == "osmesa")
    assert renderer.configure_gl() == "osmesa"
    monkeypatch.delenv("MUJOCO_GL")
    monkeypatch.setattr(renderer, "_probe", lambda backend: False)
    with pytest.raises(CanterError, match="apt-get install -y libegl1 libosmesa6"):
        renderer.configure_gl()
    monkeypatch.setenv("MUJOCO_GL", "egl")
    with pytest.raises(CanterError, match=r"apt-get install -y libegl1$"):
        renderer.configure_gl()


@pytest.mark.slow
def test_the_gl_backend_chosen_here_really_renders():
    import os

    assert os.environ.get("MUJOCO_GL") in ("egl", "osmesa")
    assert renderer._probe(os.environ["MUJOCO_GL"])


@pytest.mark.slow
def test_bad_inputs(tiny_hopper_run, tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    blocked = tmp_path / "file"
    blocked.write_text("")
    out = tmp_path / "out"
    run = str(tiny_hopper_run)
    small = ["--width", "32", "--height", "32", "--max-steps", "3"]
    for argv, message in [
        (["video", str(empty), "--out", str(out / "a.mp4")], "no checkpoint"),
        (["video", run, "--out", str(out / "a.avi")], "use .mp4 or .gif"),
        (["video", run, "--out", str(out / "a.mp4"), "--width", "33"], "even width and height"),
        (["video", run, "--out", str(out / "a.mp4"), "--max-steps", "-1"], "--max-steps must be >= 0"),
        (["video", run, "--out", str(blocked / "a.mp4")] + small, "cannot write"),
        (["video", run, "--out", str(out / "a.mp4"), "--camera", "no_such_camera"] + small, "cameras: track"),
    ]:
        code = main(argv)
        said, err = capsys.readouterr()
        assert code != 0 and message in err and err.count("\n") == 1, (argv, err)
        assert said == "", argv  # refused before it says it is rendering
    assert not out.exists() or not list(out.iterdir())  # no partial video left behind


@pytest.mark.slow
def test_a_pygame_env_renders_headless_without_an_error_line(tiny_run, tmp_path):
    """Pygame's SDL opened a sound device, and without XDG_RUNTIME_DIR printed an error as the process ended."""
    import subprocess

    env = {k: v for k, v in os.environ.items() if not k.startswith(("SDL_", "XDG_"))}
    env["PYTHONPATH"] = os.pathsep.join(sys.path)
    argv = [sys.executable, "-m", "canter.cli.main", "video", str(tiny_run.run_dir), "--out", str(tmp_path / "p.gif")]
    done = subprocess.run(argv + ["--max-steps", "3"], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and "error" not in done.stderr.lower(), done.stderr
    # A driver the machine lacks, asked for in the environment: one line that names it, not pygame's traceback.
    env["SDL_VIDEODRIVER"] = "nosuchdriver"
    done = subprocess.run(argv + ["--max-steps", "3"], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "SDL_VIDEODRIVER=nosuchdriver asks for it: unset it, or set it to dummy" in done.stderr


@pytest.mark.parametrize(
    ("name", "fps", "refused"),
    [("a.gif", 50, False), ("a.gif", 51, True), ("a.mp4", 240, False), ("a.mp4", 241, True), ("a.mp4", 0, True)],
)
def test_a_frame_rate_the_format_cannot_play_is_refused(tmp_path, name, fps, refused):
    out = tmp_path / name
    if refused:
        with pytest.raises(CanterError, match="--fps"):
            video.check_video_args(out, 1, 480, 360, fps)
    else:
        video.check_video_args(out, 1, 480, 360, fps)


@pytest.mark.parametrize("fps", [30, 20, 35, 50, 7])
def test_a_gif_plays_at_the_frame_rate_asked_for(tmp_path, fps):
    """A GIF stores each delay in whole hundredths of a second: at 30 fps its frames take 3 or 4 of them, so that
    the video lasts frames / fps, where one delay of 1000 / 30 ms, cut to 3 hundredths, played it 11% fast."""
    from PIL import Image

    from canter.use.video_file import AtomicVideo

    count = 3 * fps
    out = tmp_path / "a.gif"
    writer = AtomicVideo(out, fps)
    for frame in np.random.default_rng(0).integers(0, 256, (count, 8, 8, 3), dtype=np.uint8):
        writer.append(frame)
    writer.commit()
    with Image.open(out) as gif:
        delays = []
        for index in range(gif.n_frames):
            gif.seek(index)
            delays.append(gif.info["duration"])
    assert len(delays) == count and sum(delays) == 3000  # 3 s to the millisecond
    assert set(delays) <= {10 * (100 // fps), 10 * (-(-100 // fps))}  # every frame within a hundredth of 1 / fps


@pytest.mark.slow
def test_a_resume_renders_the_video_whose_render_a_killed_trainer_took_with_it(archived_run):
    """Such a snapshot is whole (it was saved before the render began): deleting it as half-written would lose that
    video for good."""
    folder = archived_run / "videos"
    folder.mkdir()
    snapshot = folder / ".snapshot_000000000714.npz"
    shutil.copy(archived_run / "checkpoints" / "ckpt_000000000714.npz", snapshot)
    after = folder / ".snapshot_000000001500.npz"  # of training past the checkpoint, which the resume does again
    shutil.copy(snapshot, after)
    with run_lock.RunLocks() as locks:
        locks.take(archived_run)  # as a resume takes it first
        TrainingVideos(archived_run, every=500, start_step=1190, resumed=True).close()
    assert sorted(p.name for p in folder.iterdir() if not p.name.startswith("render")) == ["step_000000000714.mp4"]
    assert len(frames_of(folder / "step_000000000714.mp4")) > 1


def test_a_run_of_an_env_gymnasium_lacks_is_told_which_backend_alone_has_it():
    """A DM Control env is EnvPool's alone: its video is refused in its own words, not in Brax's."""
    from canter.use.video_players import GymnasiumPlayer

    with pytest.raises(CanterError) as refused:
        GymnasiumPlayer("CheetahRun-v1", 64, 64, None)
    assert str(refused.value) == (
        "cannot replay CheetahRun-v1: canter renders through Gymnasium's envs, and Gymnasium has no such env (only "
        "EnvPool has it), so a run of it has no video; canter eval scores it"
    )


def test_a_run_on_brax_own_envs_is_told_it_has_no_video(archived_run, monkeypatch, capsys):
    """canter renders through Gymnasium's envs, which Brax's own models are not: `canter video`, `report --video` and
    training with videos say so in one line, before anything renders."""
    import dataclasses

    from canter.config.build import build_config
    from canter.training import restore
    from canter.use.video_players import GymnasiumPlayer

    held = r"\(only Brax has it\)" if get_backend("brax").available() else r"\(no backend installed here has it\)"
    with pytest.raises(CanterError, match=rf"cannot replay ant: .*{held}, so a run of it has no video; canter eval"):
        GymnasiumPlayer("ant", 64, 64, None)
    real = restore.policy_facts
    monkeypatch.setattr(restore, "policy_facts", lambda *a: dataclasses.replace(real(*a), env_id="ant", backend="brax"))
    refused = "a run on Brax's own envs (ant) has no video: canter renders through Gymnasium's envs, which do not have "
    refused += "Brax's models; "
    assert error_line(capsys, ["video", str(archived_run), "--out", "v.mp4"]) == refused + "canter eval scores it"
    assert not os.path.exists("v.mp4")
    if get_backend("brax").available():
        with pytest.raises(CanterError, match=re.escape(refused + "drop --video-every (run.video_every)")):
            build_config("ant", sets=["env.backend=brax", "run.video_every=1000"])


def test_a_render_process_renders_itself_or_fails_but_never_hands_off(archived_run, monkeypatch, capsys):
    """A render subprocess whose mujoco could not render headless would otherwise start another, which would do the
    same, one process after another without end."""
    monkeypatch.setattr(video, "headless_in_this_process", lambda: False)
    monkeypatch.setattr(video, "_in_render_process", False)  # `_main` sets it for the rest of its process
    monkeypatch.setattr(video, "_record_in_subprocess", lambda *a: pytest.fail("handed off to another process"))
    request = {"run_dir": str(archived_run), "out_path": "v.mp4", "max_steps": 2}
    assert video._main([json.dumps(request)]) == 2
    assert "before a headless renderer was chosen" in capsys.readouterr().err
    assert not os.path.exists("v.mp4")


def test_the_renderer_is_chosen_before_the_checks_that_import_mujoco(archived_run, tmp_path):
    """A backend's availability probe (mjx's) imports mujoco. Were it imported before MUJOCO_GL is chosen, it would
    take its windowed default and the video would go to a subprocess, whose checks would do the same."""
    script = (
        "import sys\n"
        "import canter.envs.registry as registry\n"
        "from canter.use import video\n"
        "real = registry.refuse_mujoco_py_replay\n"
        "def probing(*args, **kwargs):\n"
        "    import mujoco  # noqa: F401\n"
        "    return real(*args, **kwargs)\n"
        "registry.refuse_mujoco_py_replay = probing\n"
        "def handed_off(*args):\n"
        "    sys.exit('handed off to a subprocess')\n"
        "video._record_in_subprocess = handed_off\n"
        f"print(video.record_video({str(archived_run)!r}, 'v.mp4', max_steps=3))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    done = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "v.mp4").stat().st_size > 0


@pytest.mark.parametrize(("gl", "message"), [("bogus", "is not one of MuJoCo's renderers"), ("disable", "turns")])
def test_training_with_videos_refuses_a_renderer_it_cannot_use_before_its_folder(
    tmp_path, capsys, monkeypatch, gl, message
):
    """A renderer that fails later costs only its videos; one that the environment names wrongly is bad input."""
    monkeypatch.setenv("MUJOCO_GL", gl)
    argv = ["train", "InvertedPendulum-v5", "--video-every", "1000", "--total-steps", "512", "--out-dir", str(tmp_path)]
    assert main([*argv, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"canter: error: MUJOCO_GL={gl} {message}" in err, err
    assert list(tmp_path.iterdir()) == []


def test_a_resume_that_renders_videos_refuses_a_renderer_it_cannot_use_first(archived_run, capsys, monkeypatch):
    config = archived_run / "config.toml"
    config.write_text(config.read_text().replace("video_every = 0", "video_every = 1000"))
    before = sorted(p.relative_to(archived_run) for p in archived_run.rglob("*"))
    monkeypatch.setenv("MUJOCO_GL", "bogus")
    assert main(["train", "--resume", str(archived_run), "--total-steps", "2048", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "canter: error: MUJOCO_GL=bogus is not one of MuJoCo's renderers" in err, err
    assert sorted(p.relative_to(archived_run) for p in archived_run.rglob("*")) == before
