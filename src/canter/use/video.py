"""Videos of a trained policy, rendered headless (no GPU, no display).

MuJoCo picks its OpenGL platform from MUJOCO_GL when `mujoco` is first imported, so `configure_gl()` must run before
anything imports mujoco, gymnasium's MuJoCo envs or dm_control. It probes EGL, then OSMesa, each in a throwaway
subprocess (a failing GL library can abort the process instead of raising). When mujoco was already imported with
another platform, `record_video` renders in a subprocess instead.

Which simulator replays the policy:
- Gymnasium ids (MuJoCo, Box2D's BipedalWalker, custom `module:EnvId`): the Gymnasium env with render_mode
  "rgb_array". EnvPool's gym-style MuJoCo ids have the same observation layout as Gymnasium's, so EnvPool runs are
  replayed there with the run's saved (frozen) normalizer statistics; where the two envs of an id differ (the v4
  humanoids, `registry.replay_note`), a note says so.
- EnvPool's DM Control ids (WalkerWalk-v1): dm_control's suite and its own MuJoCo renderer, with the observation
  dict flattened in EnvPool's order (sorted keys).
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from canter.envs.dm_control_tasks import suite_task
from canter.errors import CanterError
from canter.files import OUTPUT_FILE_MODE, check_writable
from canter.signals import INTERRUPTED, StopFlag, die_with_parent
from canter.training.videos import child_env, quiet_fork

GL_PACKAGES = {"egl": "libegl1", "osmesa": "libosmesa6"}
DEFAULT_WIDTH, DEFAULT_HEIGHT, DEFAULT_FPS = 480, 360, 30
# GIF frame delays are whole hundredths of a second, and browsers play delays under 0.02 s at 0.1 s; faster MP4s
# than screens refresh only drop frames in the player.
FPS_LIMITS = {
    ".gif": (50, "its frame delays are hundredths of a second, and browsers slow shorter ones down"),
    ".mp4": (240, "faster than screens show"),
}
# What MuJoCo's own GL context reads from MUJOCO_GL (lower-cased): its renderers and its switches.
MUJOCO_GL_VALUES = frozenset(
    {"egl", "osmesa", "glfw", "glx", "cgl", "wgl", "enable", "on", "true", "1", "disable", "off", "false", "0"}
)
# Values under which MuJoCo's GLContext is GLFW's on Linux (its default, `enable` and the like), which opens an X11 or
# Wayland connection: headless, it fails only at the first frame, deep inside Gymnasium's renderer.
_DISPLAY_GL = frozenset({"glfw", "glx", "enable", "on", "true", "1"})
_NO_GL = frozenset({"disable", "off", "false", "0"})
_PLATFORM_GL = {"cgl": "Darwin", "wgl": "Windows", "glx": "Linux", "egl": "Linux", "osmesa": "Linux"}
# What to set instead, by platform.system(): canter chooses between the headless EGL and OSMesa on Linux only.
_GL_FIX = {
    "Linux": "unset MUJOCO_GL to let canter choose, or set egl or osmesa (headless)",
    "Darwin": "set MUJOCO_GL=cgl, or glfw with a display",
    "Windows": "set MUJOCO_GL=wgl, or glfw with a display",
}


def gl_fix(system: str | None = None) -> str:
    return _GL_FIX.get(system or platform.system(), _GL_FIX["Linux"])


MAX_SIDE = 4096  # larger offscreen framebuffers fail deep in MuJoCo's GL context
# A caller stopped by a signal waits this long for its render subprocess to stop: a frame, then the encoder's end.
_STOP_SECONDS = 30
_POLL_SECONDS = 0.1  # how soon a caller passes a stop signal on to its render subprocess
_PROBE = "import mujoco; c = mujoco.GLContext(16, 16); c.make_current(); c.free()"


# ------------------------------------------------------------------------------------------------------ OpenGL


def _probe(backend: str) -> bool:
    env = dict(os.environ, MUJOCO_GL=backend)
    env.pop("PYOPENGL_PLATFORM", None)
    try:
        with quiet_fork():
            done = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, timeout=120)
        return done.returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def unavailable_message(tried: list[str]) -> str:
    packages = " ".join(GL_PACKAGES[b] for b in tried if b in GL_PACKAGES) or " ".join(GL_PACKAGES.values())
    return (
        f"headless rendering is unavailable: MuJoCo could not open an OpenGL context with MUJOCO_GL="
        f"{' or '.join(tried)}; install the system package(s): apt-get install -y {packages}"
    )


def configure_gl() -> str:
    """Choose MUJOCO_GL for this process (a user's choice is kept if it works) and return it."""
    chosen = os.environ.get("MUJOCO_GL")
    if chosen:
        check_renderer_name(chosen)
        if chosen in GL_PACKAGES and "mujoco" not in sys.modules and not _probe(chosen):
            raise CanterError(unavailable_message([chosen]))
        return chosen
    if "mujoco" in sys.modules:
        raise CanterError(
            "mujoco was imported before MUJOCO_GL was set; set MUJOCO_GL=egl (or osmesa) in the environment"
        )
    for backend in GL_PACKAGES:
        if _probe(backend):
            os.environ["MUJOCO_GL"] = backend
            if backend == "osmesa":
                os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
            return backend
    raise CanterError(unavailable_message(list(GL_PACKAGES)))


def check_renderer_name(chosen: str) -> None:
    """Refuse a MUJOCO_GL that names none of MuJoCo's renderers."""
    if chosen.lower().strip() not in MUJOCO_GL_VALUES:
        raise CanterError(
            f"MUJOCO_GL={chosen} is not one of MuJoCo's renderers; set egl or osmesa (headless), glfw, glx, cgl "
            f"or wgl (a display), or unset it to let canter choose"
        )


def renderer_problem(chosen: str, system: str, environ: Mapping[str, str]) -> str | None:
    """Why MUJOCO_GL=`chosen` cannot render on this `system` (platform.system()) with these environment variables,
    or None. Kept apart from `configure_gl`, which accepts every name MuJoCo knows, whatever the machine."""
    value = chosen.lower().strip()
    if value in _NO_GL:
        return f"MUJOCO_GL={chosen} turns MuJoCo's rendering off; {gl_fix(system)}"
    if _PLATFORM_GL.get(value, system) != system:
        return f"MUJOCO_GL={chosen} is MuJoCo's renderer on {_PLATFORM_GL[value]}, not {system}; {gl_fix(system)}"
    if system == "Linux" and value in _DISPLAY_GL and not (environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY")):
        return f"MUJOCO_GL={chosen} needs a display, and DISPLAY is not set; {gl_fix(system)}"
    return None


def check_renderer() -> None:
    """Refuse, in one line and before any rendering, a MUJOCO_GL that cannot render here. Training with videos
    checks it before its run folder is made: a renderer that fails later costs only its videos."""
    if os.environ.get("MUJOCO_GL"):
        check_renderer_name(os.environ["MUJOCO_GL"])
    problem = renderer_problem(os.environ.get("MUJOCO_GL", ""), platform.system(), os.environ)
    if problem:
        raise CanterError(problem)


def _headless_in_this_process() -> bool:
    """True when MuJoCo in this process renders (or will render) through EGL or OSMesa."""
    if "mujoco" not in sys.modules:
        return True
    return sys.modules["mujoco"].GLContext.__module__ in ("mujoco.egl", "mujoco.osmesa")


# -------------------------------------------------------------------------------------------------- simulators

FREE_CAMERA = -1  # MuJoCo's free camera, which every model has (Gymnasium's and dm_control's renderers take it)


def _camera_index(camera: str) -> int | None:
    """The index a --camera value gives (-1: the free camera), or None for a camera name."""
    return int(camera) if re.fullmatch(r"-?\d+", camera.strip()) else None


def gl_failure(env_id: str, gl: str, error: str, warned: Sequence[str]) -> str:
    """The one line for MuJoCo's FatalError at the first frame: the first warning the glfw package gave as it
    failed (such as `X11: Failed to open display :1`) names the cause better than MuJoCo's own message."""
    # glfw formats its errors as `(code) b'text'`.
    reason = re.sub(r"^\(\d+\) b(['\"])(.*)\1$", r"\2", warned[0]) if warned else error.partition(",")[0]
    return f"cannot render {env_id} with MUJOCO_GL={gl}: {reason}; {gl_fix()}"


class _GymnasiumPlayer:
    def __init__(self, env_id: str, width: int, height: int, camera: str | None) -> None:
        import gymnasium as gym

        from canter.envs.registry import resolve_backend, single_env_backend

        backend = single_env_backend()
        try:
            resolve_backend(env_id, backend.name)
        except CanterError:
            raise CanterError(
                f"cannot replay {env_id}: Gymnasium has no such env to render, and canter renders through Gymnasium "
                f"(a run on Brax's own envs has no video; canter eval scores it)"
            ) from None
        entry = str(gym.spec(env_id.partition(":")[2] or env_id).entry_point)
        self.env_id = env_id
        self.size = (width, height)
        self._rendered = False
        kwargs: dict[str, Any] = {"render_mode": "rgb_array"}
        if "mujoco" in entry:
            kwargs.update(width=width, height=height)
            if camera is not None:
                index = _camera_index(camera)
                kwargs.update(camera_name=camera) if index is None else kwargs.update(camera_id=index)
        elif camera is not None:
            raise CanterError(f"--camera applies to MuJoCo envs; {env_id} has a fixed view")
        else:  # pygame draws these; its SDL would open a sound device and, headless, print an error at exit
            os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
            os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
        try:
            self.env = backend.make_single(env_id, **kwargs)
        except ValueError as exc:
            raise CanterError(f"{env_id}: {exc}") from None
        if camera is not None:
            self._check_camera(env_id, camera)

    def _check_camera(self, env_id: str, camera: str) -> None:
        """Gymnasium silently falls back to the free camera for an unknown name; say so instead."""
        import mujoco

        model = self.env.unwrapped.model
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, i) or str(i) for i in range(model.ncam)]
        index = _camera_index(camera)
        if (index is not None and not FREE_CAMERA <= index < model.ncam) or (index is None and camera not in names):
            self.env.close()
            raise CanterError(
                f"{env_id} has no camera {camera!r}; cameras: {', '.join([*names, f'{FREE_CAMERA} (the free camera)'])}"
                f", or omit --camera for the default view"
            )

    def _frame(self) -> np.ndarray:
        import mujoco

        # The first frame's warnings are held until it renders: the glfw package warns as it fails to open a display,
        # and then the first of them goes into the error's one line instead. Later frames warn as usual (held and
        # shown again, a warning would be shown at every frame).
        holding: contextlib.AbstractContextManager[Any] = (
            warnings.catch_warnings(record=True) if not self._rendered else contextlib.nullcontext([])
        )
        with holding as caught:
            try:
                frame = self.env.render()
            except mujoco.FatalError as exc:  # an OpenGL context that MuJoCo could not make
                warned = [str(w.message) for w in caught if type(w.message).__name__ == "GLFWError"]
                gl = os.environ.get("MUJOCO_GL", "")
                raise CanterError(gl_failure(self.env_id, gl, str(exc), warned)) from None
            except ValueError as exc:  # Gymnasium's MuJoCo renderer reports a bad camera name here
                raise CanterError(f"cannot render: {exc}") from None
            except RuntimeError as exc:  # pygame.error: an SDL driver from the environment that this machine lacks
                driver = os.environ.get("SDL_VIDEODRIVER", "dummy")
                fix = (
                    f"; SDL_VIDEODRIVER={driver} asks for it: unset it, or set it to dummy" if driver != "dummy" else ""
                )
                raise CanterError(f"cannot render {self.env_id}: {exc}{fix}") from None
        for w in caught or ():
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
        self._rendered = True
        return _resize(np.asarray(frame), self.size)

    def episode(self, policy: Any, seed: int, max_steps: int, on_frame: Callable[[np.ndarray], None]) -> float:
        obs, _ = self.env.reset(seed=seed)
        on_frame(self._frame())
        total, steps, done = 0.0, 0, False
        while not done and (max_steps <= 0 or steps < max_steps):
            action = policy(np.asarray(obs, np.float32).reshape(-1), deterministic=True)
            obs, reward, terminated, truncated, _ = self.env.step(
                action.reshape(self.env.action_space.shape).astype(self.env.action_space.dtype)
            )
            total += float(reward)
            steps += 1
            done = terminated or truncated
            on_frame(self._frame())
        return total

    def close(self) -> None:
        self.env.close()


