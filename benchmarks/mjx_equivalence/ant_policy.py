"""What the capsule contact frame does to a trained Ant policy: one run's checkpoint, evaluated with the same
deterministic policy on C MuJoCo (EnvPool), on the mjx backend, and on the mjx backend with MJX's own colliders put
back (canter.envs.mjx.collisions explains the difference; Ant's XML has no spheres touching capsules, so for Ant
only the capsule-plane frame differs).

Usage: python benchmarks/mjx_equivalence/ant_policy.py RUN_DIR [EPISODES] > benchmarks/mjx_equivalence/ant_policy.md
Each evaluation is a `canter eval` process; their JSON files are written next to the output as ant_policy-*.json
(in the folder named by CANTER_ANT_JSON, default benchmarks/mjx_equivalence/)."""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

# The mjx backend with canter's collider scoping replaced by a no-op, so MJX's own collider steps the contacts.
MJX_OWN_COLLIDER = (
    "import contextlib, sys; import canter.envs.mjx.env as env; "
    "env.c_mujoco_collisions = contextlib.nullcontext; "
    "from canter.cli.main import main; sys.exit(main(sys.argv[1:]))"
)

PHYSICS = {
    "C MuJoCo (EnvPool)": ("envpool", None),
    "mjx, C MuJoCo's capsule frame (canter)": ("mjx", None),
    "mjx, MJX's own capsule frame": ("mjx", MJX_OWN_COLLIDER),
}


def evaluate(run: str, episodes: int, backend: str, program: str | None, out: Path) -> dict:
    args = ["eval", run, "--backend", backend, "--episodes", str(episodes), "--json", str(out)]
    command = [sys.executable, "-c", program, *args] if program else [sys.executable, "-m", "canter.cli", *args]
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return json.loads(out.read_text())["runs"][0]


def main() -> None:
    run = sys.argv[1]
    episodes = int(sys.argv[2]) if len(sys.argv) > 2 else 50
    folder = Path(os.environ.get("CANTER_ANT_JSON", HERE))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    print("# A trained Ant-v5 policy on three physics\n")
    print(
        f"{platform.processor() or platform.machine()}, {time.strftime('%Y-%m-%d')}, commit {commit}; run "
        f"`{Path(run).name}`, its last checkpoint, {episodes} deterministic episodes per row, evaluation seed 0\n"
    )
    print("| physics | mean return | std | standard error | episodes that ran 1000 steps |")
    print("|---|---:|---:|---:|---:|")
    for i, (label, (backend, program)) in enumerate(PHYSICS.items()):
        row = evaluate(run, episodes, backend, program, folder / f"ant_policy-{i}.json")
        returns, lengths = row["returns"], row["lengths"]
        mean = sum(returns) / len(returns)
        std = math.sqrt(sum((r - mean) ** 2 for r in returns) / (len(returns) - 1))
        full = sum(1 for n in lengths if n == 1000)
        print(f"| {label} | {mean:.0f} | {std:.0f} | {std / math.sqrt(len(returns)):.0f} | {full} |", flush=True)


if __name__ == "__main__":
    main()
