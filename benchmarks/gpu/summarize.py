"""The figures of one part of run.sh as a markdown block, from the run folders and Brax records it left in OUT.

    python benchmarks/gpu/summarize.py PART OUT     # prints the block and writes OUT/PART.md

Reads only files (summary.json, metrics.csv, config.toml, brax_*.json): it imports neither canter nor JAX, so it
also summarises a part that was cut off, from whatever it had written.
"""

from __future__ import annotations

import csv
import json
import math
import sys
import tomllib
from pathlib import Path

# Humanoid-v5's goal (issue 26): a deterministic-eval return of 6000 (standing still for 1000 steps earns 5000).
HUMANOID_GOAL = 6000.0
# The CPU tables' 1M-step HalfCheetah-v5 scores that the off-policy part aims at.
HALFCHEETAH_GOALS = {"td3": 10_108.0, "sac": 11_651.0}


def runs(folder: Path) -> list[Path]:
    return sorted(p.parent for p in folder.glob("*/summary.json")) if folder.is_dir() else []


def run_facts(run_dir: Path) -> dict:
    summary = json.loads((run_dir / "summary.json").read_text())
    config = tomllib.loads((run_dir / "config.toml").read_text())
    rows = list(csv.DictReader((run_dir / "metrics.csv").open()))
    evals = [
        (int(r["global_step"]), float(r["wall_time"]), float(r["eval/return_mean"]))
        for r in rows
        if r.get("eval/return_mean")
    ]
    return dict(
        iterations=int(float(rows[-1]["iteration"])) if rows and rows[-1].get("iteration") else None,
        run=run_dir.name,
        algo=config["run"]["algo"],
        seed=config["run"]["seed"],
        num_envs=config["env"]["num_envs"],
        steps=summary["global_step"],
        wall=summary["wall_seconds"],
        compile=summary["compile_seconds"],
        sps=summary["sps"],
        train_return=summary["recent_return"],
        stop=summary["stop_reason"],
        evals=evals,
        eval_on=evaluated_on(config),
        final_eval=evals[-1][2] if evals else None,
    )


def evaluated_on(config: dict) -> str:
    """The physics of a run's evaluations during training: its own backend's, or run.eval_backend's."""
    asked = config["run"].get("eval_backend", "")
    return {"": config["env"]["backend"], "auto": "C MuJoCo"}.get(asked, asked)


def time_to(evals: list[tuple[int, float, float]], goal: float) -> str:
    hit = next(((step, wall) for step, wall, score in evals if score >= goal), None)
    return f"{hit[1]:.0f} s ({hit[0]:,} steps)" if hit else "not reached"


def evaluations(facts: dict) -> str:
    """Where the evaluations played, then each as `step (wall): return`: `on C MuJoCo: 1.02M (123 s): 6,309`."""
    each = "; ".join(f"{step / 1e6:.2f}M ({wall:.0f} s): {score:,.0f}" for step, wall, score in facts["evals"])
    return f"on {facts['eval_on']}: {each}" if each else "none"


def fmt(value: float | None, digits: int = 1) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:,.{digits}f}"


def device_name(out: Path) -> str:
    path = out / "device.txt"
    return path.read_text().strip() if path.exists() else "unknown device"


def process_seconds(out: Path, part: str) -> dict[str, float]:
    """The whole-process times run.sh recorded for a part, by label (the last run of each): those that ended by
    themselves, since a process stopped at its limit did not do the whole of its work."""
    path = out / f"{part}.times"
    if not path.exists():
        return {}
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    last = {r["label"]: r for r in records}  # a cut rerun does not fall back to an earlier run's time
    return {label: float(r["seconds"]) for label, r in last.items() if r["exit"] == 0 and not r.get("stopped", False)}


def brax_iterations(record: dict) -> int:
    """Brax's training steps: each collects batch_size x num_minibatches rollouts of unroll_length env steps."""
    s = record["settings"]
    per_step = s["batch_size"] * s["num_minibatches"] * s["unroll_length"] * s.get("action_repeat", 1)
    return round(record["steps"] / per_step)