class _DMControlPlayer:
    def __init__(self, domain: str, task: str, width: int, height: int, camera: str | None) -> None:
        try:
            from dm_control import suite
        except ImportError:
            raise CanterError(
                "rendering a DM Control run needs dm_control: pip install 'dm_control==1.0.38' (the "
                "last release that works with the pinned mujoco 3.6.0)"
            ) from None
        found = suite_task(suite, domain, task)
        if found is None:
            raise CanterError(f"dm_control has no task {domain}/{task} to replay this run in")
        self._suite = suite
        self._domain, self._task = found
        self.width, self.height = width, height
        index = None if camera is None else _camera_index(camera)
        self.camera: int | str = index if index is not None else (camera or 0)
        self.env: Any = None  # dm_control's Environment of the current episode (dm_control has no type hints)

    def episode(self, policy: Any, seed: int, max_steps: int, on_frame: Callable[[np.ndarray], None]) -> float:
        self.env = self._suite.load(self._domain, self._task, task_kwargs={"random": seed})
        step = self.env.reset()
        on_frame(self._frame())
        total, steps = 0.0, 0
        while not step.last() and (max_steps <= 0 or steps < max_steps):
            obs = np.concatenate(
                [np.asarray(step.observation[k], np.float32).reshape(-1) for k in sorted(step.observation)]
            )
            step = self.env.step(policy(obs, deterministic=True).astype(np.float64))
            total += float(step.reward or 0.0)
            steps += 1
            on_frame(self._frame())
        return total

    def _frame(self) -> np.ndarray:
        try:
            return self.env.physics.render(self.height, self.width, camera_id=self.camera)
        except ValueError as exc:
            raise CanterError(f"cannot render: {exc}") from None

    def close(self) -> None:
        if self.env is not None:
            self.env.close()


