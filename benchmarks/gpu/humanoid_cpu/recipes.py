"""Humanoid-v5 runs of benchmarks/gpu/humanoid_cpu/run.sh with different settings or seeds, side by side:
deterministic evaluations at the same env steps, training returns at the same env steps, and the steps each run
needed for a given evaluation return.

    python benchmarks/gpu/humanoid_cpu/recipes.py RUN RUN [RUN ...] > benchmarks/gpu/humanoid_cpu/recipes.md

Each run is labelled by the settings (and the seed) in which the runs differ. Reads only the run folders' files.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

from compare import GOAL, config, device, fmt, metrics

from canter.config.build import build_config

# Evaluation returns whose first crossing the table lists; the last is the goal.
THRESHOLDS = (500.0, 1000.0, 2000.0, 3000.0, 4000.0, 5000.0, GOAL)
# Sections whose settings can tell the runs apart; of run.*, which holds budgets and folders, only the seed.
LEARNING_SECTIONS = ("env", "net", "ppo")
# Print a training-return row every this many env steps (runs whose iterations differ in length line up by steps).
TRAINING_ROW_STEPS = 1_000_000
# An iteration whose approx_kl exceeds this moved the policy three times as far as these runs' median (about 0.1);
# the table lists each one.
KL_SPIKE = 0.3


def learning_settings(run_dir: Path) -> dict[str, object]:
    """The run's seed and its env, net and ppo settings; a key newer than the run gets its default, which the run
    trained with."""
    settings = config(run_dir)
    defaults = build_config(settings["env"]["id"])
    found: dict[str, object] = {"run.seed": settings["run"]["seed"]}
    for name in LEARNING_SECTIONS:
        section = {**dataclasses.asdict(defaults.section(name)), **settings[name]}
        found.update({f"{name}.{key}": value for key, value in section.items()})
    return found


def labels(runs: list[Path]) -> list[str]:
    settings = [learning_settings(run) for run in runs]
    keys = sorted({key for s in settings for key in s})
    differing = [key for key in keys if len({repr(s.get(key)) for s in settings}) > 1]
    if not differing:
        raise SystemExit("the runs' seeds and env, net and ppo settings are the same; nothing to compare")
    return [", ".join(f"{key} {s.get(key)}" for key in differing) for s in settings]


def first_crossing(evals: list[dict[str, str]], threshold: float) -> str:
    for row in evals:
        if float(row["eval/return_mean"]) >= threshold:
            return f"{int(row['global_step']):,}"
    return f"not in {int(evals[-1]['global_step']):,}" if evals else "no evaluation"


def training_return_at(run_rows: list[dict[str, str]], step: int) -> str:
    """The training return logged by the last iteration that ended at or before `step`."""
    before = [row for row in run_rows if int(row["global_step"]) <= step]
    return fmt(before[-1]["episodic_return"]) if before else ""


def update_sizes(run_rows: list[dict[str, str]]) -> tuple[str, str, str, str]:
    """The run's median approx_kl, its iterations above KL_SPIKE (env steps: approx_kl, and that iteration's
    clip_frac), its largest approx_kl, and its median clip_frac. approx_kl is a mean over samples, so one far-out
    sample can raise it alone; clip_frac, the share of samples whose ratio left the clip range, tells such an
    iteration from one that moved the policy on most states."""
    kls = sorted(float(row["approx_kl"]) for row in run_rows)
    clips = sorted(float(row["clip_frac"]) for row in run_rows)
    spikes = [
        f"{int(row['global_step']):,}: {float(row['approx_kl']):.2f} ({float(row['clip_frac']):.2f})"
        for row in run_rows
        if float(row["approx_kl"]) > KL_SPIKE
    ]
    return f"{kls[len(kls) // 2]:.3f}", "; ".join(spikes) or "none", f"{kls[-1]:.2f}", f"{clips[len(clips) // 2]:.2f}"


def gradient_norms(run_rows: list[dict[str, str]]) -> tuple[str, str]:
    """The median over iterations of each iteration's mean gradient norm before the clip, and the largest single
    step's; runs made before canter logged them say so."""
    if not run_rows or not run_rows[0].get("grad_norm"):
        return "not logged", "not logged"
    norms = sorted(float(row["grad_norm"]) for row in run_rows)
    return f"{norms[len(norms) // 2]:.3g}", f"{max(float(row['grad_norm_max']) for row in run_rows):.3g}"


