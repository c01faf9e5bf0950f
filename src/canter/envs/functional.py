"""Vectorized envs whose physics is itself JAX (MJX, Brax), behind the `VecEnv` protocol.

A backend of this kind defines ONE env as two pure functions (`FunctionalEnv`): `reset(key) -> (physics, obs)` and
`step(physics, action) -> (physics, obs, reward, terminated, info)`. `FunctionalVecEnv` vmaps them over the envs
and adds what every canter backend shares: the step limit (truncation), and EnvPool's episode semantics
(`canter.envs.base`): the step after a done is an autoreset step that ignores its action and returns the fresh reset
observation, reward 0 and both flags false.

Unlike EnvPool's handle, the whole env state (`FunctionalState`) is a pytree of arrays with the envs on the leading
axis. So it can be checkpointed, and a resumed run continues its episodes in flight exactly; and several seeds'
envs train under a plain `jax.vmap`, each seed holding its own slice (`canter.envs.base.JaxVecEnv`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from canter.envs.base import EnvSpec, JaxVecEnv, StepOutput


@dataclass(frozen=True)
class FunctionalEnv:
    """One env as pure JAX functions of a single env (no batch axis).

    `step` must return a float32 observation [obs_dim], a float32 reward, a bool `terminated` and a dict of float32
    scalars with exactly `info_keys`."""

    obs_dim: int
    act_dim: int
    action_low: tuple[float, ...]
    action_high: tuple[float, ...]
    max_episode_steps: int | None
    info_keys: tuple[str, ...]
    reset: Callable[[jax.Array], tuple[Any, jnp.ndarray]]
    step: Callable[[Any, jnp.ndarray], tuple[Any, jnp.ndarray, jnp.ndarray, jnp.ndarray, dict]]


class FunctionalState(NamedTuple):
    """The state of N envs: every leaf has the envs on its leading axis."""

    physics: Any  # the backend's own pytree (mjx.Data, a Brax State)
    key: jax.Array  # [N, 2] uint32: each env's stream of reset noise
    elapsed: jnp.ndarray  # [N] int32 steps of the episode in flight
    needs_reset: jnp.ndarray  # [N] bool: the previous step ended an episode, so this step is an autoreset


def x64_enabled() -> bool:
    """Whether JAX has 64-bit types on (`canter.core.runtime.setup_jax` sets it per backend): a JAX env built in one
    precision must not be reused in the other."""
    return bool(jax.dtypes.canonicalize_dtype(jnp.float64) == jnp.float64)


def initial_keys(seeds: list[int]) -> jax.Array:
    """One raw PRNG key per env, from its env seed (`canter.core.seeding`), in one call: a key per call would be a
    device dispatch per env, seconds for thousands of envs on a GPU."""
    return jax.vmap(jax.random.PRNGKey)(jnp.asarray(seeds, jnp.uint32))


def vector_reset(env: FunctionalEnv, keys: jax.Array) -> tuple[FunctionalState, jnp.ndarray]:
    """Reset every env with its own key: the first state and observations [N, obs_dim]."""
    keys, reset_keys = _split(keys)
    physics, obs = jax.vmap(env.reset)(reset_keys)
    n = keys.shape[0]
    return FunctionalState(physics, keys, jnp.zeros((n,), jnp.int32), jnp.zeros((n,), bool)), obs


def vector_step(env: FunctionalEnv, state: FunctionalState, action: jnp.ndarray) -> tuple[FunctionalState, StepOutput]:
    """Step N envs with EnvPool's episode semantics: envs flagged `needs_reset` reset instead of stepping."""
    physics, obs, reward, terminated, info = jax.vmap(env.step)(state.physics, action.astype(jnp.float32))
    elapsed = state.elapsed + 1
    limit = env.max_episode_steps
    truncated = (elapsed >= limit) & ~terminated if limit else jnp.zeros_like(terminated)

    keys, reset_keys = _split(state.key)
    resetting = state.needs_reset
    # Most steps reset no env: skip the resets then (a batch-level cond; under a seed group's vmap it computes both).
    reset_physics, reset_obs = jax.lax.cond(
        jnp.any(resetting),
        lambda: jax.vmap(env.reset)(reset_keys),
        lambda: (state.physics, jnp.zeros_like(obs)),
    )

    def pick(fresh: jnp.ndarray, stepped: jnp.ndarray) -> jnp.ndarray:
        mask = resetting.reshape(resetting.shape + (1,) * (stepped.ndim - 1))
        return jnp.where(mask, fresh, stepped)

    zeros = jnp.zeros_like(reward)
    out = StepOutput(
        pick(reset_obs, obs).astype(jnp.float32),
        jnp.where(resetting, zeros, reward).astype(jnp.float32),
        terminated & ~resetting,
        truncated & ~resetting,
        {k: jnp.where(resetting, zeros, v).astype(jnp.float32) for k, v in info.items()},
    )
    new_state = FunctionalState(
        jax.tree.map(pick, reset_physics, physics),
        jnp.where(resetting[:, None], keys, state.key),
        jnp.where(resetting, 0, elapsed),
        out.terminated | out.truncated,
    )
    return new_state, out


def _split(keys: jax.Array) -> tuple[jax.Array, jax.Array]:
    pairs = jax.vmap(jax.random.split)(keys)
    return pairs[:, 0], pairs[:, 1]