def ppo_brax(out: Path) -> list[str]:
    lines = [
        "| env | trainer | steps | iterations | whole process (s) | compile + training (s) | steps/s, training | "
        "final eval return | train return (last 20) | stopped |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    processes = process_seconds(out, "ppo-brax")
    for env in ("ant", "humanoid"):
        record_path = out / f"brax_{env}.json"
        if record_path.exists():
            b = json.loads(record_path.read_text())
            kind = "deterministic" if b["settings"].get("deterministic_eval") else "stochastic"
            lines.append(
                f"| {env} | Brax PPO | {b['steps']:,} | {brax_iterations(b)} | {fmt(processes.get(f'brax-{env}'))} | "
                f"{fmt(b.get('training_walltime'))} | {fmt(b['training_sps'], 0)} | "
                f"{fmt(b['final_eval_return'])} ({kind}, {b['eval_episodes']} eps) | - | end |"
            )
        for run in runs(out / "runs" / f"ppo-brax-{env}"):
            c = run_facts(run)
            lines.append(
                f"| {env} | canter ppo --preset brax | {c['steps']:,} | {c['iterations'] or '-'} | "
                f"{fmt(processes.get(f'ppo-brax-{env}'))} | {fmt(c['compile'] + c['steps'] / c['sps'])} | "
                f"{fmt(c['sps'], 0)} | {fmt(c['final_eval'])} (deterministic) | {fmt(c['train_return'])} | "
                f"{c['stop']} |"
            )
    lines.append("")
    lines.append(
        "Whole process: timed from outside by run.sh, interpreter start, imports, compile, training and evaluations "
        "(Brax evaluates three times, canter once at the end). Compile + training: Brax's `training/walltime` (its "
        "training epochs, the first of which compiles), canter's compile plus its steps at its SPS. Training: "
        "Brax's `training/sps` of its last epoch (of two: the first compiles), canter's SPS with the compile left "
        "out. canter trains whole iterations until it has counted Brax's steps, and counts no autoreset step (Brax "
        "resets inside the step that ends an episode), so it can train one iteration more: the iterations column "
        "says. A canter run stopped other than by `budget` was cut by its limit. Brax's AutoResetWrapper restarts an "
        "env from the state its first reset drew; canter draws fresh reset noise each episode, and its resets count "
        "in its SPS."
    )
    return lines


def humanoid(out: Path) -> list[str]:
    lines = [
        "| run | envs | steps | wall (s) | compile (s) | SPS | evaluations: step (wall): return | time to 6000 "
        "| stopped |",
        "|---|---:|---:|---:|---:|---:|---|---|---|",
    ]
    for run in runs(out / "runs" / "humanoid"):
        c = run_facts(run)
        lines.append(
            f"| {c['run']} | {c['num_envs']} | {c['steps']:,} | {fmt(c['wall'])} | {fmt(c['compile'])} | "
            f"{fmt(c['sps'], 0)} | {evaluations(c)} | {time_to(c['evals'], HUMANOID_GOAL)} | {c['stop']} |"
        )
    return lines


def seeds(out: Path) -> list[str]:
    lines = [
        "| program | runs | envs per seed | steps per seed | wall (s) | compile (s) | wall less compile (s) "
        "| stopped |",
        "|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    found = {label: [run_facts(r) for r in runs(out / "runs" / f"seeds-{label}")] for label in ("one", "five")}
    for label, facts in found.items():
        if facts:
            c = facts[0]
            lines.append(
                f"| {label} seed{'s' if label == 'five' else ''} | {len(facts)} | {c['num_envs']} | {c['steps']:,} | "
                f"{fmt(c['wall'])} | {fmt(c['compile'])} | {fmt(c['wall'] - c['compile'])} | {c['stop']} |"
            )
    if found["one"] and found["five"]:
        lines += ["", seeds_ratio(found["one"][0], found["five"][0])]
    return lines


def seeds_ratio(one: dict, five: dict) -> str:
    """Five seeds' wall time over one seed's, for the same steps per seed: a run cut by its limit trained fewer,
    and dividing its time by a whole run's would make five seeds look cheap; then the ratio is per step."""
    # Counted steps leave out autoreset steps, so two whole runs of one budget count slightly different numbers.
    if one["stop"] == five["stop"] == "budget":
        whole = five["wall"] / one["wall"]
        running = (five["wall"] - five["compile"]) / (one["wall"] - one["compile"])
        return f"Wall time of 5 vmapped seeds / 1 seed: {whole:.2f}x (compile left out: {running:.2f}x)."
    per_step = ((five["wall"] - five["compile"]) / five["steps"]) / ((one["wall"] - one["compile"]) / one["steps"])
    return (
        f"A run did not train its whole budget (stopped: one seed {one['stop']}, five seeds {five['stop']}), so no "
        f"whole-run ratio; time per step per seed, compile left out, 5 vmapped seeds / 1 seed: {per_step:.2f}x."
    )


def offpolicy(out: Path) -> list[str]:
    lines = [
        "| algo | envs | batch | updates per vector step | steps | wall (s) | compile (s) | SPS | evaluations: step "
        "(wall): return | CPU 1M-step score | time to it |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---|---:|---|",
    ]
    for algo, goal in HALFCHEETAH_GOALS.items():
        for run in runs(out / "runs" / f"offpolicy-{algo}"):
            c = run_facts(run)
            section = tomllib.loads((run / "config.toml").read_text())[algo]
            lines.append(
                f"| {algo} | {c['num_envs']} | {section['batch_size']} | {section['gradient_steps']} | "
                f"{c['steps']:,} | {fmt(c['wall'])} | {fmt(c['compile'])} | {fmt(c['sps'], 0)} | "
                f"{evaluations(c)} | {goal:,.0f} | {time_to(c['evals'], goal)} |"
            )
    return lines


def smoke(out: Path) -> list[str]:
    lines = ["| run | steps | wall (s) | compile (s) | SPS |", "|---|---:|---:|---:|---:|"]
    for run in runs(out / "runs" / "smoke"):
        c = run_facts(run)
        lines.append(f"| {c['run']} | {c['steps']:,} | {fmt(c['wall'])} | {fmt(c['compile'])} | {fmt(c['sps'], 0)} |")
    return lines


def precision(out: Path) -> list[str]:
    """measure.py's tables at the GPU's default matmul precision and at full float32, with each one's time."""
    lines: list[str] = []
    processes = process_seconds(out, "precision")
    for setting in ("default", "highest"):
        table = out / f"precision-{setting}.table"
        if table.exists():
            lines += [f"JAX_DEFAULT_MATMUL_PRECISION={setting} ({fmt(processes.get(f'precision-{setting}'))} s):", ""]
            lines += table.read_text().strip().splitlines()[2:] + [""]
    return lines


PARTS = {
    "ppo-brax": ppo_brax,
    "humanoid": humanoid,
    "seeds": seeds,
    "offpolicy": offpolicy,
    "smoke": smoke,
    "precision": precision,
}


def main() -> None:
    part, out = sys.argv[1], Path(sys.argv[2])
    settings = out / f"{part}.settings"
    block = [f"### {part} on {device_name(out)}", ""]
    if settings.exists():
        block += ["Settings:", "", "```", settings.read_text().strip(), "```", ""]
    block += PARTS[part](out)
    block += ["", f"Raw log: `{part}.log`."]
    text = "\n".join(block) + "\n"
    (out / f"{part}.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
