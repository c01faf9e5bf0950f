"""What `run.compress_checkpoints` saves on a replay buffer of real observations, and what it costs.

Run with canter's interpreter from the repository root:

    .venv/bin/python benchmarks/checkpoint_size/deflate.py [--env HalfCheetah-v5] [--filled 20000] [--no-write]

It fills a 100,000-transition buffer with `--filled` transitions of random actions stepped by Gymnasium's MuJoCo, then
writes it as a checkpoint plain and deflated, part-filled and then filled (the filled rows repeated), and times each
write and read in this process. It appends a dated section with the machine and the commit to results.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

import gymnasium as gym
import numpy as np

from canter.training import checkpoint

HERE = Path(__file__).resolve().parent
CAPACITY = 100_000


def filled_buffer(env_id: str, filled: int) -> dict[str, np.ndarray]:
    env = gym.make(env_id)
    obs_dim, act_dim = env.observation_space.shape[0], env.action_space.shape[0]
    shapes = {"obs": (obs_dim,), "action": (act_dim,), "reward": (), "next_obs": (obs_dim,), "terminated": ()}
    buffer = {name: np.zeros((CAPACITY, *shape), np.float32) for name, shape in shapes.items()}
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=0)
    for row in range(filled):
        action = rng.uniform(-1, 1, act_dim).astype(np.float32)
        next_obs, reward, terminated, truncated, _ = env.step(action)
        for name, value in zip(shapes, (obs, action, reward, next_obs, terminated)):
            buffer[name][row] = value
        obs = env.reset()[0] if terminated or truncated else next_obs
    return buffer


def main() -> int:
    p = argparse.ArgumentParser(description="plain and deflated checkpoints of a replay buffer")
    p.add_argument("--env", default="HalfCheetah-v5")
    p.add_argument("--filled", type=int, default=20_000)
    p.add_argument("--no-write", action="store_true", help="print only; write no files")
    args = p.parse_args()
    buffer = filled_buffer(args.env, args.filled)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for fill in ("part-filled", "full"):
            if fill == "full":
                for array in buffer.values():
                    array[args.filled :] = np.resize(array[: args.filled], array[args.filled :].shape)
            for compress in (False, True):
                path = Path(tmp) / f"{fill}-{compress}.npz"
                started = time.perf_counter()
                checkpoint.save(path, {"buffer": buffer}, {"global_step": 1}, compress=compress)
                written = time.perf_counter() - started
                started = time.perf_counter()
                checkpoint.read(path)
                read = time.perf_counter() - started
                rows.append((fill, "deflated" if compress else "plain", path.stat().st_size / 2**20, written, read))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    lines = [
        f"## {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores, {commit}: deflate.py",
        "",
        f"A {CAPACITY:,}-transition buffer of {args.env} ({args.filled:,} transitions of random actions; full: those "
        "repeated), written as a checkpoint in one process:",
        "",
        "| buffer | written | MiB | write s | read s |",
        "|---|---|---:|---:|---:|",
        *(f"| {fill} | {how} | {mib:.2f} | {w:.2f} | {r:.2f} |" for fill, how, mib, w, r in rows),
        "",
    ]
    print("\n".join(lines))
    if not args.no_write:
        with (HERE / "results.md").open("a") as f:
            f.write("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
