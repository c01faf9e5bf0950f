"""Report 000 (PPO, RPO and a symmetric action loss on HumanoidStandup-v4 and HalfCheetah-v4) redone with canter.

    python benchmarks/reports/000-humanoidstandup-halfcheetah-ppo-rpo-sym/run.py              # run what is not archived
    python benchmarks/reports/000-humanoidstandup-halfcheetah-ppo-rpo-sym/run.py --only hc-ent  # one grid
    python benchmarks/reports/000-humanoidstandup-halfcheetah-ppo-rpo-sym/run.py --write      # only rewrite the tables
    python benchmarks/reports/000-humanoidstandup-halfcheetah-ppo-rpo-sym/run.py --check      # exit 1 if stale

Every comparison is one `canter bench` grid on the report's own settings (presets report000-humanoidstandup and
report000-halfcheetah), one factor at a time, with seeds chosen before the runs (the report's seed numbers mean
nothing to canter's generators). The three seed-0 HumanoidStandup runs of 2026-11-23 (benchmarks/results/
humanoidstandup-5m) are the first results and are read from where they are archived. Their checkpoints' evaluations
on EnvPool and on Gymnasium (env_check/) and the videos and cheetah poses (video/) come from the commands the page
shows; this script only reads them.
"""

from __future__ import annotations

import json
import sys
import tomllib
from functools import partial
from pathlib import Path
from typing import Any

PAGE = Path(__file__).resolve().parent
sys.path.insert(0, str(PAGE.parent))  # timed.py, grids.py
sys.path.insert(0, str(PAGE))  # limbs.py
sys.path.insert(0, str(PAGE.parents[1]))  # archive.py
import limbs  # noqa: E402
import numpy as np  # noqa: E402
from archive import ROOT  # noqa: E402
from grids import EVAL_HEADER, Grid, archived_runs, cell_result, curves, eval_text, label, run_grid  # noqa: E402
from timed import page_main  # noqa: E402

from canter.orchestrate.bench_results import seed_record  # noqa: E402
from canter.training.run_folder import metrics_file  # noqa: E402
from canter.use.curves import read_metrics  # noqa: E402

WORK = "runs/report000"  # the bench folders (with checkpoints), relative to the repository root
SEEDS = (100, 101, 102)  # chosen before the runs, for every comparison that runs 3 seeds
ONE_SEED = (100,)  # HumanoidStandup's ablations: one 5M-step run per setting, as in the report
HS, HS_PRESET = "HumanoidStandup-v4", "report000-humanoidstandup"
HC, HC_PRESET = "HalfCheetah-v4", "report000-halfcheetah"
NO_SYM = ("sym.coef=0",)  # the preset's symmetric loss (0.02) off: the report added it last
HC_ENT0 = ("ppo.ent_coef=0",)  # HalfCheetah's ablation 1 chose 0.0; its later ablations build on that

