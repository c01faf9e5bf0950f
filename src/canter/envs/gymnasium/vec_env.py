"""Gymnasium envs, one Python env object per slot, behind the `VecEnv` protocol.

It reproduces EnvPool's episode semantics (see `canter.envs.base`), so the learner trains identically on both.
Inside jit the step is an ordered `io_callback`; it is slower than EnvPool but runs everywhere.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from canter.envs.base import IGNORED_INFO_KEYS, EnvSpec, StepOutput
from canter.envs.gymnasium import NAME
from canter.envs.gymnasium.single import check_observation, make_single, user_code


class GymnasiumVecEnv:
    def __init__(self, env_id: str, num_envs: int, seeds: list[int], on_make: Any = None, **kwargs: Any) -> None:
        """`on_make(env)`, if given, is called on each env before its first reset (e.g. to edit a MuJoCo model)."""
        self._envs = [make_single(env_id, **kwargs) for _ in range(num_envs)]
        for env in self._envs if on_make is not None else ():
            on_make(env)
        first = self._envs[0]
        self._num_envs = num_envs
        self._needs_reset = np.zeros(num_envs, bool)
        with user_code(env_id, "reset"):
            observations, _infos = zip(*(env.reset(seed=int(seed)) for env, seed in zip(self._envs, seeds)))
        check_observation(env_id, first.observation_space, observations[0], "reset")
        self._first_obs = np.stack([np.asarray(o, np.float32).reshape(-1) for o in observations])
        # Probe one throwaway step on a separate env so the info keys are known before training starts.
        probe = make_single(env_id, **kwargs)
        space = probe.action_space  # 0, or the bound nearest it: an env may refuse an action outside its bounds
        with user_code(env_id, "reset or step"):
            probe.reset(seed=0)
            probe_obs, _, _, _, probe_info = probe.step(
                np.clip(np.zeros(space.shape), space.low, space.high).astype(space.dtype)
            )
        probe.close()
        check_observation(env_id, first.observation_space, probe_obs, "step")
        self._info_keys = tuple(
            sorted(
                k
                for k, v in probe_info.items()
                if k not in IGNORED_INFO_KEYS
                and np.ndim(v) == 0
                and isinstance(v, (int, float, np.number))
                and not isinstance(v, (bool, np.bool_))
            )
        )
        act = first.action_space
        spec = getattr(first, "spec", None)
        self.spec = EnvSpec(
            id=env_id,
            backend=NAME,
            num_envs=num_envs,
            obs_dim=int(np.prod(first.observation_space.shape)),
            act_dim=int(np.prod(act.shape)),
            action_low=tuple(float(x) for x in np.asarray(act.low).reshape(-1)),
            action_high=tuple(float(x) for x in np.asarray(act.high).reshape(-1)),
            max_episode_steps=getattr(spec, "max_episode_steps", None),
            info_keys=self._info_keys,
        )
        self._action_shape = act.shape
        self._action_dtype = act.dtype

    def reset(self) -> np.ndarray:
        return self._first_obs

    def initial_state(self) -> Any:
        import jax.numpy as jnp

        return jnp.zeros((), jnp.int32)

    def host_step(self, action: np.ndarray) -> StepOutput:
        n = self._num_envs
        obs = np.empty((n, self.spec.obs_dim), np.float32)
        reward = np.zeros(n, np.float32)
        terminated = np.zeros(n, bool)
        truncated = np.zeros(n, bool)
        infos = {k: np.zeros(n, np.float32) for k in self._info_keys}
        action = np.asarray(action)
        for i, env in enumerate(self._envs):
            if self._needs_reset[i]:
                o, _ = env.reset()
                self._needs_reset[i] = False
            else:
                a = action[i].reshape(self._action_shape).astype(self._action_dtype)
                o, r, term, trunc, info = env.step(a)
                reward[i], terminated[i], truncated[i] = r, term, trunc
                for k in self._info_keys:
                    if k in info:
                        infos[k][i] = info[k]
                self._needs_reset[i] = term or trunc
            obs[i] = np.asarray(o, np.float32).reshape(-1)
        return StepOutput(obs, reward, terminated, truncated, infos)

    def jax_step(self, state: Any, action: Any) -> tuple[Any, StepOutput]:
        import jax
        import jax.numpy as jnp
        from jax.experimental import io_callback

        n = self._num_envs
        shapes = StepOutput(
            jax.ShapeDtypeStruct((n, self.spec.obs_dim), jnp.float32),
            jax.ShapeDtypeStruct((n,), jnp.float32),
            jax.ShapeDtypeStruct((n,), jnp.bool_),
            jax.ShapeDtypeStruct((n,), jnp.bool_),
            {k: jax.ShapeDtypeStruct((n,), jnp.float32) for k in self._info_keys},
        )
        out = io_callback(lambda a: self.host_step(np.asarray(a)), shapes, action.astype(jnp.float32), ordered=True)
        return state + 1, StepOutput(*out)

    def close(self) -> None:
        for env in self._envs:
            env.close()
