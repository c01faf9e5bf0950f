"""What the capsule contact frame and the GPU solver settings do to a trained Ant policy: one run's checkpoint,
evaluated with the same deterministic policy on C MuJoCo (EnvPool), on the mjx backend, on the mjx backend with MJX's
own colliders put back (canter.envs.mjx.collisions explains the difference; Ant's XML has no spheres touching
capsules, so for Ant only the capsule-plane frame differs), and on the mjx backend with env.solver_iterations=4 and
env.solver_ls_iterations=8, the settings of the GPU runs.

Usage: python benchmarks/mjx_equivalence/ant_policy.py RUN_DIR [EPISODES] > benchmarks/mjx_equivalence/ant_policy.md
Each evaluation is a `canter eval` process; their JSON files are written next to the output as ant_policy-*.json
(in the folder named by CANTER_ANT_JSON, default benchmarks/mjx_equivalence/)."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

# The mjx backend with canter's collision scoping replaced by a no-op, so MJX's own colliders step the contacts.
MJX_OWN_COLLIDER = (
    "import contextlib, sys; import canter.envs.mjx.env as env; "
    "env.c_mujoco_collisions = contextlib.nullcontext; "
    "from canter.cli.main import main; sys.exit(main(sys.argv[1:]))"
)


@dataclasses.dataclass(frozen=True)
class Physics:
    label: str
    backend: str
    program: str | None = None  # a `python -c` program in place of canter's command line
    sets: tuple[str, ...] = ()  # `canter eval --set` physics settings


PHYSICS = (
    Physics("C MuJoCo (EnvPool)", "envpool"),
    Physics("mjx, C MuJoCo's capsule frame (canter)", "mjx"),
    Physics("mjx, MJX's own capsule frame", "mjx", MJX_OWN_COLLIDER),
    Physics(
        "mjx, C MuJoCo's frame, env.solver_iterations=4, env.solver_ls_iterations=8",
        "mjx",
        sets=("env.solver_iterations=4", "env.solver_ls_iterations=8"),
    ),
)


def evaluate(run: Path, episodes: int, physics: Physics, out: Path) -> dict:
    args = ["eval", str(run), "--backend", physics.backend, "--episodes", str(episodes), "--json", str(out)]
    args += [arg for setting in physics.sets for arg in ("--set", setting)]
    program = ["-c", physics.program] if physics.program else ["-m", "canter.cli"]
    subprocess.run([sys.executable, *program, *args], check=True, stdout=subprocess.DEVNULL)
    return json.loads(out.read_text())["runs"][0]


def main() -> None:
    run = Path(sys.argv[1])
    episodes = int(sys.argv[2]) if len(sys.argv) > 2 else 50
    folder = Path(os.environ.get("CANTER_ANT_JSON", HERE))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    print(f"# A trained Ant-v5 policy on {len(PHYSICS)} physics\n")
    print(
        f"{platform.processor() or platform.machine()}, {time.strftime('%Y-%m-%d')}, commit {commit}; run "
        f"`{run.name}`, its last checkpoint, {episodes} deterministic episodes per row, evaluation seed 0\n"
    )
    print("| physics | mean return | std | standard error | episodes that ran 1000 steps |")
    print("|---|---:|---:|---:|---:|")
    for i, physics in enumerate(PHYSICS):
        row = evaluate(run, episodes, physics, folder / f"ant_policy-{i}.json")
        returns, lengths = row["returns"], row["lengths"]
        mean = sum(returns) / len(returns)
        std = math.sqrt(sum((r - mean) ** 2 for r in returns) / (len(returns) - 1))
        full = sum(1 for n in lengths if n == 1000)
        error = std / math.sqrt(len(returns))
        print(f"| {physics.label} | {mean:.0f} | {std:.0f} | {error:.0f} | {full} |", flush=True)


if __name__ == "__main__":
    main()