GRIDS = {
    "hs-ppo": Grid("hs-ppo", HS, ("ppo",), HS_PRESET, SEEDS, 5_000_000, sets=NO_SYM),
    "hs-rpo-sym": Grid("hs-rpo-sym", HS, ("rpo",), HS_PRESET, SEEDS, 5_000_000),
    "hs-ent": Grid("hs-ent", HS, ("ppo",), HS_PRESET, ONE_SEED, 5_000_000, (("ppo.ent_coef", ("0.01", "0")),), NO_SYM),
    "hs-lr-3e-4": Grid("hs-lr-3e-4", HS, ("ppo",), HS_PRESET, ONE_SEED, 1_000_000, (("ppo.lr", ("3e-4",)),), NO_SYM),
    "hs-lr-1e-4": Grid("hs-lr-1e-4", HS, ("ppo",), HS_PRESET, ONE_SEED, 2_000_000, (("ppo.lr", ("1e-4",)),), NO_SYM),
    "hs-sym": Grid("hs-sym", HS, ("rpo",), HS_PRESET, ONE_SEED, 5_000_000, (("sym.coef", ("0", "0.01", "0.05")),)),
    "hc-ent": Grid("hc-ent", HC, ("ppo",), HC_PRESET, SEEDS, 1_000_000, (("ppo.ent_coef", ("0.5", "1e-4", "0")),)),
    # The report's best run on its own seed, 8: the one seed the report names, so chosen before the run.
    "hc-best-s8": Grid("hc-best-s8", HC, ("ppo",), HC_PRESET, (8,), 1_000_000, (("ppo.ent_coef", ("0.5",)),)),
    "hc-algo": Grid("hc-algo", HC, ("ppo", "rpo"), HC_PRESET, SEEDS, 1_000_000, sets=HC_ENT0),
    "hc-net": Grid(
        "hc-net", HC, ("ppo",), HC_PRESET, SEEDS, 1_000_000, (("net.hidden", ("64-64", "64-32", "128-64")),), HC_ENT0
    ),
    # The report lists a fourth network, 128-64-64, and RPO's alpha among the settings it varied, but its slides show
    # neither result; both are run here on HalfCheetah, where a 1M-step grid takes minutes. alpha 0.5 is hc-algo's
    # rpo row (the preset's value).
    "hc-net-deep": Grid(
        "hc-net-deep", HC, ("ppo",), HC_PRESET, SEEDS, 1_000_000, (("net.hidden", ("128-64-64",)),), HC_ENT0
    ),
    "hc-rpo-alpha": Grid(
        "hc-rpo-alpha", HC, ("rpo",), HC_PRESET, SEEDS, 1_000_000, (("rpo.alpha", ("0.1", "1.0")),), HC_ENT0
    ),
}

# Steps per second of one seed for the wall-time estimates: the median of the per-iteration `sps` column of
# metrics.csv, alone (one seed in its process) and together (each of a grid's 3 seeds training in one process).
# HumanoidStandup alone: the three archived 5M-step runs of 2026-11-23 (1,287, 1,217 and 1,361); together: the
# hs-ppo grid's first 4.6M steps (543 per seed, so 1,630 for the three: 1.25x one seed alone). Both shared the
# machine with other work, as a bench here will. HalfCheetah together: the archived hc-algo grid (3,794 for ppo,
# 4,045 for rpo, per seed), as fast per seed as one seed alone (smoke runs: 3,274 and 4,326): with this preset's
# single env a step is overhead, which the seeds share.
SPS_ALONE = {HS: 1300, HC: 3900}
SPS_TOGETHER = {HS: 543, HC: 3900}

# Rows whose grid values do not say what they are.
LABELS = {"hs-rpo-sym": "rpo + sym 0.02", "hc-best-s8": "ppo.ent_coef=0.5, seed 8"}
# A row one grid shares with another that already runs its settings on its seed: grid -> (row, source grid, seed).
# hs-ent's 1e-4 is the preset's value, so that row is hs-ppo's seed-100 run rather than a fourth 5M-step run. It
# trained in one program with seeds 101-102, so its floating-point rounding, and with it its trajectory, differ
# from a lone run's (the first two episodes' returns differed by 3% on a short check); settings and seed are the same.
SHARED = {"hs-ent": ("ppo.ent_coef=0.0001", "hs-ppo", 100)}

