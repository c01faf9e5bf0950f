"""How the hc-net-deep policies move: each seed's final policy for one deterministic 1,000-step episode of Gymnasium's
HalfCheetah-v4 (env seed 0, as `canter video`), with the torso's pitch (the `rooty` hinge, qpos[2], which is not
wrapped, so whole turns add up) and its forward position.

    python benchmarks/reports/000-humanoidstandup-halfcheetah-ppo-rpo-sym/video/cheetah_pose.py BENCH_DIR

BENCH_DIR is the folder of `canter bench ... --out BENCH_DIR` for the hc-net-deep grid (checkpoints are not
archived); the result is written beside this file as cheetah_pose.json.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

from canter.use.policy import load

HERE = Path(__file__).resolve().parent
CELL = "HalfCheetah-v4__ppo__net.hidden=128-64-64"
SEEDS = (100, 101, 102)
STEPS = 1000


def pose(run: Path) -> dict[str, float]:
    policy = load(run)
    env = gym.make("HalfCheetah-v4")
    obs, _ = env.reset(seed=0)
    data = env.unwrapped.data
    pitch, total = [], 0.0
    for _ in range(STEPS):
        obs, reward, terminated, truncated, _ = env.step(policy(obs))
        total += float(reward)
        pitch.append(float(data.qpos[2]))
        if terminated or truncated:
            break
    angles = np.asarray(pitch)
    return {
        "return": total,
        "steps": len(angles),
        "forward_m": float(data.qpos[0]),
        # cos(pitch) < 0: the torso's top faces the floor, the cheetah is on its back
        "upside_down_fraction": float(np.mean(np.cos(angles) < 0)),
        "final_pitch_turns": float(angles[-1] / (2 * math.pi)),
        "most_pitch_turns": float(np.max(np.abs(angles)) / (2 * math.pi)),
    }


def main() -> int:
    bench = Path(sys.argv[1])
    result = {str(seed): pose(bench / f"{CELL}__s{seed}") for seed in SEEDS}
    (HERE / "cheetah_pose.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