class FunctionalVecEnv(JaxVecEnv):
    """`num_envs` copies of a `FunctionalEnv`. The jitted program steps them with `jax_step`; evaluation loops step
    them from numpy with `host_step`, which keeps its own state. The envs are reset when first asked for, so that
    `state_bytes` can size them before any memory is taken."""

    def __init__(self, env: FunctionalEnv, env_id: str, backend: str, num_envs: int, seeds: list[int]) -> None:
        if len(seeds) != num_envs:
            raise ValueError(f"{num_envs} envs need {num_envs} seeds, got {len(seeds)}")
        self.env = env
        self.spec = EnvSpec(
            id=env_id,
            backend=backend,
            num_envs=num_envs,
            obs_dim=env.obs_dim,
            act_dim=env.act_dim,
            action_low=env.action_low,
            action_high=env.action_high,
            max_episode_steps=env.max_episode_steps,
            info_keys=env.info_keys,
        )
        self._keys = initial_keys(seeds)
        self._started: tuple[FunctionalState, jnp.ndarray] | None = None

    def _start(self) -> tuple[FunctionalState, jnp.ndarray]:
        if self._started is None:
            self._started = _jitted(self.env).reset(self._keys)
        return self._started

    def state_shapes(self) -> Any:
        """The shapes and dtypes of the envs' state and first observations: nothing is computed."""
        return jax.eval_shape(_jitted(self.env).reset, self._keys)

    def state_bytes(self) -> int:
        """The memory the envs' state and first observations take, read from their shapes."""
        return sum(leaf.size * leaf.dtype.itemsize for leaf in jax.tree.leaves(self.state_shapes()))

    def reset(self) -> np.ndarray:
        return np.asarray(self._start()[1])

    def initial_state(self) -> FunctionalState:
        return self._start()[0]

    def jax_step(self, state: FunctionalState, action: jnp.ndarray) -> tuple[FunctionalState, StepOutput]:
        return vector_step(self.env, state, action)

    def host_step(self, action: np.ndarray) -> StepOutput:
        state, first_obs = self._start()
        state, out = _jitted(self.env).step(state, jnp.asarray(action, jnp.float32))
        self._started = (state, first_obs)
        return jax.tree.map(np.asarray, out)

    def play_episodes(self, act: Callable[[Any, jnp.ndarray], jnp.ndarray], args: Any, quota: np.ndarray) -> tuple:
        """Env i plays quota[i] whole episodes, all in one jitted program, with `act(args, obs) -> action` (a pure JAX
        function; `args` holds its arrays). Returns each env's episode returns and lengths in order, as lists.
        Stepping from the host costs a device call per step; this costs one per evaluation."""
        quota = np.asarray(quota, np.int32)
        play = _jitted_play(self.env, act, int(quota.max()))
        state, first_obs = self._start()
        returns, lengths = jax.device_get(play(args, state, jnp.asarray(first_obs), jnp.asarray(quota)))
        kept = [(i, j) for i in range(len(quota)) for j in range(quota[i])]
        return [float(returns[i, j]) for i, j in kept], [int(lengths[i, j]) for i, j in kept]

    def close(self) -> None:
        pass


class _Playing(NamedTuple):
    state: FunctionalState
    obs: jnp.ndarray
    prev_done: jnp.ndarray  # [N]: the next step is an autoreset step
    running_return: jnp.ndarray  # [N]
    running_length: jnp.ndarray  # [N]
    finished: jnp.ndarray  # [N] episodes finished so far
    returns: jnp.ndarray  # [N, Q]
    lengths: jnp.ndarray  # [N, Q]


@functools.cache
def _jitted_play(env: FunctionalEnv, act: Callable[..., Any], max_quota: int) -> Callable[..., Any]:
    """The episode loop of `play_episodes`, compiled once per env, policy function and largest quota. The
    bookkeeping is the host loop's (`canter.training.evaluation.run_episodes`): an autoreset step counts for
    nothing, and an env's episodes beyond its quota are played but not kept."""

    def play(args: Any, state: FunctionalState, obs: jnp.ndarray, quota: jnp.ndarray) -> tuple:
        n = obs.shape[0]
        rows = jnp.arange(n)

        def more(c: _Playing) -> jnp.ndarray:
            return jnp.any(c.finished < quota)

        def step(c: _Playing) -> _Playing:
            state, out = vector_step(env, c.state, act(args, c.obs))
            valid = ~c.prev_done
            running_return = c.running_return + out.reward * valid
            running_length = c.running_length + valid.astype(jnp.int32)
            done = (out.terminated | out.truncated) & valid
            keep = done & (c.finished < quota)
            slot = jnp.minimum(c.finished, max_quota - 1)
            returns = c.returns.at[rows, slot].set(jnp.where(keep, running_return, c.returns[rows, slot]))
            lengths = c.lengths.at[rows, slot].set(jnp.where(keep, running_length, c.lengths[rows, slot]))
            return _Playing(
                state,
                out.obs,
                done,
                jnp.where(done, 0.0, running_return),
                jnp.where(done, 0, running_length),
                c.finished + done.astype(jnp.int32),
                returns,
                lengths,
            )

        start = _Playing(
            state,
            obs,
            jnp.zeros((n,), bool),
            jnp.zeros((n,), jnp.float32),
            jnp.zeros((n,), jnp.int32),
            jnp.zeros((n,), jnp.int32),
            jnp.zeros((n, max_quota), jnp.float32),
            jnp.zeros((n, max_quota), jnp.int32),
        )
        end = jax.lax.while_loop(more, step, start)
        return end.returns, end.lengths

    return jax.jit(play)


class _Jitted(NamedTuple):
    reset: Callable[..., Any]
    step: Callable[..., Any]


@functools.cache
def _jitted(env: FunctionalEnv) -> _Jitted:
    """One jitted reset and step per env definition, so the envs that evaluations during training build again and
    again reuse one compiled program (per batch size) instead of compiling each time."""
    return _Jitted(jax.jit(functools.partial(vector_reset, env)), jax.jit(functools.partial(vector_step, env)))
