"""Time to score with canter's default preset: train each env for a fixed step budget that fits in 3 minutes,
with --max-minutes 3 as a guard, then evaluate 10 deterministic episodes. Median over seeds.

    .venv/bin/python benchmarks/time_to_score/run.py [--seeds 0,1,2] [--envs Hopper-v5:2.5e6,HalfCheetah-v5:3.5e6]
    .venv/bin/python benchmarks/time_to_score/run.py --readme benchmarks/time_to_score/logs/<stamp> [--check]

Appends a dated markdown section to benchmarks/time_to_score/results.md, and keeps the runs' logs, run files and
rows.json beside it in logs/<stamp>/ (benchmarks/speed_archive.py).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import textwrap
import time
from datetime import datetime
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/, for speed_archive
import speed_archive

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
CANTER = str(Path(sys.executable).with_name("canter"))
TARGETS = {"Hopper-v5": 2500.0, "HalfCheetah-v5": 5000.0}
HEAD = "# Time to score, canter default preset\n"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description="canter's default preset against the clock")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--envs", default="Hopper-v5:2.5e6,HalfCheetah-v5:3.5e6", help="comma list of ENV:STEPS")
    parser.add_argument("--minutes", type=float, default=3.0, help="--max-minutes guard of each training run")
    parser.add_argument("--out-dir", default=None, help="run folders and logs (default benchmarks/runs/tts-<stamp>)")
    parser.add_argument("--results", default=str(HERE / "results.md"))
    parser.add_argument("--no-write", action="store_true", help="print the section only; leave results.md alone")
    return speed_archive.parse_with_readme_options(parser, argv, "--readme", "time-to-score sentence")


def _timed(cmd: list[str], log: Path) -> float:
    """Run one whole process with its output in `log`; its wall seconds. Fails loudly."""
    start = time.perf_counter()
    with open(log, "w") as out:
        print(f"$ {' '.join(cmd)}", file=out, flush=True)
        done = subprocess.run(cmd, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} exited {done.returncode}; see {log}")
    return wall


def run_one(env: str, steps: str, seed: int, args: argparse.Namespace, out: Path) -> dict:
    folder = out / f"{env}__s{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    load = os.getloadavg()[0]
    train = [CANTER, "train", env, "--seed", str(seed), "--total-steps", steps, "--max-minutes", str(args.minutes)]
    train += ["--quiet", "--out-dir", str(folder), "--set", "run.tensorboard=false"]
    wall = _timed(train, folder / "train.log")
    run = next(p for p in folder.iterdir() if p.is_dir())
    summary = json.loads((run / "summary.json").read_text())
    eval_json = folder / "eval.json"
    _timed([CANTER, "eval", str(run), "--episodes", "10", "--json", str(eval_json)], folder / "eval.log")
    score = json.loads(eval_json.read_text())["runs"][0]
    return {
        "env": env,
        "seed": seed,
        "steps": summary["global_step"],
        "process_wall": wall,
        "sps": summary["sps"],
        "compile": summary["compile_seconds"],
        "eval_mean": score["return_mean"],
        "eval_std": score["return_std"],
        "load_before": load,
        "run_dir": str(run.relative_to(out)),
    }


def tables(content: dict) -> str:
    """The section's per-seed and per-env tables, from its rows.json record alone."""
    rows = content["rows"]
    lines = [
        "| env | seed | steps | process wall (s) | SPS (compile excluded) | compile (s) "
        "| eval return (10 eps, deterministic) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['env']} | {r['seed']} | {r['steps']:,} | {r['process_wall']:.0f} | {r['sps']:,.0f} | "
            f"{r['compile']:.1f} | {r['eval_mean']:.0f} ± {r['eval_std']:.0f} |"
        )
    lines += [
        "",
        "| env | median eval return over seeds | target | median process wall (s) | median SPS (compile excluded) |",
        "|---|---|---|---|---|",
    ]
    for env in dict.fromkeys(r["env"] for r in rows):
        mine = [r for r in rows if r["env"] == env]
        med = statistics.median(r["eval_mean"] for r in mine)
        target = TARGETS.get(env)
        verdict = "" if target is None else (f"{target:.0f} ({'met' if med >= target else 'not met'})")
        lines.append(
            f"| {env} | {med:.0f} | {verdict} | {statistics.median(r['process_wall'] for r in mine):.0f} | "
            f"{statistics.median(r['sps'] for r in mine):,.0f} |"
        )
    return "\n".join(lines)