# What the report says about each setting (its slides give curves and which setting won, not numbers).
REPORT = {
    "hs-ppo": {"ppo": "PPO (green): below RPO"},
    "hs-rpo-sym": {"rpo + sym 0.02": "its best run, seed 0: **train 160,000, test 131,000**"},
    "hs-ent": {
        "ppo.ent_coef=0.01": "pink",
        "ppo.ent_coef=0.0001": "**chosen** (yellow)",
        "ppo.ent_coef=0.0": "blue",
    },
    "hs-lr-3e-4": {"ppo.lr=0.0003": "gray, 1M steps"},
    "hs-lr-1e-4": {"ppo.lr=0.0001": "cyan, 2M steps"},
    "hs-sym": {
        "sym.coef=0.0": "green (RPO alone)",
        "sym.coef=0.01": '**chosen** (black): "positive effect!"',
        "sym.coef=0.05": "orange",
    },
    "hc-ent": {
        "ppo.ent_coef=0.5": "its best-run table's value: seed 8, **train 4,000, test 3,250**",
        "ppo.ent_coef=0.0001": "black",
        "ppo.ent_coef=0.0": "**chosen** (pink)",
    },
    "hc-best-s8": {"ppo.ent_coef=0.5, seed 8": "its best run, seed 8: **train 4,000, test 3,250**"},
    "hc-algo": {"ppo": "**chosen** (orange)", "rpo": "RPO, coef 0.5 (cyan)"},
    "hc-net": {
        "net.hidden=64-64": "**chosen** (orange)",
        "net.hidden=64-32": "cyan",
        "net.hidden=128-64": "yellow",
    },
    "hc-net-deep": {"net.hidden=128-64-64": "listed among its networks; no result shown"},
    "hc-rpo-alpha": {
        "rpo.alpha=0.1": "RPO alpha is among the settings it varied; no result shown",
        "rpo.alpha=1.0": "",
    },
}

SECTIONS = (
    (
        "HumanoidStandup-v4: PPO against RPO + symmetric loss, 5M steps",
        ("hs-ppo", "hs-rpo-sym"),
        "The report's best run is RPO with the symmetric loss 0.02; its PPO is the curve of its slide 3.",
    ),
    (
        "HumanoidStandup-v4, ablation 1: entropy coefficient (PPO, no symmetric loss)",
        ("hs-ent",),
        "The slides do not state this ablation's budget; canter runs it at the best run's 5M steps. The 1e-4 row is "
        "the preset's value, so it is the first table's ppo run on seed 100 (same settings and seed, but trained in "
        "one vmapped program beside seeds 101-102, whose float rounding differs from a seed trained alone: "
        "docs/multiseed.md).",
    ),
    (
        "HumanoidStandup-v4, ablation 2: learning rate (PPO, no symmetric loss)",
        ("hs-lr-3e-4", "hs-lr-1e-4"),
        "Two budgets, so two grids. The slide marks no winner; the best run's table uses 2e-5.",
    ),
    (
        "HumanoidStandup-v4, ablation 4: symmetric action loss coefficient (RPO)",
        ("hs-sym",),
        "Ablation 3 (PPO against RPO) is the first table (with the loss) and this table's 0 row (without). The "
        "slide marks 0.01 best; the best run's table says 0.02, which is the first table's RPO row. The one "
        "comparison that changes RPO alone, seed 100 without the loss, goes against the report's \"RPO is better "
        "than PPO\": RPO 165,194, PPO 215,155 (`hs-ppo`'s seed 100).",
    ),
    (
        "HalfCheetah-v4, ablation 1 and the best run: entropy coefficient (PPO, 1M steps)",
        ("hc-ent", "hc-best-s8"),
        "The best run's table says 0.5 where the ablation chose 0.0; both are run, with 1e-4, and 0.5 also on the "
        "best run's own seed, 8.",
    ),
    ("HalfCheetah-v4, ablation 2: PPO against RPO (entropy 0, 1M steps)", ("hc-algo",), ""),
    (
        "HalfCheetah-v4, ablation 3: network (PPO, entropy 0, 1M steps)",
        ("hc-net", "hc-net-deep"),
        "128-64-64 is the fourth network the report lists; its slide compares the other three.",
    ),
    (
        "HalfCheetah-v4: RPO's alpha (entropy 0, 1M steps)",
        ("hc-algo", "hc-rpo-alpha"),
        "Not a slide of the report, which names RPO alpha among the settings it changed: alpha 0.5 is the rpo row of "
        "ablation 2 (the same grid, repeated here), 0.1 and 1.0 run beside it.",
    ),
)