def main() -> None:
    runs = [Path(arg) for arg in sys.argv[1:]]
    if len(runs) < 2:
        raise SystemExit("usage: recipes.py RUN RUN [RUN ...]")
    names = labels(runs)
    rows = [metrics(run) for run in runs]
    evals = [[row for row in run_rows if row.get("eval/return_mean")] for run_rows in rows]
    print("# Humanoid-v5, the `humanoid` part's PPO settings: runs side by side\n")
    print(f"Written by `python benchmarks/gpu/humanoid_cpu/recipes.py {' '.join(str(run) for run in runs)}`.\n")
    for label, run in zip(names, runs):
        print(f"- **{label}**: `{run.name}` ({device(run)}).")
    seeds = sorted({config(run)["run"]["seed"] for run in runs})
    print(
        f"\nSeed{'s' if len(seeds) > 1 else ''} {', '.join(map(str, seeds))}; C MuJoCo (EnvPool), 2048 envs. The "
        "labels give the settings in which the runs differ; each run's config.toml holds the rest. 10 "
        "deterministic evaluation episodes every 2M env steps.\n"
    )
    print("Deterministic evaluations (env steps: return):\n")
    print("| evaluation | " + " | ".join(names) + " |")
    print("|---:|" + "---:|" * len(runs))
    for i in range(max(len(e) for e in evals)):
        cells = [f"{int(e[i]['global_step']):,}: {fmt(e[i]['eval/return_mean'])}" if i < len(e) else "" for e in evals]
        print(f"| {i + 1} | " + " | ".join(cells) + " |")
    print("\nFirst evaluation at or above each return (env steps):\n")
    print("| return | " + " | ".join(names) + " |")
    print("|---:|" + "---:|" * len(runs))
    for threshold in THRESHOLDS:
        print(f"| {threshold:,.0f} | " + " | ".join(first_crossing(e, threshold) for e in evals) + " |")
    print(
        "\nTraining return (mean of the last 20 episodes) at each million env steps that a run reached, as logged by "
        "its last iteration at or before that step:\n"
    )
    print("| env steps | " + " | ".join(names) + " |")
    print("|---:|" + "---:|" * len(runs))
    longest = max(int(r[-1]["global_step"]) for r in rows)
    for step in range(TRAINING_ROW_STEPS, longest + 1, TRAINING_ROW_STEPS):
        cells = [training_return_at(r, step) if int(r[-1]["global_step"]) >= step else "" for r in rows]
        print(f"| {step:,} | " + " | ".join(cells) + " |")
    print(
        f"\nHow far each iteration moved the policy: approx_kl per iteration (its median, each iteration above "
        f"{KL_SPIKE} as env steps: approx_kl (clip_frac), and the largest), and the median clip_frac:\n"
    )
    print("| | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(runs))
    sizes = [update_sizes(r) for r in rows]
    for i, what in enumerate(("median", f"above {KL_SPIKE}", "largest", "median clip_frac")):
        print(f"| {what} | " + " | ".join(size[i] for size in sizes) + " |")
    print(
        "\nGradient norm (actor and critic together) before `ppo.max_grad_norm` clips it: the median over iterations "
        "of each iteration's mean, and the largest of any step:\n"
    )
    print("| | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(runs))
    gradients = [gradient_norms(r) for r in rows]
    for i, what in enumerate(("median", "largest")):
        print(f"| {what} | " + " | ".join(g[i] for g in gradients) + " |")


if __name__ == "__main__":
    main()