def section(content: dict, m: dict, logs: str) -> str:
    versions = content["settings"]["versions"]
    command = " ".join([".venv/bin/python", "benchmarks/time_to_score/run.py", *content["command"][1:]])
    lines = [
        f"## {datetime.fromisoformat(content['started']):%Y-%m-%d %H:%M} — {m['cpu']}, {m['cores']} cores, "
        f"{m['gpu'] or 'no GPU'}",
        ", ".join(f"{name} {versions[name]}" for name in ("canter", "jax", "envpool", "mujoco"))
        + f". Command: `{command}`",
        "",
        f"- canter commit: {content['commit']}; 1-minute load average before each run: "
        + ", ".join(f"{r['env']} s{r['seed']} {r['load_before']:.2f}" for r in content["rows"]),
        f"- logs and rows.json: {logs}",
        "",
        tables(content),
    ]
    return "\n".join(lines) + "\n"


README_MARKERS = ("<!-- time-to-score -->\n", "<!-- /time-to-score -->")


def readme_text(content: dict, m: dict, logs: str) -> str:
    """README.md's time-to-score sentence: per env, the median eval return over seeds and the median process wall,
    against its target, with the run, machine and archive `logs` they come from. The two medians are taken apart, so
    they can come from different seeds; the sentence says so and gives each seed's pair after them."""
    rows, settings = content["rows"], content["settings"]
    scores, pairs = [], []
    for env in dict.fromkeys(r["env"] for r in rows):
        mine = [r for r in rows if r["env"] == env]
        median, wall = (
            statistics.median(r["eval_mean"] for r in mine),
            statistics.median(r["process_wall"] for r in mine),
        )
        target = TARGETS.get(env)
        verdict = "" if target is None else f" (target {target:.0f}: {'met' if median >= target else 'not met'})"
        scores.append(f"{env} scored **{median:.0f}** in {wall:.0f} s{verdict}")
        pairs.append(
            f"{env} " + ", ".join(f"{r['eval_mean']:.0f} in {r['process_wall']:.0f} s (seed {r['seed']})" for r in mine)
        )
    text = (
        f"Time to score with the default preset, by `benchmarks/time_to_score/run.py` ({m['usable_cores']}-core "
        f"{m['cpu']} with {m['gpu'] or 'no GPU'}, {content['started'][:10]}; each training run a whole process with "
        f"a {settings['minutes']:g}-minute guard, then a 10-episode deterministic eval; the return and the wall time "
        f"are separate medians over seeds {','.join(map(str, settings['seeds']))}; raw logs: [{logs}]({logs})): "
        + " and ".join(scores)
        + ". The two medians can come from different seeds; each seed's return and process wall: "
        + "; ".join(pairs)
        + "."
    )
    return textwrap.fill(text, width=116, break_long_words=False, break_on_hyphens=False)


def main(argv: list[str] | None = None) -> int:
    from canter.training.run_folder import versions

    args = parse_args(argv)
    if args.readme:
        return speed_archive.write_block(
            args.readme, README_MARKERS, readme_text, args.check, ROOT / "README.md", "--readme"
        )
    started = datetime.now().astimezone()
    out = Path(args.out_dir or ROOT / "benchmarks" / "runs" / f"tts-{started:%Y%m%d-%H%M%S}").resolve()
    seeds = [int(s) for s in args.seeds.split(",")]
    rows = []
    for item in args.envs.split(","):
        env, _, steps = item.partition(":")
        for seed in seeds:
            rows.append(run_one(env, steps, seed, args, out))
            print(json.dumps(rows[-1]), flush=True)
    settings = {"seeds": seeds, "envs": args.envs, "minutes": args.minutes, "versions": versions()}
    content = speed_archive.record("time_to_score", started, settings, rows)
    speed_archive.publish(content, out, None if args.no_write else Path(args.results), HEAD, section)
    return 0


if __name__ == "__main__":
    sys.exit(main())
