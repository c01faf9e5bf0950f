"""What one EnvPool step costs canter beyond its physics, with one env (the `cleanrl` preset's case).

    python benchmarks/envpool_step/measure.py [STEPS] > benchmarks/envpool_step/results.md

Three timings per task, each the median of five repeats of STEPS steps with random actions in bounds:
- `physics`: C MuJoCo alone, `mujoco.mj_step(model, data, nstep=frame_skip)` on the task's own model, one Python
  call per env step (what any simulator pays, plus that call);
- `envpool, jitted`: the step as canter takes it, EnvPool's XLA custom call inside one `lax.scan` of STEPS steps;
- `envpool, host`: EnvPool's Python `step` called from a loop, for comparison;
- `64-64 policy alone` and `envpool + policy, jitted`: a 64-64 tanh MLP's action (the `cleanrl` preset's actor)
  chained step to step without an env, and between the jitted EnvPool steps, as in a rollout.
The difference between the jitted step and the physics is EnvPool's own cost per step: handing the action to its
worker thread and the result back, its reward and observation code, and the autoreset bookkeeping.
"""

from __future__ import annotations

import itertools
import platform
import statistics
import subprocess
import sys
import time

import numpy as np

# Tasks whose episodes never end early: a Hopper that falls would make EnvPool reset (autoreset steps carry no
# physics), which the physics loop does not.
TASKS = ("HalfCheetah-v5", "Swimmer-v5")


def median_seconds(run, repeats: int = 5) -> float:
    run()  # warm up (and compile)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def physics(env_id: str, steps: int) -> float:
    import gymnasium as gym
    import mujoco

    env = gym.make(env_id).unwrapped
    env.reset(seed=0)
    model, data, skip = env.model, env.data, env.frame_skip
    low, high = env.action_space.low, env.action_space.high
    actions = np.random.default_rng(0).uniform(low, high, size=(steps, len(low)))

    def run() -> None:
        for action in actions:
            data.ctrl[:] = action
            mujoco.mj_step(model, data, nstep=skip)

    return median_seconds(run) / steps


def envpool_jitted(env_id: str, steps: int, with_policy: bool) -> float:
    """EnvPool's XLA step in a `lax.scan`; `with_policy` puts a 64-64 tanh MLP's action between steps, as a rollout
    of the `cleanrl` preset does (its own cost is measured alone by `policy_alone`)."""
    import jax
    import jax.numpy as jnp

    from canter.core.runtime import setup_jax
    from canter.envs.registry import make_vec_env

    setup_jax("envpool")
    env = make_vec_env(env_id, "envpool", 1, [0])
    env.reset()
    low, high = env.spec.action_low, env.spec.action_high
    noise = jnp.asarray(np.random.default_rng(0).uniform(low, high, size=(steps, 1, len(low))), jnp.float32)
    weights = _mlp(env.spec.obs_dim, len(low))

    @jax.jit
    def roll(carry, noise):
        def body(carry, eps):
            state, obs = carry
            action = _act(weights, obs, eps) if with_policy else eps
            state, out = env.jax_step(state, action)
            return (state, out.obs.astype(jnp.float32)), out.reward

        return jax.lax.scan(body, carry, noise)

    holder = {"carry": (env.initial_state(), jnp.zeros((1, env.spec.obs_dim), jnp.float32))}

    def run() -> None:
        holder["carry"], rewards = roll(holder["carry"], noise)
        rewards.block_until_ready()

    seconds = median_seconds(run) / steps
    env.close()
    return seconds


def _mlp(obs_dim: int, act_dim: int) -> list:
    import jax.numpy as jnp

    rng = np.random.default_rng(1)
    sizes = (obs_dim, 64, 64, act_dim)
    return [
        (jnp.asarray(rng.normal(size=(a, b)) / np.sqrt(a), jnp.float32), jnp.zeros(b, jnp.float32))
        for a, b in itertools.pairwise(sizes)
    ]


def _act(weights: list, obs, eps):
    import jax.numpy as jnp

    x = obs
    for i, (w, b) in enumerate(weights):
        x = x @ w + b
        if i < len(weights) - 1:
            x = jnp.tanh(x)
    return x + 0.1 * eps


def policy_alone(env_id: str, steps: int) -> float:
    """The 64-64 MLP's action alone, chained step to step in a `lax.scan`, without an env."""
    import gymnasium as gym
    import jax
    import jax.numpy as jnp

    space = gym.make(env_id)
    obs_dim, act_dim = space.observation_space.shape[0], space.action_space.shape[0]
    weights = _mlp(obs_dim, act_dim)
    noise = jnp.asarray(np.random.default_rng(0).normal(size=(steps, 1, act_dim)), jnp.float32)
    pad = jnp.zeros((1, obs_dim - act_dim), jnp.float32) if obs_dim > act_dim else None

    @jax.jit
    def roll(obs, noise):
        def body(obs, eps):
            action = _act(weights, obs, eps)
            next_obs = jnp.concatenate([action, pad], axis=-1) if pad is not None else action[:, :obs_dim]
            return next_obs, action.sum()

        return jax.lax.scan(body, obs, noise)

    def run() -> None:
        _, out = roll(jnp.zeros((1, obs_dim), jnp.float32), noise)
        out.block_until_ready()

    return median_seconds(run) / steps


def envpool_host(env_id: str, steps: int) -> float:
    import envpool

    pool = envpool.make(env_id, env_type="gymnasium", num_envs=1, batch_size=1, seed=0, num_threads=1)
    pool.reset()
    space = pool.action_space
    actions = np.random.default_rng(0).uniform(space.low, space.high, size=(steps, 1, space.shape[0]))

    def run() -> None:
        for action in actions:
            pool.step(action)

    return median_seconds(run) / steps


def main() -> None:
    steps = int(sys.argv[1]) if len(sys.argv) > 1 else 20_000
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    with open("/proc/loadavg") as f:
        load = f.read().split()[0]
    print(f"# EnvPool's cost per step beyond its physics, one env ({steps:,} steps, median of 5)\n")
    machine = platform.processor() or platform.machine()
    print(f"{machine}, {time.strftime('%Y-%m-%d %H:%M')} UTC, commit {commit}, 1-minute load {load}\n")
    print(
        "| task | physics | envpool, jitted | envpool, host | jitted less physics | 64-64 policy alone | "
        "envpool + policy, jitted | that less physics and policy |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    us = 1e6
    for env_id in TASKS:
        p, j, h = physics(env_id, steps), envpool_jitted(env_id, steps, False), envpool_host(env_id, steps)
        a, r = policy_alone(env_id, steps), envpool_jitted(env_id, steps, True)
        print(
            f"| {env_id} | {p * us:.1f} | {j * us:.1f} | {h * us:.1f} | {(j - p) * us:.1f} | {a * us:.1f} | "
            f"{r * us:.1f} | {(r - p - a) * us:.1f} |",
            flush=True,
        )
    print("\nAll figures are microseconds per env step.")


if __name__ == "__main__":
    main()
