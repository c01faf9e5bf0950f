"""PPO speed benchmark: canter (`cleanrl` and `fast` presets) against Stable-Baselines3 PPO on HalfCheetah-v4.

Run with canter's interpreter (usually through run.sh, which also makes the SB3 venv):

    .venv/bin/python benchmarks/ppo_speed/run.py [--total-steps 1e6] [--seeds 0] [--skip-sb3]
                                                  [--only canter-cleanrl,canter-fast,sb3]

Each tool runs as its own whole process, one after another (never side by side: they would share the cores):
  canter-cleanrl  canter train HalfCheetah-v4 --preset cleanrl ...   then  canter eval RUN --episodes 10
  canter-fast     canter train HalfCheetah-v4 --preset fast ...      then  canter eval RUN --episodes 10
  sb3             benchmarks/.sb3-venv/bin/python sb3_ppo.py ...     (trains, then evaluates itself)
It prints a markdown table and appends it, as a dated section with the machine and versions, to results.md, and
keeps the runs' raw files and rows.json beside it in logs/<stamp>/ (benchmarks/speed_archive.py).

The README's headline table (between its `<!-- bench-headline -->` markers) is rendered from such an archive:

    .venv/bin/python benchmarks/ppo_speed/run.py --headline benchmarks/ppo_speed/logs/<stamp> [--check]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import textwrap
import time
from dataclasses import dataclass, field
from datetime import datetime
from importlib import metadata
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/, for speed_archive
import speed_archive

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
ENV_ID = "HalfCheetah-v4"
TOOLS = ("canter-cleanrl", "canter-fast", "sb3")
EVAL_EPISODES = 10


@dataclass
class Row:
    tool: str
    seed: int
    ok: bool = False
    error: str = ""
    steps: int | None = None
    process_wall: float | None = None  # whole training process, measured from outside
    wall: float | None = None  # the tool's own wall time (after imports)
    sps: float | None = None  # compile excluded
    compile: float | None = None
    train_return: float | None = None  # mean raw return of the last 20 training episodes
    eval_mean: float | None = None
    eval_std: float | None = None
    eval_process_wall: float | None = None
    run_dir: str = ""
    extra: dict = field(default_factory=dict)


def _steps(text: str) -> int:
    value = float(text)
    if not value.is_integer() or value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole step count such as 1e6, got {text!r}")
    return int(value)


def _seeds(text: str) -> list[int]:
    try:
        return [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seeds such as 0 or 0,1,2, got {text!r}") from None


def _only(text: str) -> list[str]:
    chosen = [t.strip() for t in text.split(",") if t.strip()]
    unknown = [t for t in chosen if t not in TOOLS]
    if unknown or not chosen:
        raise argparse.ArgumentTypeError(f"--only takes a comma list of {', '.join(TOOLS)}; got {text!r}")
    return chosen


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description="canter vs Stable-Baselines3 PPO speed benchmark on HalfCheetah-v4")
    p.add_argument("--total-steps", type=_steps, default=1_000_000, help="env steps per run (default 1e6)")
    p.add_argument("--seeds", type=_seeds, default=[0], help="comma list of seeds (default 0)")
    p.add_argument("--skip-sb3", action="store_true", help="run only canter")
    p.add_argument("--only", type=_only, default=None, help=f"comma list of {','.join(TOOLS)}")
    p.add_argument(
        "--sb3-python",
        default=str(ROOT / "benchmarks" / ".sb3-venv" / "bin" / "python"),
        help="interpreter of the SB3 venv (run.sh makes it)",
    )
    p.add_argument(
        "--sb3-threads",
        type=int,
        default=2,
        help="torch threads for SB3 (default 2, the core count "
        "here); torch with 2 threads slows down badly when anything else holds a core",
    )
    p.add_argument("--canter", default=None, help="canter command (default: the one beside this interpreter)")
    p.add_argument("--out-dir", default=None, help="where run folders and logs go (default benchmarks/runs/<stamp>)")
    p.add_argument("--results", default=str(HERE / "results.md"), help="markdown file to append the section to")
    p.add_argument("--no-write", action="store_true", help="print the table only; leave results.md alone")
    args = speed_archive.parse_with_readme_options(p, argv, "--headline", "headline table")
    tools = args.only or list(TOOLS)
    if args.skip_sb3:
        tools = [t for t in tools if t != "sb3"]
    if not tools:
        p.error("nothing to run: --skip-sb3 with --only sb3")
    args.tools = tools
    return args


# ---------------------------------------------------------------------------------------------- running tools


def _run(cmd: list[str], log: Path, cwd: Path = ROOT) -> tuple[int, float, str]:
    """Run one whole process; its stdout and stderr go to `log`. Returns (exit code, wall seconds, stdout)."""
    print(f"  $ {' '.join(cmd)}", flush=True)
    start = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, stdin=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    log.write_text(
        f"$ {' '.join(cmd)}\n# exit {proc.returncode}, {wall:.1f} s\n--- stdout\n{proc.stdout}--- stderr\n{proc.stderr}"
    )
    return proc.returncode, wall, proc.stdout


def _fail(row: Row, what: str, code: int, log: Path) -> Row:
    tail = log.read_text().strip().splitlines()[-1:] if log.exists() else []
    row.error = f"{what} exited {code}: {tail[0] if tail else ''} (log: {log})"
    print(f"  FAILED: {row.error}", flush=True)
    return row


def canter_cmd(args: argparse.Namespace) -> list[str]:
    if args.canter:
        return args.canter.split()
    beside = Path(sys.executable).parent / "canter"
    if beside.exists():
        return [str(beside)]
    found = shutil.which("canter")
    return [found] if found else [sys.executable, "-m", "canter.cli.main"]


def run_canter(preset: str, seed: int, args: argparse.Namespace, out: Path) -> Row:
    row = Row(tool=f"canter-{preset}", seed=seed)
    folder = out / f"{row.tool}__s{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    canter = canter_cmd(args)
    code, wall, _ = _run(
        canter
        + [
            "train",
            ENV_ID,
            "--preset",
            preset,
            "--seed",
            str(seed),
            "--total-steps",
            str(args.total_steps),
            "--quiet",
            "--out-dir",
            str(folder),
        ],
        folder / "train.log",
    )
    row.process_wall = wall
    if code != 0:
        return _fail(row, "canter train", code, folder / "train.log")
    runs = sorted(p for p in folder.iterdir() if p.is_dir() and (p / "summary.json").exists())
    if len(runs) != 1:
        row.error = f"expected one run folder with summary.json in {folder}, found {len(runs)}"
        return row
    run = runs[0]
    row.run_dir = str(run.relative_to(out))  # the same inside the archive
    summary = json.loads((run / "summary.json").read_text())
    row.steps = int(summary["global_step"])
    row.wall = float(summary["wall_seconds"])
    row.compile = float(summary["compile_seconds"])
    row.sps = float(summary["sps"])
    row.train_return = summary.get("recent_return")
    row.extra["stop_reason"] = summary.get("stop_reason")
    if (run / "versions.json").exists():
        row.extra["versions"] = json.loads((run / "versions.json").read_text())

    eval_json = folder / "eval.json"
    code, wall, _ = _run(
        canter + ["eval", str(run), "--episodes", str(EVAL_EPISODES), "--json", str(eval_json)], folder / "eval.log"
    )
    row.eval_process_wall = wall
    if code != 0:
        return _fail(row, "canter eval", code, folder / "eval.log")
    evaluated = json.loads(eval_json.read_text())["runs"][0]
    row.eval_mean, row.eval_std = float(evaluated["return_mean"]), float(evaluated["return_std"])
    row.ok = True
    return row


def run_sb3(seed: int, args: argparse.Namespace, out: Path) -> Row:
    row = Row(tool="sb3", seed=seed)
    folder = out / f"sb3__s{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    if not Path(args.sb3_python).exists():
        row.error = f"no SB3 venv at {args.sb3_python}; make it with benchmarks/ppo_speed/run.sh (or pass --skip-sb3)"
        print(f"  FAILED: {row.error}", flush=True)
        return row
    script = [args.sb3_python, str(HERE / "sb3_ppo.py"), "--seed", str(seed), "--threads", str(args.sb3_threads)]
    model_dir = folder / "model"
    # Train in one process and evaluate in another, as for canter, so the process wall time is training only.
    code, wall, stdout = _run(
        script + ["--total-steps", str(args.total_steps), "--save", str(model_dir), "--eval-episodes", "0"],
        folder / "train.log",
    )
    row.process_wall = wall
    row.run_dir = str(folder.relative_to(out))
    if code != 0:
        return _fail(row, "sb3_ppo.py", code, folder / "train.log")
    result = _json_line(stdout)
    if result is None:
        row.error = f"sb3_ppo.py printed no JSON line (log: {folder / 'train.log'})"
        return row
    (folder / "train.json").write_text(json.dumps(result, indent=2))
    row.steps = int(result["steps"])
    row.wall = float(result["wall_seconds"])
    row.sps = float(result["sps"])
    row.train_return = result.get("final_train_return")
    row.extra["versions"] = result.get("versions", {})
    row.extra["hyperparameters"] = result.get("hyperparameters", {})

    code, wall, stdout = _run(
        script + ["--eval-from", str(model_dir), "--eval-episodes", str(EVAL_EPISODES)], folder / "eval.log"
    )
    row.eval_process_wall = wall
    evaluated = _json_line(stdout) if code == 0 else None
    if evaluated is None:
        return _fail(row, "sb3_ppo.py --eval-from", code, folder / "eval.log")
    (folder / "eval.json").write_text(json.dumps(evaluated, indent=2))
    row.eval_mean, row.eval_std = float(evaluated["eval_mean"]), float(evaluated["eval_std"])
    row.ok = True
    return row


def _json_line(stdout: str) -> dict | None:
    lines = [line for line in stdout.splitlines() if line.startswith("{")]
    return json.loads(lines[-1]) if lines else None


# -------------------------------------------------------------------------------------------------- versions


def versions(rows: list[Row]) -> dict[str, str]:
    def local(name: str) -> str:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return "not installed"

    found = {
        "canter": local("canter"),
        "jax": local("jax"),
        "jaxlib": local("jaxlib"),
        "envpool": local("envpool"),
        "mujoco (canter)": local("mujoco"),
    }
    sb3 = next((r.extra["versions"] for r in rows if r.tool == "sb3" and r.extra.get("versions")), None)
    if sb3:
        found.update(
            {
                "stable-baselines3": sb3.get("stable_baselines3"),
                "torch": sb3.get("torch"),
                "gymnasium (sb3)": sb3.get("gymnasium"),
                "mujoco (sb3)": sb3.get("mujoco"),
            }
        )
    else:
        found.update({"stable-baselines3": "not run", "torch": "not run"})
    return {k: str(v) for k, v in found.items()}


# ----------------------------------------------------------------------------------------------------- table

HEADER = (
    "| tool/preset | seed | steps | process wall (s) | SPS (compile excluded) | compile (s) | "
    "final train return (last 20 eps) | eval return mean ± std (10 eps, deterministic) | SPS ratio vs SB3 |"
)
RULE = "|---|---:|---:|---:|---:|---:|---:|---:|---:|"


def _f(value: float | None, fmt: str = ".1f", none: str = "—") -> str:
    return none if value is None else format(value, fmt)


def _mean(values: list[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return sum(kept) / len(kept) if kept else None


def table(rows: list[Row]) -> str:
    sb3_sps = _mean([r.sps for r in rows if r.tool == "sb3" and r.ok])
    lines = [HEADER, RULE]

    def ratio(sps: float | None) -> str:
        return "—" if sps is None or not sb3_sps else f"{sps / sb3_sps:.2f}×"

    for r in rows:
        if not r.ok and r.sps is None:
            lines.append(f"| {r.tool} | {r.seed} | failed: {r.error} | | | | | | |")
            continue
        compile_ = _f(r.compile, ".1f", "— (none)") if r.tool == "sb3" else _f(r.compile)
        evaluation = "—" if r.eval_mean is None else f"{r.eval_mean:.1f} ± {r.eval_std:.1f}"
        lines.append(
            f"| {r.tool} | {r.seed} | {_f(r.steps, ',')} | {_f(r.process_wall)} | {_f(r.sps, ',.0f')} | "
            f"{compile_} | {_f(r.train_return)} | {evaluation} | {ratio(r.sps)} |"
        )
    seeds = sorted({r.seed for r in rows})
    if len(seeds) > 1:
        for tool in dict.fromkeys(r.tool for r in rows):
            group = [r for r in rows if r.tool == tool and r.ok]
            if not group:
                continue
            evals = [r.eval_mean for r in group if r.eval_mean is not None]
            spread = ""
            if evals:
                m = sum(evals) / len(evals)
                spread = f"{m:.1f} ± {(sum((e - m) ** 2 for e in evals) / len(evals)) ** 0.5:.1f} (over seeds)"
            sps = _mean([r.sps for r in group])
            lines.append(
                f"| **{tool}** | mean of {len(group)} | {_f(_mean([r.steps for r in group]), ',.0f')} | "
                f"{_f(_mean([r.process_wall for r in group]))} | {_f(sps, ',.0f')} | "
                f"{_f(_mean([r.compile for r in group]))} | "
                f"{_f(_mean([r.train_return for r in group]))} | {spread} | {ratio(sps)} |"
            )
    return "\n".join(lines)


def speedups(rows: list[Row]) -> list[str]:
    sb3 = [r for r in rows if r.tool == "sb3" and r.ok]
    if not sb3:
        return []
    sb3_wall, sb3_sps = _mean([r.process_wall for r in sb3]), _mean([r.sps for r in sb3])
    out = []
    for tool in dict.fromkeys(r.tool for r in rows if r.tool != "sb3"):
        group = [r for r in rows if r.tool == tool and r.ok]
        if group:
            wall, sps = _mean([r.process_wall for r in group]), _mean([r.sps for r in group])
            out.append(
                f"- {tool} vs SB3: {sps / sb3_sps:.2f}× the SPS (compile excluded), "
                f"{sb3_wall / wall:.2f}× faster in whole-process wall time "
                f"({wall:.1f} s vs {sb3_wall:.1f} s)."
            )
    return out


def rows_of(content: dict) -> list[Row]:
    return [Row(**row) for row in content["rows"]]


def tables(content: dict) -> str:
    """The section's table and speed-ups, from its rows.json record alone."""
    rows = rows_of(content)
    extra = speedups(rows)
    return table(rows) + ("\n\n" + "\n".join(extra) if extra else "")


