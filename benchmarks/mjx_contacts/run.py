"""env.contacts=floor against the XML's contacts: MJX physics steps per second of a ported task, on this machine.

For each task and setting, one jitted program steps `--envs` vmapped envs (the run's solver settings: 4 iterations,
8 line-search iterations) from slightly perturbed starting poses; after its compile, `--steps` steps are timed,
repeated `--rounds` times with the two settings alternating (A B A B), so that the ratio holds on a noisy machine.
Writes results.md beside this file with the machine, the date and the commit.

    python benchmarks/mjx_contacts/run.py                       # Humanoid-v5, 16 envs
    python benchmarks/mjx_contacts/run.py --tasks Humanoid-v5,Ant-v5 --envs 64
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

from canter.core.runtime import setup_jax

setup_jax("mjx")

import jax  # noqa: E402

from canter.envs.mjx.env import MjxTaskEnv  # noqa: E402
from canter.envs.mjx.library import import_mjx  # noqa: E402

HERE = Path(__file__).resolve().parent
SETTINGS = ("all", "floor")


def stepper(env_id: str, contacts: str, envs: int):
    """A compiled vmapped physics step, its starting data, and the number of contact slots MJX allots."""
    mjx = import_mjx()
    env = MjxTaskEnv(env_id, solver_iterations=4, solver_ls_iterations=8, contacts=contacts)
    data = mjx.make_data(env.model)
    slots = getattr(data, "_impl", data).contact.geom.shape[0]
    keys = jax.random.split(jax.random.key(0), envs)
    batch = jax.vmap(lambda k: data.replace(qpos=data.qpos + 0.01 * jax.random.normal(k, data.qpos.shape)))(keys)
    step = jax.jit(jax.vmap(lambda d: mjx.step(env.model, d)))
    return step, jax.block_until_ready(step(batch)), slots


def rate(step, batch, steps: int, envs: int) -> float:
    started = time.perf_counter()
    for _ in range(steps):
        batch = step(batch)
    jax.block_until_ready(batch)
    return steps * envs / (time.perf_counter() - started)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default="Humanoid-v5")
    parser.add_argument("--envs", type=int, default=16)
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    load = os.getloadavg()[0]  # other work on the machine slows both settings alike within a round
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=HERE).stdout
    rows = []
    for env_id in args.tasks.split(","):
        built = {c: stepper(env_id, c, args.envs) for c in SETTINGS}
        rates: dict[str, list[float]] = {c: [] for c in SETTINGS}
        for _ in range(args.rounds):
            for c in SETTINGS:
                rates[c].append(rate(built[c][0], built[c][1], args.steps, args.envs))
        medians = {c: statistics.median(rates[c]) for c in SETTINGS}
        rows.append(
            f"| {env_id} | {built['all'][2]} | {built['floor'][2]} | {medians['all']:,.0f} | {medians['floor']:,.0f} "
            f"| {medians['floor'] / medians['all']:.2f}x |"
        )
        print(rows[-1], flush=True)
    text = "\n".join(
        [
            "# env.contacts=floor: MJX physics speed (written by run.py)",
            "",
            f"{datetime.now(UTC):%Y-%m-%d %H:%M} UTC, commit {commit.strip()}, {platform.machine()}, "
            f"{jax.devices()[0].device_kind} ({jax.default_backend()}), JAX {jax.__version__}, Python "
            f"{sys.version.split()[0]}. Command: `python benchmarks/mjx_contacts/run.py {' '.join(sys.argv[1:])}`",
            "",
            f"{args.envs} vmapped envs, solver 4 x 8, median of {args.rounds} rounds of {args.steps} steps (A B A B). "
            f"Load average before the runs: {load:.1f}.",
            "",
            "| task | contact slots, all | contact slots, floor | physics steps/s, all | physics steps/s, floor "
            "| ratio |",
            "|---|---:|---:|---:|---:|---:|",
            *rows,
            "",
        ]
    )
    (HERE / "results.md").write_text(text)


if __name__ == "__main__":
    main()
