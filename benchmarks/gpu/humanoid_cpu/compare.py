"""The `humanoid` part's PPO settings on C MuJoCo against the same run on MJX: returns at the same env steps.

    python benchmarks/gpu/humanoid_cpu/compare.py CPU_RUN GPU_RUN > benchmarks/gpu/humanoid_cpu/results.md

CPU_RUN is the run that benchmarks/gpu/humanoid_cpu/run.sh trains on this machine (EnvPool, the XML's solver);
GPU_RUN is an archived `humanoid` part run folder (mjx on a GPU). Both are seed 0 with the same settings, so where
their physics agree their training returns agree step for step. Reads only the run folders' files.
"""

from __future__ import annotations

import csv
import json
import sys
import tomllib
from pathlib import Path

# Humanoid-v5's goal (issue 26): a deterministic-eval return of 6000 within 5 minutes on one GPU.
GOAL = 6000.0
# Settings that must be equal for the two runs to be comparable step for step.
SHARED = ("ppo", "net")


def metrics(run_dir: Path) -> list[dict[str, str]]:
    with (run_dir / "metrics.csv").open() as f:
        return list(csv.DictReader(f))


def config(run_dir: Path) -> dict:
    return tomllib.loads((run_dir / "config.toml").read_text())


def device(run_dir: Path) -> str:
    versions = json.loads((run_dir / "versions.json").read_text())
    machine = versions["gpu"] or f"{versions['cpu']}, {versions['cpu_count']} cores"
    changes = " with uncommitted changes" if versions.get("canter_dirty") else ""
    return f"{machine}, JAX {versions['jax']}, commit {versions['canter_commit'][:7]}{changes}"


def fmt(value: str) -> str:
    return f"{float(value):,.1f}" if value else ""


def seconds(value: str) -> str:
    return f"{float(value):.0f}" if value else ""


def main() -> None:
    cpu_dir, gpu_dir = Path(sys.argv[1]), Path(sys.argv[2])
    cpu_config, gpu_config = config(cpu_dir), config(gpu_dir)
    for section in SHARED:
        if cpu_config[section] != gpu_config[section]:
            raise SystemExit(f"the runs' [{section}] settings differ; they do not compare step for step")
    cpu, gpu = metrics(cpu_dir), metrics(gpu_dir)
    gpu_env = gpu_config["env"]
    print("# Humanoid-v5 with the `humanoid` part's PPO settings: C MuJoCo against MJX, step for step\n")
    print(f"Written by `python benchmarks/gpu/humanoid_cpu/compare.py {cpu_dir} {gpu_dir}`.\n")
    print(
        f"Seed {cpu_config['run']['seed']} both; PPO with the brax preset's humanoid table "
        f"({cpu_config['env']['num_envs']} envs, ppo.n_steps {cpu_config['ppo']['n_steps']}, "
        f"minibatch {cpu_config['ppo']['minibatch_size']}, {cpu_config['ppo']['epochs']} epochs).\n"
    )
    print(f"- C MuJoCo: EnvPool, the XML's solver, `{cpu_dir.name}` ({device(cpu_dir)}).")
    print(
        f"- MJX: `{gpu_dir.name}` ({device(gpu_dir)}), env.solver_iterations {gpu_env.get('solver_iterations', 0)}, "
        f"env.solver_ls_iterations {gpu_env.get('solver_ls_iterations', 0)}.\n"
    )
    print(
        "| iteration | env steps (C MuJoCo) | training return, C MuJoCo | training return, MJX "
        "| wall s, C MuJoCo | wall s, MJX |"
    )
    print("|---:|---:|---:|---:|---:|---:|")
    for row in cpu:
        i = int(row["iteration"])
        other = gpu[i - 1] if i <= len(gpu) else {"episodic_return": "", "wall_time": ""}
        print(
            f"| {i} | {int(row['global_step']):,} | {fmt(row['episodic_return'])} | {fmt(other['episodic_return'])} "
            f"| {seconds(row['wall_time'])} | {seconds(other['wall_time'])} |"
        )
    evals = [r for r in cpu if r.get("eval/return_mean")]
    print("\nDeterministic evaluations of the C MuJoCo run (10 episodes each, C MuJoCo):\n")
    print("| env steps | eval return | eval episode length |")
    print("|---:|---:|---:|")
    for r in evals:
        print(f"| {int(r['global_step']):,} | {fmt(r['eval/return_mean'])} | {fmt(r['eval/length_mean'])} |")
    reached = [r for r in evals if float(r["eval/return_mean"]) >= GOAL]
    last = cpu[-1]
    verdict = (
        f"first reached {GOAL:,.0f} at {int(reached[0]['global_step']):,} env steps"
        if reached
        else f"did not reach {GOAL:,.0f} in {int(last['global_step']):,} env steps"
    )
    print(f"\nThe C MuJoCo run {verdict}.")
    log = cpu_dir / "train.log"
    if log.is_file():  # one line per process: a stop and its resume (EnvPool's episodes restart on resume)
        print("\nIts processes, as each one ended:\n")
        for line in log.read_text().splitlines():
            if line.startswith("steps "):
                print(f"- {line}")


if __name__ == "__main__":
    main()
