"""EnvPool backend: native MuJoCo, Box2D and DM Control envs stepped in C++.

Training steps the pool inside the jitted rollout through EnvPool's XLA custom call. The pool always uses one
worker thread: with two threads the XLA path corrupted MuJoCo's memory here (the process dies with no Python
exception), and a crash no handler can catch must not be reachable from the CLI.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from canter.envs.base import IGNORED_INFO_KEYS, EnvSpec, StepOutput

# EnvPool families with continuous actions that canter trains on.
_CONTINUOUS_MODULES = ("envpool.mujoco.gym", "envpool.mujoco.dmc")
_CONTINUOUS_IDS = ("BipedalWalker-v3", "BipedalWalkerHardcore-v3", "LunarLanderContinuous-v2",
                   "LunarLanderContinuous-v3", "Pendulum-v1", "MountainCarContinuous-v0")


def available() -> bool:
    try:
        import envpool  # noqa: F401
    except Exception:
        return False
    return True


def supported_ids() -> list[str]:
    if not available():
        return []
    from envpool.registration import registry

    ids = []
    for env_id, spec in registry.specs.items():
        module = spec[0] if isinstance(spec, tuple) else ""
        if module in _CONTINUOUS_MODULES or env_id in _CONTINUOUS_IDS:
            ids.append(env_id)
    return ids


def _flatten(obs: Any, keys: tuple[str, ...] | None, xp: Any) -> Any:
    if keys is None:
        return obs.astype(xp.float32)
    parts = [obs[k].reshape(obs[k].shape[0], -1).astype(xp.float32) for k in keys]
    return xp.concatenate(parts, axis=-1)


class EnvPoolVecEnv:
    def __init__(self, env_id: str, num_envs: int, seeds: list[int], **kwargs: Any) -> None:
        import envpool
        import gymnasium as gym

        self._pool = envpool.make(env_id, env_type="gymnasium", num_envs=num_envs, batch_size=num_envs,
                                  seed=list(seeds), num_threads=1, **kwargs)
        obs_space, act_space = self._pool.observation_space, self._pool.action_space
        if not isinstance(act_space, gym.spaces.Box):
            raise ValueError(f"{env_id} has discrete actions")
        if isinstance(obs_space, gym.spaces.Dict):
            self._obs_keys: tuple[str, ...] | None = tuple(sorted(obs_space.spaces))
            obs_dim = sum(int(np.prod(obs_space[k].shape)) or 1 for k in self._obs_keys)
        else:
            self._obs_keys = None
            obs_dim = int(np.prod(obs_space.shape))
        self._action_dtype = np.dtype(act_space.dtype)
        self._num_envs = num_envs
        obs, info = self._pool.reset()
        self._first_obs = _flatten(obs, self._obs_keys, np)
        self._info_keys = tuple(sorted(k for k, v in info.items() if k not in IGNORED_INFO_KEYS
                                       and isinstance(v, np.ndarray) and v.shape == (num_envs,)
                                       and np.issubdtype(v.dtype, np.floating)))
        config = self._pool.spec.config
        self.spec = EnvSpec(
            id=env_id, backend="envpool", num_envs=num_envs, obs_dim=obs_dim, act_dim=int(np.prod(act_space.shape)),
            action_low=tuple(float(x) for x in np.asarray(act_space.low).reshape(-1)),
            action_high=tuple(float(x) for x in np.asarray(act_space.high).reshape(-1)),
            max_episode_steps=int(getattr(config, "max_episode_steps", 0)) or None, info_keys=self._info_keys)
        self._xla = None

    def reset(self) -> np.ndarray:
        # The pool was reset at construction; a second reset would advance the seeded reset streams.
        return self._first_obs

    def initial_state(self) -> Any:
        if self._xla is None:
            self._xla = self._pool.xla()
        return self._xla[0]

    def jax_step(self, state: Any, action: Any) -> tuple[Any, StepOutput]:
        import jax.numpy as jnp

        if self._xla is None:
            self._xla = self._pool.xla()
        step = self._xla[3]
        state, (obs, reward, terminated, truncated, info) = step(state, action.astype(self._action_dtype))
        infos = {k: info[k].astype(jnp.float32) for k in self._info_keys}
        return state, StepOutput(_flatten(obs, self._obs_keys, jnp), reward.astype(jnp.float32), terminated,
                                 truncated, infos)

    def host_step(self, action: np.ndarray) -> StepOutput:
        obs, reward, terminated, truncated, info = self._pool.step(np.asarray(action, self._action_dtype))
        infos = {k: np.asarray(info[k], np.float32) for k in self._info_keys}
        return StepOutput(_flatten(obs, self._obs_keys, np), np.asarray(reward, np.float32),
                          np.asarray(terminated, bool), np.asarray(truncated, bool), infos)

    def close(self) -> None:
        close = getattr(self._pool, "close", None)
        if close is not None:
            close()