def section(content: dict, m: dict, logs: str) -> str:
    settings, rows = content["settings"], rows_of(content)
    started, seeds = datetime.fromisoformat(content["started"]), settings["seeds"]
    lines = [
        f"## {started.strftime('%Y-%m-%d %H:%M %Z').strip()} — {ENV_ID}, {settings['total_steps']:,} steps, "
        f"seed{'s' if len(seeds) > 1 else ''} {','.join(map(str, seeds))}"
        + (" (smoke run, not a benchmark)" if settings["total_steps"] < 1_000_000 else ""),
        "",
        f"- machine: {m['cpu']}, {m['cores']} cores, {m['memory']}, {m['os']}, Python {m['python']}",
        f"- date: {content['started']}",
        "- 1-minute load average before each run: "
        + ", ".join(f"{r.tool} s{r.seed} {r.extra.get('load_before', 0):.2f}" for r in rows)
        + " (well above 0 means something else was using the cores and the numbers are not clean)",
        f"- canter commit: {content['commit']}; SB3 torch threads: {settings['sb3_threads']}",
        "- versions: " + ", ".join(f"{k} {val}" for k, val in settings["versions"].items()),
        f"- logs and rows.json: {logs}",
        "",
        tables(content),
    ]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------ README headline

HEADLINE_MARKERS = ("<!-- bench-headline -->\n", "<!-- /bench-headline -->")
HEADLINE_TOOLS = {  # the README's rows, in its order
    "sb3": "Stable-Baselines3 {sb3} PPO, CleanRL settings",
    "canter-cleanrl": "canter `--preset cleanrl` (same settings, 1 env)",
    "canter-fast": "canter default `fast` preset (16 envs)",
}


