"""How large an off-policy run's checkpoints are, with two source trees: the same short run trained by each.

Run with canter's interpreter from the repository root:

    .venv/bin/python benchmarks/checkpoint_size/run.py --before REF [--algo td3] [--env HalfCheetah-v5]
                                                       [--steps 12000] [--every 4000] [--no-write]

Each tree trains the run once, as a whole `canter train` process with its default replay buffer (1e6 transitions)
and a checkpoint every `--every` steps; the script lists the size of every checkpoint the run keeps and the
process's wall time. It writes the raw rows (sizes.jsonl) beside this file and appends a dated section with the
machine and the commits to results.md.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE.parent))  # benchmarks/, for two_trees

from two_trees import append_results, commits, extract_src, heading  # noqa: E402


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description="checkpoint sizes of one short off-policy run, with two source trees")
    p.add_argument("--before", required=True, help="git ref of the tree to compare against")
    p.add_argument("--algo", default="td3")
    p.add_argument("--env", default="HalfCheetah-v5")
    p.add_argument("--steps", type=int, default=12_000)
    p.add_argument("--every", type=int, default=4_000)
    p.add_argument("--no-write", action="store_true", help="print only; write no files")
    return p.parse_args(argv)


def train(src: Path, out: Path, args: argparse.Namespace) -> tuple[float, dict[str, int]]:
    """Wall seconds of one whole training process, and the bytes of each checkpoint its run keeps."""
    command = ["env", f"PYTHONPATH={src}", sys.executable, "-m", "canter.cli", "train", args.env]
    command += ["--algo", args.algo, "--total-steps", str(args.steps), "--quiet", "--out-dir", str(out)]
    command += ["--set", f"run.checkpoint_every={args.every}", "--set", f"{args.algo}.learning_starts=1000"]
    started = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - started
    run = next(out.iterdir())
    return wall, {p.name: p.stat().st_size for p in sorted((run / "checkpoints").glob("*.npz"))}


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    before, now = commits(args.before)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, src in (("before", extract_src(before, Path(tmp))), ("now", ROOT / "src")):
            wall, sizes = train(src, Path(tmp) / f"runs-{label}", args)
            rows.append({"tree": label, "train_wall_s": round(wall, 2), "checkpoint_bytes": sizes})
            print(rows[-1], flush=True)
    mib = {row["tree"]: {name: size / 2**20 for name, size in row["checkpoint_bytes"].items()} for row in rows}
    walls = {row["tree"]: row["train_wall_s"] for row in rows}
    names = sorted(set(mib["before"]) | set(mib["now"]))
    lines = [
        heading(now, before),
        "",
        f"A {args.algo} {args.env} run of {args.steps:,} steps (default replay buffer, learning_starts 1000), a "
        f"checkpoint every {args.every:,} steps, trained once by each tree (one whole process each):",
        "",
        f"| checkpoint | {before} (before) MiB | {now} (now) MiB |",
        "|---|---:|---:|",
        *(f"| {n} | {mib['before'].get(n, float('nan')):.1f} | {mib['now'].get(n, float('nan')):.1f} |" for n in names),
        f"| all kept | {sum(mib['before'].values()):.1f} | {sum(mib['now'].values()):.1f} |",
        f"| train wall s | {walls['before']:.1f} | {walls['now']:.1f} |",
        "",
    ]
    print("\n".join(lines))
    if not args.no_write:
        shared = dict(before=before, now=now, algo=args.algo, env=args.env)
        append_results(HERE, "How large an off-policy run's checkpoints are", lines, "sizes.jsonl", rows, **shared)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
