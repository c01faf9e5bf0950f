"""What evaluation during training (`canter train --eval-every N`) costs in whole-process wall time.

Run with canter's interpreter from the repository root, on an otherwise idle machine:

    .venv/bin/python benchmarks/eval_cost/run.py [--env HalfCheetah-v5] [--total-steps 1000000]
                                                 [--eval-every 500000] [--eval-episodes 10] [--reps 3]
                                                 [--seed 0] [--no-write]

Each repetition runs two whole `canter train ENV --total-steps N --seed S --quiet` processes with the default preset,
one without evaluation and one with `--eval-every N --eval-episodes K`, alternating which goes first, and times each
from outside (interpreter start, imports, env and model setup, compile, training, evaluations, checkpoints). The
logged SPS excludes everything outside the jitted iterations, evaluations included, so only this time shows their
cost. It writes the raw timings (timings.jsonl) and every process's output (logs/) beside this file, and appends a
dated section with the machine, the commit and the ratio to results.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path
from statistics import median

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
LIMIT = 1.05  # issue 25: evaluation adds at most 5% to whole-process wall time at the recommended interval


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description="whole-process wall time of canter train with and without evaluation")
    p.add_argument("--env", default="HalfCheetah-v5")
    p.add_argument("--total-steps", type=int, default=1_000_000)
    p.add_argument("--eval-every", type=int, default=500_000, help="the interval docs/see.md recommends")
    p.add_argument("--eval-episodes", type=int, default=10)
    p.add_argument("--reps", type=int, default=3, help="pairs of runs (one without and one with evaluation)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--runs-dir", default=None, help="run folders (default: a temporary folder, deleted after)")
    p.add_argument("--no-write", action="store_true", help="print the section; write no file here")
    return p.parse_args(argv)


def command(args: argparse.Namespace, out_dir: Path, evaluates: bool) -> list[str]:
    argv = [
        str(Path(sys.executable).parent / "canter"),
        "train",
        args.env,
        "--total-steps",
        str(args.total_steps),
        "--seed",
        str(args.seed),
        "--quiet",
        "--out-dir",
        str(out_dir),
    ]
    if evaluates:
        argv += ["--eval-every", str(args.eval_every), "--eval-episodes", str(args.eval_episodes)]
    return argv


def timed_run(argv: list[str], log: Path) -> dict:
    """Wall and CPU seconds of one whole process, and what its run folder recorded."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load = os.getloadavg()[0]
    started = time.perf_counter()
    done = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    log.write_text(f"$ {' '.join(argv)}\n{done.stdout}{done.stderr}exit {done.returncode}, wall {wall:.2f} s\n")
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed (exit {done.returncode}); see {log}")
    run_dir = Path(done.stdout.split("run: ", 1)[1].splitlines()[0])
    summary = json.loads((run_dir / "summary.json").read_text())
    versions = json.loads((run_dir / "versions.json").read_text())
    return {
        "wall_s": round(wall, 3),
        "cpu_s": round(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, 3),
        "load_before": round(load, 2),
        "steps": summary["global_step"],
        "sps": round(summary["sps"], 1),
        "compile_s": round(summary["compile_seconds"], 2),
        "evaluations": _evaluations(run_dir),
        "commit": versions.get("canter_commit"),
        "dirty": versions.get("canter_dirty"),
    }


def _evaluations(run_dir: Path) -> int:
    import csv

    with open(run_dir / "metrics.csv", newline="") as f:
        return sum(1 for row in csv.DictReader(f) if row.get("eval/return_mean"))


def _machine() -> str:
    from canter.training.run_folder import cpu_name

    try:
        mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError):
        mem = float("nan")
    system = f"{platform.platform()}, Python {platform.python_version()}"
    return f"{cpu_name()}, {os.cpu_count()} logical cores, {mem:.0f} GiB, {system}"