# Options that name paths on the machine that ran, not settings of the run; a caption leaves them out.
LOCAL_OPTIONS = frozenset({"--sb3-python", "--canter", "--out-dir", "--results"})


def settings_args(args: list[str]) -> list[str]:
    """`args` without LOCAL_OPTIONS and their values (given as `--option VALUE` or `--option=VALUE`)."""
    kept, skip = [], False
    for arg in args:
        if skip:
            skip = False
        elif arg in LOCAL_OPTIONS:
            skip = True
        elif arg.split("=", 1)[0] not in LOCAL_OPTIONS:
            kept.append(arg)
    return kept


def headline(content: dict, m: dict, logs: str) -> str:
    """The README's headline block: per tool, SPS, its ratio to SB3's, process wall and eval return (each the mean
    over seeds), with a caption that names the run, the machine and the archive `logs` it comes from."""
    settings, rows = content["settings"], [r for r in rows_of(content) if r.ok]
    seeds, steps = settings["seeds"], settings["total_steps"]
    args = settings_args(content["command"][1:])
    how = "`make bench`" if not args else f"`benchmarks/ppo_speed/run.sh {' '.join(args)}`"
    caption = (
        f"{ENV_ID}, {f'{steps / 1e6:g}M' if steps % 100_000 == 0 else f'{steps:,}'} steps, "
        f"seed{'s' if len(seeds) > 1 else ''} {','.join(map(str, seeds))}"
        + (" (means over seeds)" if len(seeds) > 1 else "")
        + f", {m['usable_cores']}-core {m['cpu']} with {m['gpu'] or 'no GPU'}, {content['started'][:10]}, "
        f"each tool a whole process run one after another by {how} (full table: "
        f"[benchmarks/ppo_speed/results.md](benchmarks/ppo_speed/results.md); raw logs: [{logs}]({logs})):"
    )
    lines = [
        "| tool / preset | SPS (compile excluded) | vs SB3 | process wall | eval return (10 eps, deterministic) |",
        "|---|---:|---:|---:|---:|",
    ]
    sb3_sps = _mean([r.sps for r in rows if r.tool == "sb3"])
    for tool, label in HEADLINE_TOOLS.items():
        group = [r for r in rows if r.tool == tool]
        sps = _mean([r.sps for r in group])
        if sps is None:
            continue
        ratio = "—" if not sb3_sps else "1.0x" if tool == "sb3" else f"**{sps / sb3_sps:.1f}x**"
        wall, evaluation = _mean([r.process_wall for r in group]), _mean([r.eval_mean for r in group])
        lines.append(
            f"| {label.format(sb3=settings['versions'].get('stable-baselines3'))} | {sps:,.0f} | {ratio} | "
            f"{_f(wall, '.0f')} s | {_f(evaluation, '.0f')} |"
        )
    wrapped = textwrap.fill(caption, width=116, break_long_words=False, break_on_hyphens=False)
    return wrapped + "\n\n" + "\n".join(lines)


