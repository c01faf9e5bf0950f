"""Videos of a trained policy, rendered headless (no GPU, no display).

The OpenGL platform is chosen before anything imports mujoco (`canter.use.renderer`). When mujoco was already
imported with another platform, `record_video` renders in a subprocess instead (`python -m canter.use.video`).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from canter.errors import CanterError, error_line
from canter.files import check_writable
from canter.signals import INTERRUPTED, StopFlag, die_with_parent
from canter.training.videos import child_env, quiet_fork
from canter.use.renderer import check_renderer, configure_gl, gl_fix, headless_in_this_process
from canter.use.video_file import AtomicVideo
from canter.use.video_players import DMControlPlayer, GymnasiumPlayer

DEFAULT_WIDTH, DEFAULT_HEIGHT, DEFAULT_FPS = 480, 360, 30
# GIF frame delays are whole hundredths of a second, and browsers play delays under 0.02 s at 0.1 s; faster MP4s
# than screens refresh only drop frames in the player.
FPS_LIMITS = {
    ".gif": (50, "its frame delays are hundredths of a second, and browsers slow shorter ones down"),
    ".mp4": (240, "faster than screens show"),
}
MAX_SIDE = 4096  # larger offscreen framebuffers fail deep in MuJoCo's GL context
# A caller stopped by a signal waits this long for its render subprocess to stop: a frame, then the encoder's end.
_STOP_SECONDS = 30
_POLL_SECONDS = 0.1  # how soon a caller passes a stop signal on to its render subprocess
_in_render_process = False  # set in a render subprocess (`_main`), which renders itself or fails, never hands off


def check_video_args(out: Path, episodes: int, width: int, height: int, fps: int, max_steps: int = 0) -> None:
    if out.suffix.lower() not in (".mp4", ".gif"):
        raise CanterError(f"--out {out}: the video format comes from the name; use .mp4 or .gif")
    if episodes < 1:
        raise CanterError(f"--episodes must be >= 1, got {episodes}")
    if max_steps < 0:
        raise CanterError(f"--max-steps must be >= 0 (0: whole episodes), got {max_steps}")
    if width < 16 or height < 16 or fps < 1:
        raise CanterError(f"need --width and --height >= 16 and --fps >= 1, got {width}x{height} at {fps} fps")
    fastest, why = FPS_LIMITS[out.suffix.lower()]
    if fps > fastest:
        raise CanterError(f"--fps goes up to {fastest} for {out.suffix.lower()} ({why}), got {fps}")
    if max(width, height) > MAX_SIDE:
        raise CanterError(
            f"--width and --height go up to {MAX_SIDE} (OpenGL's offscreen buffers), got {width}x{height}"
        )
    if out.suffix.lower() == ".mp4" and (width % 2 or height % 2):
        raise CanterError(f"MP4 (H.264, yuv420p) needs an even width and height, got {width}x{height}")
    check_writable(out)  # before the rendering, which can take minutes


class _Stopped(BaseException):
    """Raised at the first frame after SIGINT or SIGTERM, to remove the unfinished video before the signal acts."""


def record_video(
    run_dir: str | Path,
    out_path: str | Path,
    episodes: int = 1,
    width: int = DEFAULT_WIDTH,
    height: int = DEFAULT_HEIGHT,
    fps: int = DEFAULT_FPS,
    camera: str | None = None,
    seed: int = 0,
    checkpoint: str | Path = "last",
    max_steps: int = 0,
    on_start: Callable[[], None] | None = None,
    on_episode: Callable[[int, float], None] | None = None,
    stop: StopFlag | None = None,
) -> list[float]:
    """Render `episodes` deterministic episodes of a run's checkpoint (`last`, `best` or a file) to an MP4 or
    GIF, written atomically; returns the episode returns. Episode i starts from env seed `seed + i`. `on_start()`
    is called once the arguments are checked and rendering begins, and `on_episode(i, return)` as each episode
    ends, since a long episode takes minutes to render on a CPU. In a process whose MuJoCo already renders
    otherwise, the render runs in a subprocess: then `on_start` comes before that process checks the camera and
    the env, and every `on_episode` once the file is written. SIGINT or SIGTERM (in the main thread; not one that
    the process ignores) stops the render at its next frame and removes the unfinished file; then the signal acts
    as it would have (`StopFlag.deliver`): Python's SIGINT handler raises KeyboardInterrupt, and SIGTERM's default
    action ends the process. Where the caller's own handler returns instead, so does this, with no file written
    and the returns of the episodes finished before the stop (fewer than asked). With `stop`, a StopFlag that the
    caller has entered and delivers itself, its signal stops the render (one that came before the render started,
    too) and this returns as just said, leaving the signal to the caller."""
    from canter.envs.registry import (
        dm_control_task,
        note_replay,
        refuse_mujoco_py_replay,
        refuse_video_of_own_envs,
        single_env_backend,
    )
    from canter.training.checkpoint import read_header, resolve
    from canter.training.evaluation import check_episodes_end
    from canter.training.restore import policy_facts

    if not str(out_path).strip():  # Path("") is ".", which the suffix check would name instead
        raise CanterError("--out is empty; give the file to write, e.g. --out policy.mp4 (or .gif)")
    out = Path(out_path)
    check_video_args(out, episodes, width, height, fps, max_steps)
    newest = resolve(Path(run_dir), checkpoint)
    trained = policy_facts(read_header(newest), newest)
    refuse_video_of_own_envs(trained.backend, trained.env_id, "canter eval scores it")
    if "mujoco" not in sys.modules:
        # Before the checks below, which may import mujoco (a JAX-native backend's availability): imported first, it
        # would take its default, windowed platform, and this process could not render.
        configure_gl()
    if dm_control_task(trained.env_id) is None:  # here, not in a render subprocess, whose output is not shown
        refuse_mujoco_py_replay(
            trained.env_id,
            "canter renders its videos",
            "render a run of {newer} instead",
            " (canter eval --backend {ports} scores this one)",
        )
        if not max_steps:
            check_episodes_end(
                trained.env_id,
                single_env_backend().name,
                "a video episode",
                instead=", or cut episodes with --max-steps N (max_steps=)",
            )
        note_replay(trained.env_id, trained.backend, single_env_backend().name)
    if not headless_in_this_process():
        if _in_render_process:  # handing off again would start one render process after another without end
            raise CanterError(
                f"mujoco was imported with MUJOCO_GL={os.environ.get('MUJOCO_GL', '')!r} before a headless renderer "
                f"was chosen; {gl_fix()}"
            )
        # Resolved here, so that a run without the checkpoint asked for fails with its own message.
        path = resolve(Path(run_dir), checkpoint).absolute()
        if on_start:
            on_start()
        returns = _record_in_subprocess(run_dir, out, episodes, width, height, fps, camera, seed, path, max_steps, stop)
        for i, value in enumerate(returns):
            if on_episode:
                on_episode(i, value)
        return returns
    from canter.use.policy import load

    check_renderer()
    policy = load(run_dir, checkpoint)
    task = dm_control_task(policy.facts.env_id)
    player = (
        DMControlPlayer(*task, width, height, camera)
        if task
        else GymnasiumPlayer(policy.facts.env_id, width, height, camera)
    )
    returns = []
    # SIGINT and SIGTERM set a flag that the next frame acts on, as they stop training at the next iteration: raised
    # in a handler, an exception could be lost (`StopFlag`).
    with _stop_flag(stop) as flag:
        try:
            with quiet_fork():  # imageio runs ffmpeg to check it, then again at the first frame
                writer = AtomicVideo(out, fps)
                try:
                    if on_start:
                        on_start()

                    def on_frame(frame: np.ndarray) -> None:
                        if flag.signal is not None:
                            raise _Stopped
                        writer.append(frame)

                    for i in range(episodes):
                        returns.append(player.episode(policy, seed + i, max_steps, on_frame))
                        if on_episode:
                            on_episode(i, returns[-1])
                    writer.commit()
                except BaseException:
                    writer.abort()
                    raise
        except _Stopped:
            pass  # the signal is delivered below, once its handler from before is back
        finally:
            player.close()
    if stop is None:
        flag.deliver()
    return returns


def _stop_flag(stop: StopFlag | None) -> contextlib.AbstractContextManager[StopFlag]:
    """The caller's StopFlag, which it has entered and delivers, else one of this render's own."""
    return contextlib.nullcontext(stop) if stop is not None else StopFlag()


def _record_in_subprocess(
    run_dir: Any,
    out: Path,
    episodes: int,
    width: int,
    height: int,
    fps: int,
    camera: str | None,
    seed: int,
    checkpoint: Path,
    max_steps: int,
    caller_stop: StopFlag | None = None,
) -> list[float]:
    request = dict(
        run_dir=str(run_dir),
        out_path=str(out),
        episodes=episodes,
        width=width,
        height=height,
        fps=fps,
        camera=camera,
        seed=seed,
        max_steps=max_steps,
        checkpoint=str(checkpoint),
    )
    with _stop_flag(caller_stop) as stop:
        with quiet_fork():
            process = subprocess.Popen(
                [sys.executable, "-m", "canter.use.video", json.dumps(request)],
                env=child_env(),
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
        try:
            stdout, stderr = _wait_for_renderer(process, stop)
        except BaseException:  # a second Ctrl-C: this process leaves now, and the renderer still stops and cleans up
            process.terminate()
            raise
    if caller_stop is None:
        stop.deliver()
    lines = stdout.strip().splitlines()
    if stop.signal is not None and process.returncode != 0:
        return []  # stopped, and the caller's own handler let it go on: no episode came back, and no file
    if process.returncode != 0 or not lines:
        error = (stderr.strip().splitlines() or ["no output"])[-1]
        raise CanterError(f"rendering failed in a subprocess: {error.removeprefix('canter: error: ')}")
    return json.loads(lines[-1])


def _wait_for_renderer(process: subprocess.Popen, stop: StopFlag) -> tuple[str, str]:
    """The render subprocess's stdout and stderr once it ends. A stop signal to this process is passed on to it as
    SIGTERM, a stop that it too takes at its next frame, removing its temp file (rather than render on as an
    orphan); it is killed if it has not ended within _STOP_SECONDS."""
    deadline = None
    while True:
        try:
            return process.communicate(timeout=_POLL_SECONDS)
        except subprocess.TimeoutExpired:
            if stop.signal is None:
                continue
            if deadline is None:
                process.terminate()
                deadline = time.monotonic() + _STOP_SECONDS
            elif time.monotonic() > deadline:
                process.kill()


def _main(argv: list[str]) -> int:
    """Entry point of the render subprocesses (`_record_in_subprocess`, `canter.training.videos`): one JSON request;
    prints the returns as JSON."""
    global _in_render_process
    _in_render_process = True
    request = json.loads(argv[0])
    parent = request.pop("parent", None)
    if parent is not None:
        # Killed, a trainer leaves its run folder to the next resume, which must not find an old renderer still
        # writing into it (Linux; elsewhere it renders on).
        die_with_parent(signal.SIGKILL, parent)
    nice = request.pop("nice", 0)
    if nice:
        os.nice(nice)
    started = time.perf_counter()
    try:
        returns = record_video(**request)
    except CanterError as exc:
        print(error_line(exc), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("canter: interrupted", file=sys.stderr)
        return INTERRUPTED
    print(f"{request['out_path']}: returns {returns} in {time.perf_counter() - started:.1f} s", file=sys.stderr)
    print(json.dumps(returns))
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
