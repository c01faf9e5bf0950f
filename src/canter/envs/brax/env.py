"""One Brax env as a `FunctionalEnv`: the physics state is Brax's own `State`, stepped by Brax's MJX pipeline."""

from __future__ import annotations

import contextlib
import functools
import io
import warnings
from types import ModuleType
from typing import Any

import jax
import jax.numpy as jnp

from canter.envs.functional import FunctionalEnv, x64_enabled

# The physics pipeline canter runs Brax's envs on: MJX, the one Brax's current speed figures use.
PIPELINE = "mjx"
# Brax's published training settings cut episodes at 1000 steps (`episode_length=1000`).
MAX_EPISODE_STEPS = 1000
# Names Brax registers that canter does not offer, and why.
LEFT_OUT = {
    "fast": "a stub env of Brax's own tests",
    "swimmer": "Brax builds it on its older pipelines only, not on MJX",
}


@functools.cache
def brax_envs() -> ModuleType:
    """`brax.envs`, imported once. Importing MJX prints a line to stdout for each optional GPU library (warp) it
    lacks; those are not used here, so the lines are dropped."""
    with contextlib.redirect_stdout(io.StringIO()):
        import brax.envs

    return brax.envs


def env_names() -> list[str]:
    """Brax's env names that canter trains on, as Brax spells them."""
    return sorted(name for name in brax_envs()._envs if name not in LEFT_OUT)


def load_env(env_id: str) -> Any:
    """Brax's env `env_id` on the MJX pipeline."""
    with warnings.catch_warnings():
        # Brax warns on every model load that its own pipelines are unmaintained; canter uses MJX's.
        warnings.filterwarnings("ignore", message="Brax System, piplines and environments")
        return brax_envs().get_environment(env_id, backend=PIPELINE)


def functional_env(env_id: str) -> FunctionalEnv:
    """`env_id`, built once per process and precision: every env made for it (training, each evaluation) shares
    its model and compiled programs."""
    return _functional_env(env_id, x64_enabled())


@functools.cache
def _functional_env(env_id: str, x64: bool) -> FunctionalEnv:
    """`env_id` as pure functions of one Brax `State`.

    - observation: `state.obs` as float32; reward: `state.reward`; terminated: `state.done` (Brax's envs end
      episodes only by termination; the step limit is `FunctionalVecEnv`'s truncation, as Brax's EpisodeWrapper);
    - info: the scalar entries of `state.metrics` (reward terms, positions, velocities), under fixed keys;
    - action bounds [-1, 1]: Brax's envs declare none and Brax's own PPO acts in [-1, 1] (a tanh); where a model's
      ctrlrange is narrower (Humanoid's 0.4), MuJoCo clamps the control while the reward's control cost is charged
      on the action, exactly as under Brax's training."""
    env = load_env(env_id)
    template = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
    info_keys = tuple(sorted(key for key, value in template.metrics.items() if value.shape == ()))

    def reset(key: jax.Array) -> tuple[Any, jnp.ndarray]:
        state = env.reset(key)
        return state, state.obs.astype(jnp.float32)

    def step(state: Any, action: jnp.ndarray) -> tuple[Any, jnp.ndarray, jnp.ndarray, jnp.ndarray, dict]:
        state = env.step(state, action.astype(state.pipeline_state.ctrl.dtype))
        # Some envs store Python floats in a step's metrics; arrays of fixed dtypes keep the scan's carry stable.
        info = {key: jnp.asarray(state.metrics[key], jnp.float32) for key in info_keys}
        obs, reward = jnp.asarray(state.obs, jnp.float32), jnp.asarray(state.reward, jnp.float32)
        return state, obs, reward, jnp.asarray(state.done) > 0.5, info

    act_dim = int(env.action_size)
    return FunctionalEnv(
        obs_dim=int(template.obs.shape[-1]),
        act_dim=act_dim,
        action_low=(-1.0,) * act_dim,
        action_high=(1.0,) * act_dim,
        max_episode_steps=MAX_EPISODE_STEPS,
        info_keys=info_keys,
        reset=reset,
        step=step,
    )