# The report's ablation 3 is one figure with PPO and RPO overlaid; the bench draws one plot per grid, so the two
# grids' archived runs are drawn together by canter plot (the bench's own metric and smoothing).
OVERLAY = PAGE / "ppo_vs_rpo_HumanoidStandup-v4.png"
OVERLAY_COMMAND = (
    f"canter plot {PAGE.relative_to(ROOT)}/runs/hs-ppo/{HS}__ppo__s* {PAGE.relative_to(ROOT)}/runs/hs-rpo-sym/"
    f"{HS}__rpo__s* --metrics episodic_return --smooth 5 --out {OVERLAY.relative_to(ROOT)}"
)

LIMBS_TITLE = "### HumanoidStandup-v4: does the symmetric loss make the humanoid use both sides?"
LIMBS_COMMAND = f"python {PAGE.relative_to(ROOT)}/limbs.py"
LIMBS_NOTE = (
    "Each final policy, 5 deterministic episodes (the evaluation env, its first 5 seeds), clipped actions. *Effort "
    "asymmetry*: |L - R| / (L + R) of the two sides' mean squared torques, 0 for even use, 1 for one side only. "
    "*Mirror mismatch*: E|L - sR|² / (E|L|² + E|R|²), with the left shoulders' mirrored axes flipped (s), 0 for "
    "mirror-image motion, 1 for sides that move independently, 2 for opposite motion. The report judged this from "
    "videos; the seed-0 runs keep their checkpoints in benchmarks/results, the others were measured where they "
    "trained."
)

SEED0 = ROOT / "benchmarks" / "results" / "humanoidstandup-5m"
# label, folder under run-folders/, eval_<name>.json, what the report says of it
SEED0_RUNS = (
    ("ppo", "ppo", "ppo", REPORT["hs-ppo"]["ppo"]),
    ("rpo", "rpo", "rpo", "RPO, coef 0.5 (yellow): **better than PPO**"),
    ("rpo + sym 0.02", "rposym", "rposym", REPORT["hs-rpo-sym"]["rpo + sym 0.02"]),
)
# How each was trained (benchmarks/results/README.md): the preset's seed, 0, and its 5M steps.
SEED0_COMMANDS = {
    "ppo": f"canter train {HS} --preset {HS_PRESET} --algo ppo --set sym.coef=0",
    "rpo": f"canter train {HS} --preset {HS_PRESET} --set sym.coef=0",
    "rpo + sym 0.02": f"canter train {HS} --preset {HS_PRESET}",
}

# HumanoidStandup's reward_linup is the torso's height over the physics timestep: Gymnasium's humanoidstandup_v4.py
# (and v5, whose uph_cost_weight is 1) has uph_cost = qpos[2] / model.opt.timestep, 0.003 s in humanoidstandup.xml
# (not dt, the 0.015 s of the 5 physics steps between actions). metrics.csv holds each episode's sum of it (a reward
# term), averaged over the episodes an iteration ended.
LINUP_TIMESTEP = 0.003
LAST_EPISODES = 20  # as the train column: the mean return of the last 20 training episodes
HEIGHTS_TITLE = "### HumanoidStandup-v4: does the humanoid stand up?"

# The seed-0 checkpoints evaluated on both backends' HumanoidStandup-v4: the evaluations are archived here.
ENV_CHECK = PAGE / "env_check"
BACKENDS = {"envpool": "EnvPool", "gymnasium": "Gymnasium"}
IMPACT_CAP = 10.0  # Gymnasium's impact cost per step, min(0.5e-6 * sum(cfrc_ext^2), 10); EnvPool's has none
MARKERS = {
    "commands": ("<!-- report000-commands -->\n", "<!-- /report000-commands -->"),
    "results": ("<!-- report000-results -->\n", "<!-- /report000-results -->"),
}