def headline_logs(readme: str) -> Path | None:
    """The archive the README's headline block names as its raw logs (None for a block that names none)."""
    return speed_archive.block_logs(readme, HEADLINE_MARKERS)


def write_headline(folder: Path, check: bool, readme: Path = ROOT / "README.md") -> int:
    """Render README.md's headline block from an archive folder; with `check`, exit 1 where it differs instead."""
    return speed_archive.write_block(folder, HEADLINE_MARKERS, headline, check, readme, "--headline")


RESULTS_HEAD = """# PPO speed: canter vs Stable-Baselines3 on HalfCheetah-v4

Written by `benchmarks/ppo_speed/run.py` (see `benchmarks/README.md`); each run appends a dated section.
All tools run one after another, each as a whole process, on the same machine.

- **process wall**: wall time of the whole training process (interpreter start, imports, env and model setup,
  compile for canter, training, final checkpoint), measured from outside. Evaluation is not included.
- **SPS**: env steps per second while training, compile excluded (canter: `summary.json` `sps`; SB3: steps /
  time inside `learn()`).
- **final train return**: mean raw return of the last 20 training episodes.
- **eval return**: 10 deterministic episodes on fresh envs with the observation normalizer frozen.
- **SPS ratio vs SB3**: SPS of the row / SPS of SB3 (mean over seeds).
"""


