"""Players that replay a policy for a video: each steps one simulator's env and renders its frames.

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
import os
import re
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from canter.envs.dm_control_tasks import suite_task
from canter.errors import CanterError
from canter.use.renderer import gl_failure

FREE_CAMERA = -1  # MuJoCo's free camera, which every model has (Gymnasium's and dm_control's renderers take it)


def _camera_index(camera: str) -> int | None:
    """The index a --camera value gives (-1: the free camera), or None for a camera name."""
    return int(camera) if re.fullmatch(r"-?\d+", camera.strip()) else None


class GymnasiumPlayer:
    def __init__(self, env_id: str, width: int, height: int, camera: str | None) -> None:
        import gymnasium as gym

        from canter.envs.registry import held_only_elsewhere, resolve_backend, single_env_backend

        backend = single_env_backend()
        try:
            resolve_backend(env_id, backend.name)
        except CanterError:
            raise CanterError(
                f"cannot replay {env_id}: canter renders through {backend.label}'s envs, and {backend.label} has no "
                f"such env ({held_only_elsewhere(env_id)}), so a run of it has no video; canter eval scores it"
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


class DMControlPlayer:
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