def _duration(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 5400 else f"{seconds / 60:.0f} min"


def estimate_seconds(grid: Grid) -> float:
    if len(grid.seeds) == 1:
        return grid.env_steps() / SPS_ALONE[grid.env]
    return grid.env_steps() / len(grid.seeds) / SPS_TOGETHER[grid.env]


def commands_table() -> str:
    lines = [
        "| grid | command | env steps | estimated wall | archived |",
        "|---|---|---:|---:|---|",
    ]
    for name, grid in GRIDS.items():
        cells = grid.cells()
        done = sum(cell_result(PAGE, grid, cell) is not None for cell in cells)
        lines.append(
            f"| `{name}` | `{grid.command(WORK)}` | {grid.env_steps() / 1e6:g}M | {_duration(estimate_seconds(grid))} "
            f"| {done} of {len(cells)} cells |"
        )
    total = sum(estimate_seconds(g) for g in GRIDS.values())
    lines.append(f"| all | `python {PAGE.relative_to(ROOT)}/run.py` | | {_duration(total)} | |")
    # run.py does not train the seed-0 runs (they are archived in benchmarks/results), so their commands, which
    # that folder's README gives, are repeated here for the page to say how every row of it was made.
    for variant, folder, _, _ in SEED0_RUNS:
        [run] = (SEED0 / "run-folders" / folder).iterdir()
        config = tomllib.loads((run / "config.toml").read_text())["run"]
        lines.append(
            f"| seed 0, {variant} | `{SEED0_COMMANDS[variant]}`, then `canter eval RUN --episodes 10` | "
            f"{config['total_steps'] / 1e6:g}M | | yes, in [`{SEED0.relative_to(ROOT)}`](../../results/"
            f"humanoidstandup-5m/) (its config.toml names the preset `{config['preset']}`, now an alias of "
            f"`{HS_PRESET}`) |"
        )
    return "\n".join(lines)


def _per_seed(result: dict[str, Any]) -> str:
    return ", ".join(f"{r['eval_mean']:,.0f}" for r in result["runs"])


def shared_row(name: str) -> tuple[str, str]:
    """The row `name` takes from another grid's run: its label and its table row."""
    text, source, seed = SHARED[name]
    [cell] = GRIDS[source].cells()
    report = REPORT[name].get(text, "")
    runs = [r for r in archived_runs(PAGE, GRIDS[source], cell) if r["seed"] == seed]
    if not runs:
        return text, f"| {text} | {report} | {seed} | not run yet (`{source}`, seed {seed}) | | | |"
    [run] = runs
    return text, (
        f"| {text} | {report} | {seed} (`{source}`'s run) | {run['eval_mean']:,.0f} | {run['eval_mean']:,.0f} | "
        f"{run['summary']['recent_return']:,.0f} | {run['wall_seconds'] / 60:.0f} min, with `{source}`'s other seeds |"
    )


def grid_rows(name: str) -> list[str]:
    """The grid's rows, with any row it shares with another grid, in the order the report lists them."""
    grid = GRIDS[name]
    cells = grid.cells()
    rows = {}
    for cell in cells:
        text = LABELS.get(name, label(cell, cells))
        report = REPORT[name].get(text, "")
        result = cell_result(PAGE, grid, cell)
        seeds = ",".join(map(str, grid.seeds))
        if result is None:
            rows[text] = f"| {text} | {report} | {seeds} | not run yet (`{name}`) | | | |"
            continue
        rows[text] = (
            f"| {text} | {report} | {seeds} | {eval_text(result)} | {_per_seed(result)} | "
            f"{result['train_return']:,.0f} | {result['wall_minutes']:.0f} min |"
        )
    if name in SHARED:
        text, row = shared_row(name)
        rows[text] = row
    order = list(REPORT[name])
    return [rows[text] for text in sorted(rows, key=lambda t: order.index(t) if t in order else len(order))]


def seed0_rows() -> list[str]:
    """The three runs of 2026-11-23, seed 0, archived with their checkpoints in benchmarks/results."""
    rows = []
    for variant, folder, evaluation, report in SEED0_RUNS:
        [run] = (SEED0 / "run-folders" / folder).iterdir()
        summary = json.loads((run / "summary.json").read_text())
        [result] = json.loads((SEED0 / f"eval_{evaluation}.json").read_text())["runs"]
        wall = seed_record(run, 0)["wall_seconds"]
        link = f"[{variant}](../../results/humanoidstandup-5m/run-folders/{folder}/)"
        # One seed: the eval column and the per-seed column hold the same mean, as in the one-seed grids' rows.
        rows.append(
            f"| {link} | {report} | 0 (2026-11-23) | {result['return_mean']:,.0f} | {result['return_mean']:,.0f} "
            f"| {summary['recent_return']:,.0f} | {wall / 60:.0f} min |"
        )
    return rows


def torso_heights(run: Path) -> tuple[float, float, float]:
    """A run's episode-mean torso height in metres, in its first training iteration that ended episodes, over the
    last iterations that ended at least LAST_EPISODES, and in the highest of any iteration."""
    columns = read_metrics(metrics_file(run))
    ended = columns["episodes"] > 0
    episodes = columns["episodes"][ended]
    heights = columns["info/reward_linup"][ended] / columns["episodic_length"][ended] * LINUP_TIMESTEP
    last = int(np.searchsorted(np.cumsum(episodes[::-1]), LAST_EPISODES)) + 1  # whole iterations from the end
    final = float(np.average(heights[-last:], weights=episodes[-last:]))
    return float(heights[0]), final, float(heights.max())


def height_runs() -> list[tuple[str, str, Path, float]]:
    """Every archived HumanoidStandup run: its setting, its seed, its folder and its evaluation's mean return per
    step."""
    runs = []
    for variant, folder, evaluation, _ in SEED0_RUNS:
        [run] = (SEED0 / "run-folders" / folder).iterdir()
        [result] = json.loads((SEED0 / f"eval_{evaluation}.json").read_text())["runs"]
        runs.append((variant, "0 (2026-11-23)", run, result["return_mean"] / result["length_mean"]))
    for name, grid in GRIDS.items():
        if grid.env != HS:
            continue
        cells = grid.cells()
        for cell in cells:
            text = LABELS.get(name, label(cell, cells))
            for record in archived_runs(PAGE, grid, cell):
                evaluation = record["evaluation"]
                per_step = evaluation["mean"] / float(np.mean(evaluation["lengths"]))
                run = cell.run_dir(PAGE / "runs" / name, record["seed"])
                runs.append((f"{text} (`{name}`)", str(record["seed"]), run, per_step))
    return runs


def heights_text() -> str:
    rows = [
        "| run | seed | first training episodes | last 20 training episodes | highest iteration | evaluation |",
        "|---|---|---:|---:|---:|---:|",
    ]
    measured = []  # first, last 20, highest, evaluation
    for setting, seed, run, per_step in height_runs():
        # EnvPool's return per step is reward_linup + 1 (alive) - the control cost (at most 0.1 * 17 * 0.4^2 =
        # 0.272, 0.0008 m of height, left out); it has no impact cost.
        heights = (*torso_heights(run), LINUP_TIMESTEP * (per_step - 1))
        measured.append(heights)
        rows.append(f"| {setting} | {seed} | " + " | ".join(f"{h:.2f}" for h in heights) + " |")
    firsts, finals, highs, evaluated = zip(*measured)
    note = (
        "The torso's height in metres, averaged over each 1,000-step episode. Gymnasium's HumanoidStandup-v4 (and "
        "v5) rewards `reward_linup` = qpos[2] / 0.003 every step, the torso's height over the physics timestep with "
        "weight 1, so a training episode's mean height is 0.003 × its `info/reward_linup` in metrics.csv (the "
        "episode's sum, averaged over the episodes an iteration ended) / its length. *first*: the first iteration "
        f"that ended episodes; *last 20*: the last iterations that ended at least {LAST_EPISODES} episodes, the "
        "train column's; *highest*: the highest of any iteration; *evaluation*: the 10 deterministic episodes of the "
        "eval column, 0.003 × (R / L - 1) from their mean return R over L steps, EnvPool's return per step being "
        "reward_linup + 1 minus a control cost of at most 0.272 (0.0008 m). The humanoid starts lying with its "
        f"torso at 0.105 m (humanoidstandup.xml), as the first episodes' {min(firsts):.2f}-{max(firsts):.2f} m "
        "show. The same body in Humanoid-v4 starts standing with its torso at 1.4 m, and an episode there ends as a "
        "fall once the torso is below 1.0 m. Every run here ends its training at "
        f"{min(finals):.2f}-{max(finals):.2f} m and evaluates at {min(evaluated):.2f}-{max(evaluated):.2f} m; "
        f"no iteration of any run averages above {max(highs):.2f} m."
    )
    return f"{HEIGHTS_TITLE}\n\n" + "\n".join(rows) + f"\n\n{note}"


def env_check() -> dict[str, dict[str, dict[str, Any]]]:
    """The archived evaluations of the seed-0 checkpoints: backend -> the run's SEED0_RUNS label -> its result."""
    labels = {folder: variant for variant, folder, _, _ in SEED0_RUNS}
    results: dict[str, dict[str, dict[str, Any]]] = {}
    for backend in BACKENDS:
        runs = json.loads((ENV_CHECK / f"eval_{backend}.json").read_text())["runs"]
        results[backend] = {labels[Path(r["run"]).parent.name]: r for r in runs}
    return results


def env_check_text() -> str:
    commands = "\n".join(
        f"canter eval {SEED0.relative_to(ROOT)}/run-folders/*/* --backend {backend} "
        f"--json {(ENV_CHECK / f'eval_{backend}.json').relative_to(ROOT)}"
        for backend in BACKENDS
    )
    results = env_check()
    rows = [
        "| run (seed 0) | EnvPool | Gymnasium | Gymnasium - EnvPool |",
        "|---|---:|---:|---:|",
    ]
    for variant, _, _, _ in SEED0_RUNS:
        envpool, gymnasium = (results[backend][variant] for backend in BACKENDS)
        gap = gymnasium["return_mean"] - envpool["return_mean"]
        rows.append(
            f"| {variant} | {envpool['return_mean']:,.0f} ± {envpool['return_std']:,.0f} | "
            f"{gymnasium['return_mean']:,.0f} ± {gymnasium['return_std']:,.0f} | {gap:+,.0f} "
            f"({gap / envpool['return_mean']:+.0%}) |"
        )
    [episodes] = {r["episodes"] for result in results.values() for r in result.values()}
    [steps] = {r["length_mean"] for result in results.values() for r in result.values()}
    note = (
        f"Mean ± std over {episodes} deterministic episodes of {steps:,.0f} steps (eval seed 0) of each "
        "seed-0 checkpoint, which trained on EnvPool. Gymnasium's HumanoidStandup-v4 gives the policy the 84 "
        "contact-force entries of its observation that EnvPool's keeps at 0, and subtracts an impact cost of at "
        f"most {IMPACT_CAP:g} per step ({IMPACT_CAP * steps:,.0f} per episode) that EnvPool's leaves out. Every "
        f"policy scores less there, by {min(gymnasium_losses()):.0%} to {max(gymnasium_losses()):.0%}."
    )
    title = "### HumanoidStandup-v4: the seed-0 policies on EnvPool's env and on Gymnasium's"
    return f"{title}\n\n```\n{commands}\n```\n\n" + "\n".join(rows) + f"\n\n{note}"


def gymnasium_losses() -> list[float]:
    """How much less each seed-0 policy scores on Gymnasium's env than on EnvPool's, as a fraction."""
    results = env_check()
    return [1 - results["gymnasium"][v]["return_mean"] / results["envpool"][v]["return_mean"] for v, *_ in SEED0_RUNS]


def protocol_text() -> str:
    losses = gymnasium_losses()
    return (
        "Protocol: the report's *train* and *test* figures are the highest points of its curves "
        '("Training: 160,000 (highest)", "Test: 131,000 (highest)"): *train* CleanRL\'s logged training episodic '
        "return, *test* an evaluation of unstated length. canter's are final means, not maxima: its *eval* is a "
        "deterministic evaluation of the final policy, 10 episodes per seed, and its *train* the mean return of the "
        "last 20 training episodes. Both use the v4 envs (canter through EnvPool, MuJoCo 3.6), but EnvPool's "
        "HumanoidStandup-v4 is not Gymnasium's, which CleanRL and most likely the report stepped: its observation's "
        "84 contact-force entries stay 0 and its reward leaves out the impact cost. The seed-0 policies score "
        f"{min(losses):.0%} to {max(losses):.0%} less on Gymnasium's env (the table above), so canter's "
        "HumanoidStandup figures and the report's are of two envs that differ by more than a rounding. Wall time is "
        "the bench's (the training loop of a cell's seeds, which train together in one process, every session of a "
        "resumed run) on a 2-core AMD EPYC without GPU, often shared with other work."
    )


def time_text() -> str:
    """The wall time of every archived run, added up."""
    walls = {HS: 0.0, HC: 0.0}
    for grid in GRIDS.values():
        for cell in grid.cells():
            result = cell_result(PAGE, grid, cell)
            if result is not None:
                walls[grid.env] += result["wall_minutes"] * 60
    seed0 = []
    for _, folder, _, _ in SEED0_RUNS:
        [run] = (SEED0 / "run-folders" / folder).iterdir()
        seed0.append(seed_record(run, 0)["wall_seconds"])
    grids = walls[HS] + walls[HC]
    return (
        "Time: the report gives no wall time. canter's archived runs add up to "
        f"{(grids + sum(seed0)) / 3600:.1f} h of wall time: the grids {grids / 3600:.1f} h (HumanoidStandup "
        f"{walls[HS] / 3600:.1f} h, HalfCheetah {walls[HC] / 60:.0f} min; a cell counts once, its seeds training "
        f"together), and the three seed-0 runs {sum(seed0) / 3600:.1f} h (one seed per process; the three started "
        f"together and ran side by side, the last for {max(seed0) / 3600:.1f} h). Runs often shared the 2 cores, "
        "with each other or with other work, so the sum is not the time from the page's first run to its last."
    )


def results_text() -> str:
    header = [
        f"| setting | report | seeds | canter {EVAL_HEADER} | per seed | canter train | wall |",
        "|---|---|---|---:|---|---:|---:|",
    ]
    parts = []
    for title, names, note in SECTIONS:
        rows = [row for name in names for row in grid_rows(name)]
        if "hs-ppo" in names:
            rows = seed0_rows() + rows
        commands = "\n".join(GRIDS[name].command(WORK) for name in names)
        text = f"### {title}\n\n```\n{commands}\n```\n\n" + "\n".join(header + rows)
        plots = [curves(PAGE, GRIDS[name]) for name in names]
        images = " ".join(f"![{p.parent.name}]({p.relative_to(PAGE)})" for p in plots if p.is_file())
        parts.append(text + (f"\n\n{note}" if note else "") + (f"\n\n{images}" if images else ""))
        if "hs-ppo" in names and OVERLAY.is_file():
            parts.append(
                f"The two grids' seeds 100-102 in one figure, as the report's ablation 3 draws PPO and RPO (this "
                f"RPO has the symmetric loss 0.02):\n\n```\n{OVERLAY_COMMAND}\n```\n\n"
                f"![ppo against rpo + sym 0.02]({OVERLAY.relative_to(PAGE)})"
            )
        if "hs-sym" in names:
            parts.append(f"{LIMBS_TITLE}\n\n```\n{LIMBS_COMMAND}\n```\n\n{limbs.table()}\n\n{LIMBS_NOTE}")
            parts.append(heights_text())
    return "\n\n".join([*parts, env_check_text(), protocol_text(), time_text()])


def main() -> int:
    steps = {name: partial(run_grid, PAGE, grid, ROOT / WORK) for name, grid in GRIDS.items()}
    blocks = [(MARKERS["commands"], commands_table), (MARKERS["results"], results_text)]
    return page_main(__doc__ or "", PAGE, blocks, steps, archives=[SEED0])


if __name__ == "__main__":
    sys.exit(main())