# ------------------------------------------------------------------------------------------------------ main


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.headline:
        return write_headline(args.headline, args.check)
    started = datetime.now().astimezone()
    out = Path(args.out_dir) if args.out_dir else ROOT / "benchmarks" / "runs" / started.strftime("%Y%m%d-%H%M%S")
    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    print(
        f"PPO speed benchmark: {ENV_ID}, {args.total_steps:,} steps, seeds {args.seeds}, tools {args.tools}", flush=True
    )
    print(f"run folders and logs: {out}", flush=True)
    if os.getloadavg()[0] > 0.5:
        print(
            f"warning: 1-minute load average is {os.getloadavg()[0]:.2f}; something else is using the cores, "
            f"so the timings will not be clean",
            flush=True,
        )

    rows: list[Row] = []
    for seed in args.seeds:
        for tool in args.tools:
            print(f"[{tool} seed {seed}]", flush=True)
            load_before = os.getloadavg()[0]
            row = run_sb3(seed, args, out) if tool == "sb3" else run_canter(tool.split("-", 1)[1], seed, args, out)
            row.extra["load_before"] = load_before
            if row.ok:
                print(
                    f"  steps {row.steps:,} | process wall {row.process_wall:.1f} s | {row.sps:,.0f} SPS"
                    f" | compile {_f(row.compile, '.1f', 'none')}{' s' if row.compile is not None else ''}"
                    f" | load {row.extra.get('load_before', 0):.2f} | train return {_f(row.train_return)}"
                    f" | eval {row.eval_mean:.1f} ± {row.eval_std:.1f}",
                    flush=True,
                )
            rows.append(row)

    settings = {
        "total_steps": args.total_steps,
        "seeds": args.seeds,
        "tools": args.tools,
        "sb3_threads": args.sb3_threads,
        "versions": versions(rows),
    }
    content = speed_archive.record("ppo_speed", started, settings, [r.__dict__ for r in rows])
    results = None if args.no_write else Path(args.results)
    speed_archive.publish(content, out, results, RESULTS_HEAD, section)
    return 0 if all(r.ok for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
