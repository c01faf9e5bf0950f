"""Several seeds in one process (`canter train ENV --seeds ...`) against one seed and against separate processes.

Run with canter's interpreter from the repository root, on an otherwise idle machine:

    .venv/bin/python benchmarks/multiseed/run.py [--env Hopper-v5] [--preset fast] [--set KEY=VALUE ...]
                                                 [--total-steps 200000] [--seeds 0,1,2,3,4]
                                                 [--only one,group,sequential,concurrent] [--no-write]

Rows, all with the same config (`--preset`, default `fast`, and `--set`) and the same step budget per seed, each a whole
`canter train` process timed from outside:
  one         canter train ENV --seed S0                    (the first seed alone)
  group       canter train ENV --seeds S0,S1,...            (every seed in one vmapped program)
  sequential  canter train ENV --seed S, one process after another
  concurrent  canter train ENV --seed S, all processes started at once on the same cores
It prints a markdown table and appends it, as a dated section with the machine, to results.md, and keeps the runs'
logs, run files and rows.json beside it in logs/<stamp>/ (benchmarks/speed_archive.py).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/, for speed_archive
import speed_archive

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
ROWS = ("one", "group", "sequential", "concurrent")
TARGET = 3.0  # issue 5: five seeds together within 3x the wall time of one


@dataclass
class Row:
    name: str
    seeds: list[int]
    process_wall: float  # whole processes, from the first start to the last exit
    cpu: float  # user + system seconds of those processes
    steps: int  # env steps over all seeds
    sps: list[float]  # per seed, summary.json sps (compile excluded)
    compile: list[float]  # per process, summary.json compile_seconds
    returns: list[float | None]
    load: float  # 1-minute load average before the row


def _steps(text: str) -> int:
    value = float(text)
    if not value.is_integer() or value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole step count such as 2e5, got {text!r}")
    return int(value)


def _seeds(text: str) -> list[int]:
    try:
        seeds = [int(s) for s in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seeds such as 0,1,2,3,4, got {text!r}") from None
    if len(set(seeds)) != len(seeds) or len(seeds) < 2:
        raise argparse.ArgumentTypeError(f"expected at least two distinct seeds, got {text!r}")
    return seeds


def _only(text: str) -> list[str]:
    chosen = [t.strip() for t in text.split(",") if t.strip()]
    if not chosen or any(t not in ROWS for t in chosen):
        raise argparse.ArgumentTypeError(f"--only takes a comma list of {', '.join(ROWS)}; got {text!r}")
    return chosen


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description="canter: several seeds in one process vs one seed vs separate processes")
    p.add_argument("--env", default="Hopper-v5")
    p.add_argument("--preset", default="fast", help="canter preset for every row (default fast)")
    p.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="passed to every canter train command; repeatable",
    )
    p.add_argument("--total-steps", type=_steps, default=200_000, help="env steps per seed (default 2e5)")
    p.add_argument("--seeds", type=_seeds, default=[0, 1, 2, 3, 4])
    p.add_argument("--only", type=_only, default=list(ROWS))
    p.add_argument("--out-dir", type=Path, default=None, help="run folders and logs (default benchmarks/runs/...)")
    p.add_argument("--results", type=Path, default=HERE / "results.md")
    p.add_argument("--no-write", action="store_true", help="print the section only")
    return p.parse_args(argv)


def _canter() -> list[str]:
    return [sys.executable, "-m", "canter.cli.main"]


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _run_processes(commands: list[list[str]], logs: list[Path], concurrent: bool) -> tuple[float, float]:
    """Wall and CPU seconds of the commands, run one after another or all at once; fails loudly."""
    cpu0, start = _children_cpu(), time.perf_counter()
    batches = [commands] if concurrent else [[c] for c in commands]
    log_iter = iter(logs)
    for batch in batches:
        procs = []
        for command in batch:
            log = next(log_iter)
            with open(log, "w") as out:  # the child keeps its own copy of the descriptor
                print(f"$ {' '.join(command)}", file=out, flush=True)
                procs.append((subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT, cwd=ROOT), log))
        for proc, log in procs:
            if proc.wait() != 0:
                raise SystemExit(f"{' '.join(proc.args)} failed; see {log}")
    return time.perf_counter() - start, _children_cpu() - cpu0


def _summaries(folder: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted(folder.glob("*/summary.json"))]


def run_row(name: str, args: argparse.Namespace, out: Path) -> Row:
    seeds = [args.seeds[0]] if name == "one" else list(args.seeds)
    folder = out / name
    folder.mkdir(parents=True, exist_ok=True)
    base = _canter() + [
        "train",
        args.env,
        "--preset",
        args.preset,
        "--total-steps",
        str(args.total_steps),
        "--quiet",
        "--out-dir",
        str(folder),
    ]
    for item in args.sets:
        base += ["--set", item]
    if name == "group":
        commands = [base + ["--seeds", ",".join(map(str, seeds))]]
    else:
        commands = [base + ["--seed", str(s)] for s in seeds]
    logs = [folder / f"train_{i}.log" for i in range(len(commands))]
    load = os.getloadavg()[0]
    wall, cpu = _run_processes(commands, logs, concurrent=(name == "concurrent"))
    summaries = _summaries(folder)
    if len(summaries) != len(seeds):
        raise SystemExit(f"{name}: expected {len(seeds)} run folders in {folder}, found {len(summaries)}")
    compile_seconds = sorted({s["compile_seconds"] for s in summaries})
    return Row(
        name,
        seeds,
        wall,
        cpu,
        sum(s["global_step"] for s in summaries),
        [s["sps"] for s in summaries],
        compile_seconds,
        [s["recent_return"] for s in summaries],
        load,
    )


def tables(content: dict) -> str:
    """The section's table and the ratios below it, from its rows.json record alone."""
    rows = [Row(**row) for row in content["rows"]]
    lines = [
        "| row | seeds | processes | process wall (s) | train SPS per seed (compile excluded) | CPU (s) "
        "| steps, all seeds | steps/s of wall, all seeds | compile per process (s) | wall / one seed |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    one = next((r for r in rows if r.name == "one"), None)
    for r in rows:
        processes = 1 if r.name == "group" else len(r.seeds)
        ratio = f"{r.process_wall / one.process_wall:.2f}×" if one else "—"
        sps = ", ".join(f"{s:,.0f}" for s in r.sps)
        compile_text = (
            ", ".join(f"{c:.1f}" for c in r.compile)
            if len(r.compile) <= 2
            else f"{min(r.compile):.1f}–{max(r.compile):.1f}"
        )
        lines.append(
            f"| {r.name} | {len(r.seeds)} | {processes} | {r.process_wall:.1f} | {sps} | {r.cpu:.1f} | {r.steps:,} | "
            f"{r.steps / r.process_wall:,.0f} | {compile_text} | {ratio} |"
        )
    lines.append("")
    by = {r.name: r for r in rows}
    n = len(content["settings"]["seeds"])
    if one and "group" in by:
        verdict = "meets" if by["group"].process_wall <= TARGET * one.process_wall else "misses"
        lines.append(
            f"- {n} seeds in one process took {by['group'].process_wall / one.process_wall:.2f}× the wall time of "
            f"one seed (target ≤ {TARGET:.0f}×: {verdict} it) and {by['group'].cpu / one.cpu:.2f}× its CPU time."
        )
    for name in ("sequential", "concurrent"):
        if "group" in by and name in by:
            how = "one after another" if name == "sequential" else "at once"
            lines.append(
                f"- against {n} separate processes run {how}: the group took "
                f"{by['group'].process_wall / by[name].process_wall:.2f}× their wall time and "
                f"{by['group'].cpu / by[name].cpu:.2f}× their CPU time."
            )
    return "\n".join(lines)


HEAD = "# Several seeds in one process\n\nWritten by `benchmarks/multiseed/run.py`; each run appends a dated section.\n"


def section(content: dict, m: dict, logs: str) -> str:
    settings, v = content["settings"], content["settings"]["versions"]
    started = datetime.fromisoformat(content["started"]).astimezone(UTC)
    config = f"preset {settings['preset']}" + "".join(f", --set {item}" for item in settings["sets"])
    lines = [
        f"## {started:%Y-%m-%d %H:%M} UTC — {settings['env']}, {config}, {settings['total_steps']:,} steps per seed, "
        f"seeds {','.join(map(str, settings['seeds']))}",
        "",
        f"- machine: {m['cpu']}, {m['cores']} cores, {m['memory']}, {m['os']}, Python {m['python']}; "
        f"canter {v['canter']}, jax {v['jax']}, envpool {v['envpool']}, mujoco {v['mujoco']}",
        f"- canter commit: {content['commit']}",
        "- 1-minute load average before each row: "
        + ", ".join(f"{r['name']} {r['load']:.2f}" for r in content["rows"])
        + " (well above 0 means something else was using the cores and the numbers are not clean)",
        f"- logs and rows.json: {logs}",
        "",
        tables(content),
        "",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from canter.training.run_folder import versions

    args = parse_args(argv)
    started = datetime.now().astimezone()
    out = (args.out_dir or ROOT / "benchmarks" / "runs" / f"multiseed-{started:%Y%m%d-%H%M%S}").resolve()
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in (r for r in ROWS if r in args.only):
        print(f"running {name} ...", flush=True)
        rows.append(run_row(name, args, out))
        print(f"  wall {rows[-1].process_wall:.1f} s, CPU {rows[-1].cpu:.1f} s", flush=True)
    settings = {k: getattr(args, k) for k in ("env", "preset", "sets", "total_steps", "seeds", "only")}
    content = speed_archive.record("multiseed", started, settings | {"versions": versions()}, [asdict(r) for r in rows])
    speed_archive.publish(content, out, None if args.no_write else args.results, HEAD, section)
    return 0


if __name__ == "__main__":
    sys.exit(main())