def section(args: argparse.Namespace, rows: list[dict]) -> str:
    off = [r for r in rows if not r["evaluates"]]
    on = [r for r in rows if r["evaluates"]]
    wall_off, wall_on = median(r["wall_s"] for r in off), median(r["wall_s"] for r in on)
    ratio = wall_on / wall_off
    pair_ratios = [b["wall_s"] / a["wall_s"] for a, b in zip(off, on)]
    cpu_ratio = median(r["cpu_s"] for r in on) / median(r["cpu_s"] for r in off)
    # Wall time outside the jitted iterations (imports, setup, compile, checkpoints and evaluations): other load on
    # the machine changes the training speed of a run, which this leaves out.
    outside = {id(r): r["wall_s"] - r["steps"] / r["sps"] for r in rows}
    extra = median(outside[id(r)] for r in on) - median(outside[id(r)] for r in off)
    commit = rows[0]["commit"] or "unknown"
    dirty = rows[0]["dirty"]
    lines = [
        f"## {datetime.now(UTC):%Y-%m-%d %H:%M} UTC — {args.env}, {args.total_steps:,} steps, "
        f"--eval-every {args.eval_every:,} --eval-episodes {args.eval_episodes}",
        "",
        f"- machine: {_machine()}",
        f"- canter commit: {commit}" + (" (working tree modified)" if dirty else ""),
        f"- command: `canter train {args.env} --total-steps {args.total_steps} --seed {args.seed} --quiet` (default "
        f"preset), with and without `--eval-every {args.eval_every} --eval-episodes {args.eval_episodes}`; "
        f"{args.reps} alternating pairs",
        f"- 1-minute load average before each run: {', '.join(str(r['load_before']) for r in rows)} (above 0 means "
        f"something else was using the cores)",
        "",
        "| rep | order | evaluation | process wall (s) | outside training (s) | CPU (s) | SPS | compile (s) | evals |",
        "|---:|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['rep']} | {r['order']} | {'on' if r['evaluates'] else 'off'} | {r['wall_s']:.1f} "
            f"| {outside[id(r)]:.1f} | {r['cpu_s']:.1f} "
            f"| {r['sps']:,.0f} | {r['compile_s']:.1f} | {r['evaluations']} |"
        )
    lines += [
        "",
        f"- median process wall: {wall_off:.1f} s without, {wall_on:.1f} s with evaluation: "
        f"**ratio {ratio:.3f}** (limit {LIMIT:.2f}: {'met' if ratio <= LIMIT else 'NOT met'})",
        f"- per-pair ratios: {', '.join(f'{x:.3f}' for x in pair_ratios)}; median CPU-time ratio {cpu_ratio:.3f}",
        f"- wall time outside training (wall − steps / SPS; SPS excludes compile and evaluations): median "
        f"{extra:+.2f} s with evaluation, i.e. a ratio of {(wall_off + extra) / wall_off:.3f} at equal training speed",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logs = HERE / "logs" if not args.no_write else Path(os.environ.get("TMPDIR", "/tmp")) / "eval_cost_logs"
    logs.mkdir(parents=True, exist_ok=True)
    runs = Path(args.runs_dir) if args.runs_dir else Path(os.environ.get("TMPDIR", "/tmp")) / "canter_eval_cost"
    rows = []
    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    try:
        for rep in range(1, args.reps + 1):
            order = (False, True) if rep % 2 else (True, False)
            for position, evaluates in enumerate(order, 1):
                name = f"{stamp}_rep{rep}_{'on' if evaluates else 'off'}"
                result = timed_run(command(args, runs / name, evaluates), logs / f"{name}.log")
                row = {"rep": rep, "order": position, "evaluates": evaluates, **result}
                print(json.dumps(row), flush=True)
                rows.append(row)
    finally:
        if not args.runs_dir:
            shutil.rmtree(runs, ignore_errors=True)
    text = section(args, rows)
    print(text)
    if not args.no_write:
        with open(HERE / "timings.jsonl", "a") as f:
            for row in rows:
                f.write(json.dumps({"stamp": stamp, "env": args.env, "total_steps": args.total_steps, **row}) + "\n")
        results = HERE / "results.md"
        if not results.exists():
            results.write_text(
                "# Cost of evaluation during training\n\nWritten by `benchmarks/eval_cost/run.py`; each run appends "
                "a dated section. Raw timings: `timings.jsonl`; every process's output: `logs/`.\n\n"
            )
        with open(results, "a") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
