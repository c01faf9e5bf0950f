"""What loading a run's checkpoint costs, measured as whole `canter eval` processes of two source trees side by side.

Run with canter's interpreter from the repository root:

    .venv/bin/python benchmarks/load_cost/run.py --before REF [--algo td3] [--env HalfCheetah-v5] [--pairs 5]
                                                 [--resave] [--no-write]

It trains one short run with the tree of REF (so that both trees can read it), then times `canter eval RUN
--episodes 2` alternately with REF's `src/` and with this working tree's, A B A B, from outside: interpreter start,
imports, reading and restoring the checkpoint, the policy's compile and two episodes. Each process's peak memory is
the kernel's account of that child. Pairing keeps the ratio meaningful on a machine whose speed drifts. It writes the
raw timings (timings.jsonl) beside this file and appends a dated section with the machine, the commits and the
medians to results.md. `--resave` is for a tree that writes a newer checkpoint format than REF reads: the tree
under test then plays a copy of the run whose newest checkpoint it has written again, the same state in its own
format.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from statistics import median

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE.parent))  # benchmarks/, for two_trees

from two_trees import append_results, commits, extract_src, heading  # noqa: E402


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description="whole-process time of canter eval with two source trees")
    p.add_argument("--before", required=True, help="git ref of the tree to compare against")
    p.add_argument("--algo", default="td3")
    p.add_argument("--env", default="HalfCheetah-v5")
    p.add_argument("--pairs", type=int, default=5)
    p.add_argument("--resave", action="store_true", help="this tree plays a copy resaved in its checkpoint format")
    p.add_argument("--no-write", action="store_true", help="print only; write no files")
    return p.parse_args(argv)


def canter(src: Path, *args: str) -> list[str]:
    return ["env", f"PYTHONPATH={src}", sys.executable, "-m", "canter.cli", *args]


def timed(command: list[str]) -> tuple[float, float]:
    """Wall seconds and peak memory (MiB) of one whole process."""
    started = time.perf_counter()
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - started
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"failed: {' '.join(command)}: {proc.stderr.read().decode() if proc.stderr else ''}")
    return wall, usage.ru_maxrss / 1024


RESAVE = """
import sys
from canter.training import checkpoint
from canter.training.restore import load_state
_, _, state, header = load_state(sys.argv[1])
checkpoint.save(checkpoint.latest(sys.argv[1]), state, header)
"""


def resaved_copy(run: Path) -> Path:
    """A copy of the run whose newest checkpoint this tree has written again."""
    copy = run.with_name(run.name + "-resaved")
    shutil.copytree(run, copy)
    subprocess.run(["env", f"PYTHONPATH={ROOT / 'src'}", sys.executable, "-c", RESAVE, str(copy)], check=True)
    return copy


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    before, now = commits(args.before)
    with tempfile.TemporaryDirectory() as tmp:
        old = extract_src(before, Path(tmp))
        out = Path(tmp) / "runs"
        train = ["train", args.env, "--algo", args.algo, "--total-steps", "2000", "--quiet", "--out-dir", str(out)]
        subprocess.run(canter(old, *train, "--set", f"{args.algo}.learning_starts=1000"), check=True)
        run = next(out.iterdir())
        trees = {"before": old, "now": ROOT / "src"}
        runs = {"before": run, "now": resaved_copy(run) if args.resave else run}
        rows = []
        for pair in range(args.pairs):
            for label in ("before", "now") if pair % 2 == 0 else ("now", "before"):
                wall, peak = timed(canter(trees[label], "eval", str(runs[label]), "--episodes", "2"))
                rows.append({"pair": pair, "tree": label, "wall_s": round(wall, 3), "peak_mib": round(peak, 1)})
                print(rows[-1], flush=True)
    walls = {label: [r["wall_s"] for r in rows if r["tree"] == label] for label in trees}
    peaks = {label: [r["peak_mib"] for r in rows if r["tree"] == label] for label in trees}
    ratios = [n / b for n, b in zip(walls["now"], walls["before"])]
    lines = [
        heading(now, before),
        "",
        f"`canter eval RUN --episodes 2` of a {args.algo} {args.env} run (2,000 steps, its default replay buffer), "
        f"{args.pairs} pairs of whole processes"
        + (", the tree under test playing a copy resaved in its checkpoint format:" if args.resave else ":"),
        "",
        "| tree | wall s (median) | peak MiB (median) |",
        "|---|---:|---:|",
        f"| {before} (before) | {median(walls['before']):.2f} | {median(peaks['before']):.0f} |",
        f"| {now} (now) | {median(walls['now']):.2f} | {median(peaks['now']):.0f} |",
        "",
        f"Median of the paired ratios now/before: {median(ratios):.2f} (min {min(ratios):.2f}, max {max(ratios):.2f}).",
        "",
    ]
    print("\n".join(lines))
    if not args.no_write:
        title = "What loading a run costs: whole `canter eval` processes"
        shared = dict(before=before, now=now, algo=args.algo, env=args.env)
        append_results(HERE, title, lines, "timings.jsonl", rows, **shared)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
