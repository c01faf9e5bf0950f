"""TD3 speed benchmark: canter td3 against Stable-Baselines3 TD3 on HalfCheetah-v4, same hyperparameters
(256-256 relu, batch 256, one gradient step per env step, policy delay 2; canter's td3 defaults).

Run with canter's interpreter (the SB3 venv is the one benchmarks/ppo_speed/run.sh makes):

    .venv/bin/python benchmarks/td3_speed/run.py --total-steps 1e6                        # the full benchmark
    .venv/bin/python benchmarks/td3_speed/run.py --total-steps 30000 --learning-starts 5000  # a short probe

The tools run one after another, each as a whole process. Besides the overall SPS, each row gives the steady SPS
over the steps after learning_starts (canter: from metrics.csv; SB3: from a callback), and the 1M-step time that
rate implies: 25k warm-up steps at the measured warm-up rate plus 975k steps at the steady rate (SB3's warm-up
rate is not measured, so its projection is the 975k steps alone). The markdown table is printed and appended, as a
dated section with the machine and versions, to results.md, and the runs' raw files and rows.json are kept beside
it in logs/<stamp>/ (benchmarks/speed_archive.py).
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import os
import resource
import sys
import textwrap
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/, for speed_archive
import speed_archive

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
ENV_ID = "HalfCheetah-v4"
FULL_STEPS, FULL_LEARNING_STARTS = 1_000_000, 25_000


def _ppo_bench():
    """benchmarks/ppo_speed/run.py, for its process runner and argument parsers."""
    spec = importlib.util.spec_from_file_location("ppo_speed_run", HERE.parent / "ppo_speed" / "run.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up here
    spec.loader.exec_module(module)
    return module


ppo = _ppo_bench()


@dataclass
class Row:
    tool: str
    ok: bool = False
    error: str = ""
    steps: int | None = None
    process_wall: float | None = None
    sps: float | None = None
    steady_sps: float | None = None
    warmup_sps: float | None = None
    compile: float | None = None
    train_return: float | None = None
    load_before: float = 0.0
    cpu_seconds: float | None = None  # user + sys of the whole training process
    extra: dict = field(default_factory=dict)

    def projected_minutes(self) -> float | None:
        if not self.steady_sps:
            return None
        warm = FULL_LEARNING_STARTS / self.warmup_sps if self.warmup_sps else 0.0
        return (warm + (FULL_STEPS - FULL_LEARNING_STARTS) / self.steady_sps) / 60


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description="canter td3 vs Stable-Baselines3 TD3 speed on HalfCheetah-v4")
    p.add_argument("--total-steps", type=ppo._steps, default=FULL_STEPS)
    p.add_argument("--learning-starts", type=int, default=FULL_LEARNING_STARTS)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--only", choices=("canter", "sb3"), default=None)
    p.add_argument("--sb3-python", default=str(ROOT / "benchmarks" / ".sb3-venv" / "bin" / "python"))
    p.add_argument("--sb3-threads", type=int, default=2)
    p.add_argument("--canter", default=None, help="canter command (default: the one beside this interpreter)")
    p.add_argument("--out-dir", default=None)
    p.add_argument("--results", default=str(HERE / "results.md"))
    p.add_argument("--no-write", action="store_true")
    args = speed_archive.parse_with_readme_options(p, argv, "--readme", "TD3 paragraph")
    if not 0 <= args.learning_starts < args.total_steps:
        p.error("--learning-starts must be in [0, --total-steps)")
    return args


def _rates_from_metrics(path: Path, learning_starts: int) -> tuple[float | None, float | None]:
    """(warm-up SPS, steady SPS) from metrics.csv: per-call steps over per-call time, split at learning_starts."""
    with open(path) as f:
        rows = list(csv.DictReader(f))
    warm_steps = warm_time = steady_steps = steady_time = 0.0
    previous = 0
    for r in rows:
        step, sps = int(r["global_step"]), float(r["sps"])
        steps = step - previous
        if previous >= learning_starts:
            steady_steps, steady_time = steady_steps + steps, steady_time + steps / sps
        elif step <= learning_starts:
            warm_steps, warm_time = warm_steps + steps, warm_time + steps / sps
        previous = step
    return (warm_steps / warm_time if warm_time else None, steady_steps / steady_time if steady_time else None)


def run_canter(args: argparse.Namespace, out: Path) -> Row:
    row = Row("canter td3")
    folder = out / "canter"
    folder.mkdir(parents=True, exist_ok=True)
    cmd = ppo.canter_cmd(args) + [
        "train",
        ENV_ID,
        "--algo",
        "td3",
        "--seed",
        str(args.seed),
        "--total-steps",
        str(args.total_steps),
        "--set",
        f"td3.learning_starts={args.learning_starts}",
        "--set",
        "run.checkpoint_every=0",
        "--quiet",
        "--out-dir",
        str(folder),
    ]
    code, wall, _ = ppo._run(cmd, folder / "train.log")
    row.process_wall = wall
    if code != 0:
        row.error = f"canter exited {code} (log: {folder / 'train.log'})"
        return row
    run = next(p for p in folder.iterdir() if p.is_dir() and (p / "summary.json").exists())
    summary = json.loads((run / "summary.json").read_text())
    row.steps, row.sps = int(summary["global_step"]), float(summary["sps"])
    row.compile, row.train_return = float(summary["compile_seconds"]), summary.get("recent_return")
    row.warmup_sps, row.steady_sps = _rates_from_metrics(run / "metrics.csv", args.learning_starts)
    row.ok = True
    return row


def run_sb3(args: argparse.Namespace, out: Path) -> Row:
    row = Row("SB3 TD3")
    folder = out / "sb3"
    folder.mkdir(parents=True, exist_ok=True)
    if not Path(args.sb3_python).exists():
        row.error = f"no SB3 venv at {args.sb3_python}; make it with benchmarks/ppo_speed/run.sh"
        return row
    cmd = [
        args.sb3_python,
        str(HERE / "sb3_td3.py"),
        "--total-steps",
        str(args.total_steps),
        "--learning-starts",
        str(args.learning_starts),
        "--seed",
        str(args.seed),
        "--threads",
        str(args.sb3_threads),
    ]
    code, wall, stdout = ppo._run(cmd, folder / "train.log")
    row.process_wall = wall
    result = ppo._json_line(stdout) if code == 0 else None
    if result is None:
        row.error = f"sb3_td3.py failed (log: {folder / 'train.log'})"
        return row
    row.steps, row.sps, row.steady_sps = result["steps"], result["sps"], result["steady_sps"]
    row.train_return = result["final_train_return"]
    row.extra["versions"] = result["versions"]
    row.ok = True
    return row


def _f(value, fmt=".1f"):
    return "—" if value is None else format(value, fmt)


def tables(content: dict) -> str:
    """The section's table, from its rows.json record alone."""
    rows = [Row(**row) for row in content["rows"]]
    sb3 = next((r for r in rows if r.tool.startswith("SB3") and r.ok), None)
    lines = [
        "| tool | steps | process wall (s) | SPS (all) | warm-up SPS | steady SPS (after learning_starts) | "
        "projected 1M time (min) | compile (s) | process CPU time (s) | train return (last 20 eps) | "
        "steady SPS vs SB3 |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        if not r.ok:
            lines.append(f"| {r.tool} | failed: {r.error} | | | | | | | | | |")
            continue
        ratio = f"{r.steady_sps / sb3.steady_sps:.2f}×" if sb3 and sb3.steady_sps and r.steady_sps else "—"
        lines.append(
            f"| {r.tool} | {_f(r.steps, ',')} | {_f(r.process_wall)} | {_f(r.sps, ',.0f')} | "
            f"{_f(r.warmup_sps, ',.0f')} | {_f(r.steady_sps, ',.0f')} | {_f(r.projected_minutes())} | "
            f"{_f(r.compile)} | {_f(r.cpu_seconds)} | {_f(r.train_return)} | {ratio} |"
        )
    return "\n".join(lines)


def section(content: dict, m: dict, logs: str) -> str:
    settings, started = content["settings"], datetime.fromisoformat(content["started"])
    lines = [
        f"## {started.strftime('%Y-%m-%d %H:%M %Z').strip()}: {ENV_ID}, {settings['total_steps']:,} steps, "
        f"learning_starts {settings['learning_starts']:,}, seed {settings['seed']}"
        + (" (short probe)" if settings["total_steps"] < FULL_STEPS else ""),
        "",
        f"- machine: {m['cpu']}, {m['cores']} cores, {m['memory']}, {m['os']}, Python {m['python']}",
        f"- date: {content['started']}; canter commit {content['commit']}",
        "- 1-minute load average before each run: "
        + ", ".join(f"{r['tool']} {r['load_before']:.2f}" for r in content["rows"])
        + " (above ~0.5 means other processes shared the 2 cores, and absolute numbers are pessimistic)",
        f"- logs and rows.json: {logs}",
        "",
        tables(content),
    ]
    return "\n".join(lines) + "\n"


README_MARKERS = ("<!-- td3-speed -->\n", "<!-- /td3-speed -->")


def readme_text(content: dict, m: dict, logs: str) -> str:
    """README.md's td3-speed paragraph: steady SPS of canter and SB3, their ratio, whole-process walls and the 1M-step
    times those rates imply, with the run, machine and archive `logs` they come from."""
    settings = content["settings"]
    rows = [Row(**row) for row in content["rows"] if row["ok"]]
    mine = next(r for r in rows if r.tool.startswith("canter"))
    sb3 = next(r for r in rows if r.tool.startswith("SB3"))
    args = ppo.settings_args(content["command"][1:])
    probe = settings["total_steps"] < FULL_STEPS
    mine_minutes, sb3_minutes = mine.projected_minutes(), sb3.projected_minutes()
    assert mine.steady_sps and sb3.steady_sps and mine_minutes and sb3_minutes, "both rows have steady rates"
    command = " ".join(["benchmarks/td3_speed/run.py", *args])
    text = (
        f"TD3 on {ENV_ID} (256-256, batch 256, one gradient step per env step), side by side with SB3's TD3, each a "
        f"whole process run one after another by `{command}` ({settings['total_steps']:,} steps, learning_starts "
        f"{settings['learning_starts']:,}{', a short probe' if probe else ''}; {m['usable_cores']}-core {m['cpu']} "
        f"with {m['gpu'] or 'no GPU'}, {content['started'][:10]}, 1-minute load average before the runs "
        f"{' and '.join(f'{r.load_before:.2f}' for r in rows)}; raw logs: [{logs}]({logs})): "
        f"canter's steady SPS after learning_starts is **{mine.steady_sps:,.0f}** against SB3's "
        f"**{sb3.steady_sps:,.0f}**, **{mine.steady_sps / sb3.steady_sps:.1f}x**, and the whole processes took "
        f"{mine.process_wall:.0f} s and {sb3.process_wall:.0f} s. At those rates 1M steps take about "
        f"{mine_minutes:.0f} minutes against SB3's {sb3_minutes / 60:.1f} hours. SB3's figure is its 975k steps after "
        f"learning_starts alone (its warm-up rate is not measured); canter's adds its 25k warm-up steps."
    )
    return textwrap.fill(text, width=116, break_long_words=False, break_on_hyphens=False)


HEAD = """# TD3 speed: canter vs Stable-Baselines3 on HalfCheetah-v4

Written by `benchmarks/td3_speed/run.py`; each run appends a dated section. Both tools use 1 env, 256-256 relu
actor and critics, batch 256, one gradient step per env step, policy delay 2, Gaussian exploration noise 0.1,
target noise 0.2 clipped at 0.5, buffer 1e6. The projected 1M-step time is 25k warm-up steps at the warm-up rate
plus 975k steps at the steady rate. SB3's warm-up is not timed separately, so its projection is the 975k steps at
the steady rate alone and leaves out its 25k warm-up steps (random actions without gradient steps, faster than the
steady rate). Full benchmark: `.venv/bin/python benchmarks/td3_speed/run.py --total-steps 1e6`.
"""


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.readme:
        return speed_archive.write_block(
            args.readme, README_MARKERS, readme_text, args.check, ROOT / "README.md", "--readme"
        )
    started = datetime.now().astimezone()
    out = Path(args.out_dir or ROOT / "benchmarks" / "runs" / f"td3-{started.strftime('%Y%m%d-%H%M%S')}").resolve()
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for tool, runner in (("canter", run_canter), ("sb3", run_sb3)):
        if args.only and args.only != tool:
            continue
        print(f"[{tool}]", flush=True)
        load = os.getloadavg()[0]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        row = runner(args, out)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        row.load_before = load
        row.cpu_seconds = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
        rows.append(row)
    settings = {
        "total_steps": args.total_steps,
        "learning_starts": args.learning_starts,
        "seed": args.seed,
        "only": args.only,
        "sb3_threads": args.sb3_threads,
    }
    content = speed_archive.record("td3_speed", started, settings, [asdict(r) for r in rows])
    speed_archive.publish(content, out, None if args.no_write else Path(args.results), HEAD, section)
    return 0 if all(r.ok for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
