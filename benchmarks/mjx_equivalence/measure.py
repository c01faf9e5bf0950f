"""How closely the mjx backend's ports follow Gymnasium's v5 tasks (C MuJoCo), per task, with uniform random actions.

- each step from the same state: before every step the MJX state is set to C MuJoCo's full MjData, both take the
  same action; the largest relative error (|a - b| / (1 + |b|)) of observation, reward and info over STEPS steps,
  and the number of steps whose termination flags differ;
- the same for C MuJoCo against itself with qpos moved by 1e-9 and left to run, which shows how fast the task is
  chaotic under random actions (errors there are not the port's).

Usage: python benchmarks/mjx_equivalence/measure.py [STEPS] [ENV ...]
CANTER_SOLVER=ITERATIONS,LS_ITERATIONS measures the ports with env.solver_iterations and env.solver_ls_iterations
set (C MuJoCo keeps the XML's); CANTER_PRECISION=float64 steps MJX in float64 (the default is float32, as in
training); JAX_DEFAULT_MATMUL_PRECISION=highest keeps a GPU's matrix products in full float32 (its default is
TensorFloat-32; benchmarks/gpu/run.sh precision measures both). results.md holds three tables:
    { python measure.py; echo; CANTER_SOLVER=4,8 python measure.py; echo; CANTER_PRECISION=float64 python measure.py; }
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import time

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

from canter.core.runtime import setup_jax
from canter.envs.mjx.env import MjxTaskEnv
from canter.envs.mjx.library import import_mjx
from canter.envs.mjx.tasks import TASKS


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.max(np.abs(a - b) / (1.0 + np.abs(b))))


def each_step(env_id: str, steps: int, iterations: int = 0, ls_iterations: int = 0) -> dict[str, float]:
    mjx = import_mjx()
    ported = MjxTaskEnv(env_id, iterations, ls_iterations)
    reference = gym.make(env_id)
    model, data = reference.unwrapped.model, reference.unwrapped.data
    model.opt.solver = ported.mj_model.opt.solver
    reference.reset(seed=3)
    step = jax.jit(ported.step)
    rng = np.random.default_rng(0)
    worst = {"obs": 0.0, "reward": 0.0, "info": 0.0, "flag_mismatches": 0, "terminations": 0}
    for _ in range(steps):
        state = mjx.put_data(model, data)
        action = rng.uniform(reference.action_space.low, reference.action_space.high).astype(np.float32)
        obs, reward, terminated, _, info = reference.step(action)
        _, p_obs, p_reward, p_terminated, p_info = step(state, jnp.asarray(action))
        worst["obs"] = max(worst["obs"], _rel(p_obs, obs))
        worst["reward"] = max(worst["reward"], _rel(p_reward, reward))
        worst["info"] = max([worst["info"]] + [_rel(p_info[k], info[k]) for k in p_info])
        worst["flag_mismatches"] += int(bool(p_terminated) != terminated)
        if terminated:
            worst["terminations"] += 1
            reference.reset()
    return worst


def chaos(env_id: str, steps: int) -> float:
    a, b = gym.make(env_id), gym.make(env_id)
    a.reset(seed=3)
    b.reset(seed=3)
    b.unwrapped.set_state(a.unwrapped.data.qpos + 1e-9, a.unwrapped.data.qvel.copy())
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(steps):
        action = rng.uniform(a.action_space.low, a.action_space.high).astype(np.float32)
        oa, _, ta, _, _ = a.step(action)
        ob, _, tb, _, _ = b.step(action)
        worst = max(worst, _rel(ob, oa))
        if ta or tb:
            break
    return worst


def main() -> None:
    steps = int(sys.argv[1]) if len(sys.argv) > 1 else 200
    iterations, ls_iterations = (int(x) for x in os.environ.get("CANTER_SOLVER", "0,0").split(","))
    envs = sys.argv[2:] or list(TASKS)
    setup_jax("mjx")
    precision = os.environ.get("CANTER_PRECISION", "float32")
    if precision not in ("float32", "float64"):
        sys.exit(f"CANTER_PRECISION={precision}: use float32 or float64")
    # float64 physics separate the port's errors from float32 rounding (the observation is still returned as float32).
    jax.config.update("jax_enable_x64", precision == "float64")
    # A copy of the work tree without .git, as a device machine may get, has no commit to name here.
    git_head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    commit = git_head or "unknown (no git checkout)"
    solver = (
        f"env.solver_iterations={iterations}, env.solver_ls_iterations={ls_iterations} (C MuJoCo: the XML's)"
        if iterations or ls_iterations
        else "the XML's solver settings on both"
    )
    print(f"# MJX ports against Gymnasium v5 ({steps} steps, uniform random actions; {solver})\n")
    print(
        f"{platform.processor() or platform.machine()}, {time.strftime('%Y-%m-%d')}, commit {commit}, "
        f"JAX {jax.__version__} on {jax.default_backend()}, physics in {precision}, matmul precision "
        f"{jax.config.jax_default_matmul_precision or 'default'}\n"
    )
    print("| task | obs | reward | info | flag mismatches | terminations | C vs C moved 1e-9 (free-running) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for env_id in envs:
        r = each_step(env_id, steps, iterations, ls_iterations)
        print(
            f"| {env_id} | {r['obs']:.1e} | {r['reward']:.1e} | {r['info']:.1e} | {r['flag_mismatches']} | "
            f"{r['terminations']} | {chaos(env_id, steps):.1e} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
