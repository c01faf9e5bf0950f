"""What building a bench's scoreboard (results.md, statistics.json) costs for many methods, with two source trees.

Run with canter's interpreter from the repository root:

    .venv/bin/python benchmarks/scoreboard_cost/run.py --before REF [--methods 20 100] [--seeds 5] [--no-write]

For each method count it builds the scoreboard of the same synthetic final scores (5 envs, `--seeds` runs per
method and env, drawn from a fixed generator) in a fresh process of REF's `src/` and of this working tree's, and
times `build_scoreboard` inside each process. It checks that both trees write the same statistics.json, byte for
byte, and writes the raw timings (timings.jsonl) and a dated section of results.md beside this file.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE.parent))  # benchmarks/, for two_trees

from two_trees import append_results, commits, extract_src, heading  # noqa: E402

BUILD = """
import json, sys, time
import numpy as np
from canter.use.scoreboard import TRAINING_SOURCE, RunScore, build_scoreboard

methods, seeds = int(sys.argv[1]), int(sys.argv[2])
envs = ["Hopper-v4", "Walker2d-v4", "HalfCheetah-v4", "Ant-v4", "Humanoid-v4"]
rng = np.random.default_rng(0)
scores = [
    RunScore(f"ppo, lr={m}", env, "ppo", float(rng.normal(1000 + 10 * m, 300)), f"r{m}-{e}-{s}")
    for m in range(methods) for e, env in enumerate(envs) for s in range(seeds)
]
started = time.perf_counter()
board = build_scoreboard(scores, TRAINING_SOURCE)
seconds = time.perf_counter() - started
print(json.dumps({"seconds": round(seconds, 3), "comparisons": len(board.comparisons), "json": board.json()}))
"""


def build(src: Path, methods: int, seeds: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src))
    out = subprocess.run(
        [sys.executable, "-c", BUILD, str(methods), str(seeds)], env=env, check=True, capture_output=True, text=True
    ).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="build_scoreboard time with two source trees")
    p.add_argument("--before", required=True, help="git ref of the tree to compare against")
    p.add_argument("--methods", type=int, nargs="+", default=[20, 100])
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--no-write", action="store_true", help="print only; write no files")
    args = p.parse_args(argv)
    before, now = commits(args.before)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"before": extract_src(before, Path(tmp)), "now": ROOT / "src"}
        for methods in args.methods:
            built = {label: build(src, methods, args.seeds) for label, src in trees.items()}
            same = built["before"]["json"] == built["now"]["json"]
            for label, result in built.items():
                digest = hashlib.sha256(result["json"].encode()).hexdigest()[:16]
                rows.append(
                    dict(
                        tree=label,
                        methods=methods,
                        seeds=args.seeds,
                        seconds=result["seconds"],
                        comparisons=result["comparisons"],
                        statistics_sha256=digest,
                        same_json=same,
                    )
                )
                print(rows[-1], flush=True)
    lines = [
        heading(now, before),
        "",
        f"`build_scoreboard` of synthetic final scores: 5 envs, {args.seeds} seeds per method and env.",
        "",
        "| methods | pairs compared | before s | now s | statistics.json identical |",
        "|---:|---:|---:|---:|---|",
    ]
    for methods in args.methods:
        b, n = (next(r for r in rows if r["tree"] == t and r["methods"] == methods) for t in ("before", "now"))
        lines.append(f"| {methods} | {n['comparisons']} | {b['seconds']:.2f} | {n['seconds']:.2f} | {n['same_json']} |")
    lines.append("")
    print("\n".join(lines))
    if not args.no_write:
        title = "What building a scoreboard costs for many methods"
        append_results(HERE, title, lines, "timings.jsonl", rows, before=before, now=now)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
