"""EnvPool's pools behind the `VecEnv` protocol."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from canter.envs.base import IGNORED_INFO_KEYS, EnvSpec, StepOutput
from canter.envs.envpool import NAME
from canter.envs.envpool.shards import default_shards, shard_sizes

# EnvPool rebuilds its Gymnasium spaces on every reset and host step, declaring float32 Boxes with float64 bounds
# (Pendulum, Box2D); Gymnasium warns about that cast each time. The warning is about EnvPool's own spec code and
# gives the user nothing to act on, so it is silenced for the process (this exact message only).
warnings.filterwarnings("ignore", message=r".*precision lowered by casting to float32")


def _flatten(obs: Any, keys: tuple[str, ...] | None, xp: Any) -> Any:
    if keys is None:
        return obs.astype(xp.float32)
    parts = [obs[k].reshape(obs[k].shape[0], -1).astype(xp.float32) for k in keys]
    return xp.concatenate(parts, axis=-1)


class EnvPoolVecEnv:
    """`shards` independent single-threaded pools splitting the envs as evenly as possible. Their XLA steps are
    independent operations in the jitted program, so XLA's CPU runtime runs them concurrently: two cores step physics
    at once, while no pool ever uses the multi-threaded mode that crashed."""

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        seeds: list[int],
        shards: int = 0,
        observation_keys: frozenset[str] | None = None,
        **kwargs: Any,
    ) -> None:
        """`observation_keys`: the entries of a Dict observation to keep (all when None)."""
        import envpool
        import gymnasium as gym

        sizes = shard_sizes(num_envs, shards or default_shards(num_envs))
        starts = np.cumsum([0] + sizes).tolist()
        self._slices = [slice(start, start + size) for start, size in zip(starts, sizes)]
        self._pools = [
            envpool.make(
                env_id,
                env_type="gymnasium",
                num_envs=size,
                batch_size=size,
                seed=list(seeds[part]),
                num_threads=1,
                **kwargs,
            )
            for size, part in zip(sizes, self._slices)
        ]
        pool = self._pools[0]
        obs_space, act_space = pool.observation_space, pool.action_space
        if not isinstance(act_space, gym.spaces.Box):
            raise ValueError(f"{env_id} has discrete actions")
        if isinstance(obs_space, gym.spaces.Dict):
            keep = observation_keys if observation_keys is not None else frozenset(obs_space.spaces)
            self._obs_keys: tuple[str, ...] | None = tuple(sorted(k for k in obs_space.spaces if k in keep))
            obs_dim = sum(_entry_size(obs_space[k].shape) for k in self._obs_keys)
        else:
            self._obs_keys = None
            obs_dim = int(np.prod(obs_space.shape))
        self._action_dtype = np.dtype(act_space.dtype)
        self._num_envs = num_envs
        resets = [p.reset() for p in self._pools]
        self._first_obs = np.concatenate([_flatten(obs, self._obs_keys, np) for obs, _ in resets])
        info = resets[0][1]
        self._info_keys = tuple(
            sorted(
                k
                for k, v in info.items()
                if k not in IGNORED_INFO_KEYS
                and isinstance(v, np.ndarray)
                and v.shape == (sizes[0],)
                and np.issubdtype(v.dtype, np.floating)
            )
        )
        config = pool.spec.config
        self.spec = EnvSpec(
            id=env_id,
            backend=NAME,
            num_envs=num_envs,
            obs_dim=obs_dim,
            act_dim=int(np.prod(act_space.shape)),
            action_low=tuple(float(x) for x in np.asarray(act_space.low).reshape(-1)),
            action_high=tuple(float(x) for x in np.asarray(act_space.high).reshape(-1)),
            max_episode_steps=int(getattr(config, "max_episode_steps", 0)) or None,
            info_keys=self._info_keys,
        )
        self._xla: list | None = None

    def reset(self) -> np.ndarray:
        # The pools were reset at construction; a second reset would advance the seeded reset streams.
        return self._first_obs

    def _xla_fns(self) -> list:
        if self._xla is None:
            self._xla = [p.xla() for p in self._pools]
        return self._xla

    def initial_state(self) -> Any:
        return tuple(x[0] for x in self._xla_fns())

    def jax_step(self, state: Any, action: Any) -> tuple[Any, StepOutput]:
        import jax.numpy as jnp

        action = action.astype(self._action_dtype)
        handles, outs = [], []
        for handle, xla, part in zip(state, self._xla_fns(), self._slices):
            handle, out = xla[3](handle, action[part])
            handles.append(handle)
            outs.append(out)
        return tuple(handles), self._merge(outs, jnp)

    def host_step(self, action: np.ndarray) -> StepOutput:
        # Every pool gets its actions before any result is awaited, so the pools step at once, as in `jax_step`.
        action = np.asarray(action, self._action_dtype)
        for pool, part in zip(self._pools, self._slices):
            pool.send(action[part])
        return self._merge([pool.recv(reset=False, return_info=True) for pool in self._pools], np)

    def _merge(self, outs: list, xp: Any) -> StepOutput:
        cat = xp.concatenate
        return StepOutput(
            cat([_flatten(o[0], self._obs_keys, xp) for o in outs]),
            cat([o[1].astype(xp.float32) for o in outs]),
            cat([o[2].astype(bool) for o in outs]),
            cat([o[3].astype(bool) for o in outs]),
            {k: cat([o[4][k].astype(xp.float32) for o in outs]) for k in self._info_keys},
        )

    def close(self) -> None:
        for pool in self._pools:
            close = getattr(pool, "close", None)
            if close is not None:
                close()


def _entry_size(shape: tuple[int, ...] | None) -> int:
    """Flat size of one entry of a Dict observation; a scalar entry is one number."""
    if shape is None:
        raise ValueError("a Dict observation entry has no shape")
    return int(np.prod(shape)) or 1
