"""Time to score with canter's default preset: train each env for a fixed step budget that fits in 3 minutes,
with --max-minutes 3 as a guard, then evaluate 10 deterministic episodes. Median over seeds.

    .venv/bin/python benchmarks/time_to_score/run.py [--seeds 0,1,2] [--envs Hopper-v5:2.5e6,HalfCheetah-v5:3.5e6]

Appends a dated markdown section to benchmarks/time_to_score/results.md.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path

from canter.training.run_folder import cpu_name

ROOT = Path(__file__).resolve().parents[2]
CANTER = str(Path(sys.executable).with_name("canter"))
TARGETS = {"Hopper-v5": 2500.0, "HalfCheetah-v5": 5000.0}


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--envs", default="Hopper-v5:2.5e6,HalfCheetah-v5:3.5e6")
    parser.add_argument("--minutes", type=float, default=3.0)
    parser.add_argument(
        "--out-dir", default=str(ROOT / "benchmarks" / "runs" / ("tts-" + time.strftime("%Y%m%d-%H%M%S")))
    )
    parser.add_argument("--results", default=str(Path(__file__).with_name("results.md")))
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    rows = []
    for item in args.envs.split(","):
        env, _, steps = item.partition(":")
        for seed in seeds:
            out = Path(args.out_dir) / f"{env}__s{seed}"
            cmd = [
                CANTER,
                "train",
                env,
                "--seed",
                str(seed),
                "--total-steps",
                steps,
                "--max-minutes",
                str(args.minutes),
                "--quiet",
                "--out-dir",
                str(out),
                "--set",
                "run.tensorboard=false",
            ]
            start = time.perf_counter()
            subprocess.run(cmd, check=True)
            wall = time.perf_counter() - start
            run = next(p for p in out.iterdir() if p.is_dir())
            summary = json.loads((run / "summary.json").read_text())
            eval_json = out / "eval.json"
            subprocess.run(
                [CANTER, "eval", str(run), "--episodes", "10", "--json", str(eval_json)],
                check=True,
                stdout=subprocess.DEVNULL,
            )
            score = json.loads(eval_json.read_text())[0]
            rows.append(
                {
                    "env": env,
                    "seed": seed,
                    "steps": summary["global_step"],
                    "process_wall": wall,
                    "sps": summary["sps"],
                    "compile": summary["compile_seconds"],
                    "eval_mean": score["return_mean"],
                    "eval_std": score["return_std"],
                }
            )
            print(json.dumps(rows[-1]), flush=True)

    from importlib import metadata

    command = " ".join([".venv/bin/python", "benchmarks/time_to_score/run.py"] + sys.argv[1:])
    lines = [
        f"\n## {datetime.now():%Y-%m-%d %H:%M} — {cpu_name()}, {os.cpu_count()} cores, no GPU",
        f"canter {metadata.version('canter')}, jax {metadata.version('jax')}, envpool {metadata.version('envpool')}, "
        f"mujoco {metadata.version('mujoco')}. Command: `{command}`",
        "",
        "| env | seed | steps | process wall (s) | SPS (compile excluded) | compile (s) "
        "| eval return (10 eps, deterministic) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['env']} | {r['seed']} | {r['steps']:,} | {r['process_wall']:.0f} | {r['sps']:,.0f} | "
            f"{r['compile']:.1f} | {r['eval_mean']:.0f} ± {r['eval_std']:.0f} |"
        )
    lines += ["", "| env | median eval return over seeds | target | median process wall (s) |", "|---|---|---|---|"]
    for env in dict.fromkeys(r["env"] for r in rows):
        mine = [r for r in rows if r["env"] == env]
        med = statistics.median(r["eval_mean"] for r in mine)
        target = TARGETS.get(env)
        verdict = "" if target is None else (f"{target:.0f} ({'met' if med >= target else 'not met'})")
        lines.append(f"| {env} | {med:.0f} | {verdict} | {statistics.median(r['process_wall'] for r in mine):.0f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    path = Path(args.results)
    if not path.exists():
        path.write_text("# Time to score, canter default preset\n")
    with open(path, "a") as f:
        f.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