def _resize(frame: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    if (frame.shape[1], frame.shape[0]) == size:
        return frame
    from PIL import Image

    return np.asarray(Image.fromarray(frame).resize(size, Image.Resampling.BILINEAR))


# ------------------------------------------------------------------------------------------------------ writing


class _GifWriter:
    """GIF frames held in memory (Pillow holds them until the end anyway) and encoded at close in one write, so
    that a failed write raises there, once, rather than again from a finalizer."""

    def __init__(self, path: Path, fps: int) -> None:
        self.path, self.fps = path, fps
        self.frames: list[np.ndarray] = []

    def append_data(self, frame: np.ndarray) -> None:
        self.frames.append(frame)

    def close(self) -> None:
        import imageio.v3 as iio

        frames, self.frames = self.frames, []
        if frames:
            data = iio.imwrite("<bytes>", np.stack(frames), extension=".gif", duration=1000.0 / self.fps, loop=0)
            self.path.write_bytes(data)


_TEMP_MARK = ".tmp"  # ends the stem of every temp video (`_AtomicVideo`): what `is_unfinished_video` looks for


def is_unfinished_video(path: Path) -> bool:
    """Whether `path` is the temp file of a video (`.NAME.<random>.tmp.mp4` beside NAME.mp4): one still being
    rendered, or left by a renderer that was killed. Readers of a videos/ folder skip these."""
    name = Path(path).name
    return name.startswith(".") and Path(Path(name).stem).suffix == _TEMP_MARK


class _AtomicVideo:
    """Frames go to a temp file beside the output, renamed into place only once the video is complete."""

    def __init__(self, out: Path, fps: int) -> None:
        import imageio.v2 as imageio

        suffix = out.suffix.lower()
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            fd, name = tempfile.mkstemp(prefix=f".{out.stem}.", suffix=f"{_TEMP_MARK}{suffix}", dir=out.parent)
            os.close(fd)
        except OSError as exc:
            raise CanterError(f"cannot write {out}: {exc.strerror or exc}; pick a writable path") from None
        self.out, self.tmp, self.frames = out, Path(name), 0
        self.writer: Any
        try:
            if suffix == ".gif":
                self.writer = _GifWriter(self.tmp, fps)
            else:
                self.writer = imageio.get_writer(
                    self.tmp,
                    format="FFMPEG",
                    mode="I",
                    fps=fps,
                    codec="libx264",
                    pixelformat="yuv420p",
                    macro_block_size=1,
                    quality=7,
                    ffmpeg_log_level="fatal",  # a failed write is reported by commit() as one line
                )
        except BaseException:  # an error, or a second Ctrl-C, before the caller has a writer to abort
            self.tmp.unlink(missing_ok=True)
            raise

    def append(self, frame: np.ndarray) -> None:
        try:
            self.writer.append_data(np.ascontiguousarray(frame[..., :3], dtype=np.uint8))
        except OSError as exc:  # the encoder died, or (GIF) the write failed
            raise self._write_error(exc) from None
        self.frames += 1

    def _write_error(self, exc: OSError | None) -> CanterError:
        from canter.files import WriteError, is_write_error

        if exc is not None and is_write_error(exc):
            return WriteError(self.out, exc)
        # ffmpeg reports a failed write (a full disk) only on its stderr and exit status, which imageio drops.
        return CanterError(
            f"cannot write {self.out}: the video encoder could not finish the file (is {self.out.parent} full?); "
            f"free space in {self.out.parent}, then run the command again"
        )

    def commit(self) -> None:
        try:
            self.writer.close()
            if self.tmp.suffix.endswith(".mp4"):
                import imageio_ffmpeg

                imageio_ffmpeg.count_frames_and_secs(str(self.tmp))  # fails on a file ffmpeg could not finish
        except (OSError, RuntimeError) as exc:
            raise self._write_error(exc if isinstance(exc, OSError) else None) from None
        os.chmod(self.tmp, OUTPUT_FILE_MODE)  # mkstemp's 0600 is for the temp file, not the video
        os.replace(self.tmp, self.out)

    def abort(self) -> None:
        try:
            with contextlib.suppress(Exception):  # the temp file goes either way
                self.writer.close()
        finally:  # also when a second Ctrl-C cuts the close short
            self.tmp.unlink(missing_ok=True)


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
    from canter.envs.registry import dm_control_task, note_replay, single_env_backend
    from canter.training.checkpoint import read_header, resolve

    if not str(out_path).strip():  # Path("") is ".", which the suffix check would name instead
        raise CanterError("--out is empty; give the file to write, e.g. --out policy.mp4 (or .gif)")
    out = Path(out_path)
    check_video_args(out, episodes, width, height, fps, max_steps)
    header = read_header(resolve(Path(run_dir), checkpoint))
    if dm_control_task(header["env"]["id"]) is None:  # here, not in a render subprocess, whose output is not shown
        note_replay(header["env"]["id"], header["env"]["backend"], single_env_backend().name)
    if not _headless_in_this_process():
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

    configure_gl()
    check_renderer()
    policy = load(run_dir, checkpoint)
    task = dm_control_task(policy.facts.env_id)
    player = (
        _DMControlPlayer(*task, width, height, camera)
        if task
        else _GymnasiumPlayer(policy.facts.env_id, width, height, camera)
    )
    returns = []
    # SIGINT and SIGTERM set a flag that the next frame acts on, as they stop training at the next iteration: raised
    # in a handler, an exception could be lost (`StopFlag`).
    with _stop_flag(stop) as flag:
        try:
            with quiet_fork():  # imageio runs ffmpeg to check it, then again at the first frame
                writer = _AtomicVideo(out, fps)
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
        print(f"canter: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("canter: interrupted", file=sys.stderr)
        return INTERRUPTED
    print(f"{request['out_path']}: returns {returns} in {time.perf_counter() - started:.1f} s", file=sys.stderr)
    print(json.dumps(returns))
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
