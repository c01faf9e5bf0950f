"""Report 002 (TRPO on Hopper with a torso-mass test; PPO and DDPG tuned by Optuna on BipedalWalker) redone with canter.

    python benchmarks/reports/002-hopper-trpo-bipedalwalker/run.py                    # run what is not archived
    python benchmarks/reports/002-hopper-trpo-bipedalwalker/run.py --only tune-ppo    # one step (repeatable)
    python benchmarks/reports/002-hopper-trpo-bipedalwalker/run.py --write            # only rewrite the tables
    python benchmarks/reports/002-hopper-trpo-bipedalwalker/run.py --check            # exit 1 if stale

Seeds 100, 101 and 102 were chosen before the runs (the report's seeds 47, 33, 12 and 35 mean nothing to canter's
generators). Hopper is a `canter bench` grid, and its three policies are then swept over the torso mass with
`canter eval --vary`. BipedalWalker runs are whole `canter train` processes with `--stop-at-return 300`, one seed at a
time, so each one's wall time to 300 is its own: `canter bench` counts a run that stopped at the return as
unfinished (its budget is not reached) and would resume it on the next call. The two short `canter tune` studies
search the report's own spaces (search_space_ppo.toml and search_space_ddpg.toml beside this file, which --check
validates as `canter tune --space` would).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

PAGE = Path(__file__).resolve().parent
sys.path.insert(0, str(PAGE.parent))  # timed.py, grids.py
sys.path.insert(0, str(PAGE.parents[1]))  # archive.py
from archive import ROOT  # noqa: E402
from grids import EVAL_HEADER, Grid, cell_result, eval_text, run_grid  # noqa: E402
from timed import (  # noqa: E402
    archived,
    canter_command,
    load_text,
    out_of_time,
    page_main,
    run_to_deadline,
    timed_train,
)

from canter.orchestrate.search_space import Param, load_space  # noqa: E402
from canter.use.statistics import aggregates  # noqa: E402

WORK = "runs/report002"  # bench, train and tune folders (with checkpoints), relative to the repository root
SEEDS = (100, 101, 102)  # chosen before the runs
PAGE_PATH = PAGE.relative_to(ROOT)

HOPPER = Grid("hopper-trpo", "Hopper-v4", ("trpo",), "report002-hopper-trpo", SEEDS, 1_000_000)
TORSO_SCALES = ("0.5", "0.75", "1", "1.25", "1.5")
TORSO_EPISODES = 10
SWEEP = PAGE / "torso_mass.png"  # and torso_mass.json beside it, as canter eval --vary --out writes them

WALKER = "BipedalWalker-v3"
WALKER_STEPS = "1e7"  # the report's budget: ten million env steps or a return of 300, whichever comes first
WALKER_PRESETS = {"ppo": "report002-bipedalwalker-ppo", "ddpg": "report002-ddpg"}
WALKER_EPISODES = 100  # the report's evaluation
# PPO's first attempt, with canter's reward and observation normalization on (the report's SB3 has neither unless
# VecNormalize is wrapped in, which it does not mention): archived under runs/<this>/ with its curves, and shown
# beside the rerun without them.
FIRST_ATTEMPT = "first-attempt-normalized"
FIRST_CURVES = "curves_ppo_first_attempt.png"
FIRST_ATTEMPT_SET = "env.normalize_reward=true"  # the preset's value then; its observation normalization is on still

# The report's own search spaces and its runtime settings (table 3), cut from 50 trials to 10 (and from 10 random
# startup trials to 5, from 4 jobs to 1): per trial the report's 1M steps and 20 evaluations of 5 episodes.
TUNE_TRIALS, TUNE_STEPS = 10, "1e6"
TUNE_SETTINGS = ["--trials", str(TUNE_TRIALS), "--startup-trials", "5", "--total-steps", TUNE_STEPS]
TUNE_SETTINGS += ["--evaluations", "20", "--eval-episodes", "5", "--jobs", "1"]
TUNE_SETTINGS += ["--seed", "100", "--sampler-seed", "100"]  # the trials' seed, and TPE's, chosen before the runs
TUNE_FILES = ("summary.md", "best.toml")
# The runs' curves, as the report's figures 2-7 draw them (smoothed over 50 logged rows).
CURVES = {
    "ppo": "episodic_return,episodic_length,sps,approx_kl,clip_frac,explained_variance,entropy,policy_loss,value_loss",
    "ddpg": "episodic_return,episodic_length,sps,actor_loss,critic_loss",
}

# Steps per second for the wall-time estimates, the median of the per-iteration `sps` column of metrics.csv from two
# smoke runs of about 20k steps each, made on 2026-11-26 under a load average of 9-11 before any run of these
# presets was archived: trpo 5,208 and 5,697, ppo 9,134 and 8,680, ddpg 1,337 and 2,630 (a HumanoidStandup smoke run
# beside them gave 830, 1,816 and 1,342 against 1,300 for its archived 5M-step runs, so expect +-50%). What the
# archived runs took is in the commands table's last column (`archived_wall`): ppo 37 min for its three seeds
# against 56 estimated, ddpg 4.7 h against 4.2.
SPS = {"hopper-trpo": 5400, "ppo": 8900, "ddpg": 2000}
# A trial's start, compile and evaluations: trials of 4k-8k steps took 0.8-1.1 min in two 2-trial smoke studies.
TRIAL_OVERHEAD_SECONDS = 60
# canter eval --vary: 3 runs x 5 masses x 10 episodes of up to 1,000 steps on Gymnasium's Hopper, about 2k steps/s.
SWEEP_SECONDS = 3 * len(TORSO_SCALES) * TORSO_EPISODES * 1000 / 2000

# The report's table 6: evaluation over 100 episodes (env seed 1), training time (H:MM:SS) to the end of training.
REPORT_WALKER = (
    ("ppo", 47, "308.4 (35.8)", "893.2", "4:55:52"),
    ("ppo", 33, "300.1 (74.9)", "744.6", "1:28:15"),
    ("ppo", 12, "-121.1 (3.6)", "103.9", "1:39:10"),
    ("ddpg", 33, "156.3 (86.1)", "1272.3", "1:47:11"),
    ("ddpg", 35, "-42.8 (10.8)", "1600.0", "1:45:15"),
    ("ddpg", 12, "-31.3 (68.2)", "1589.4", "1:54:18"),
    ("ddpg", 47, "none: stopped after 12 h", "", ""),
)
# The report's tables 2 and 5: the values Optuna chose (canter's names, the report's values), and the reward of the
# best trial during tuning.
REPORT_TUNE: dict[str, tuple[str, dict[str, Any]]] = {
    "ppo": (
        "315.19",
        {
            "ppo.n_steps": 512,
            "ppo.lr": 1.8451057856134118e-4,
            "ppo.epochs": 5,
            "ppo.minibatch_size": 32,
            "ppo.gamma": 0.99,
            "ppo.gae_lambda": 0.99,
            "ppo.ent_coef": 6.243275791612454e-06,
            "ppo.clip": 0.2,
            "ppo.max_grad_norm": 0.6,
            "ppo.vf_coef": 0.38040715408689363,
            "ppo.target_kl": 0.1200865249782578,
        },
    ),
    "ddpg": (
        "-3.91",
        {
            "ddpg.actor_lr": 2.7076207562598673e-05,
            "ddpg.critic_lr": 2.7076207562598673e-05,
            "ddpg.batch_size": 512,
            "ddpg.buffer_size": 1_000_000,
            "ddpg.gamma": 0.98,
            "ddpg.tau": 0.001,
            "ddpg.train_freq": 16,
            "ddpg.gradient_steps": 16,
            "ddpg.noise": "gaussian",
            "ddpg.noise_std": 0.8906602621112266,
        },
    ),
}
# The two PPO keys whose SB3 value means something else in canter, with the factor the preset and the search space
# apply: SB3's value loss is the plain MSE, canter's 0.5 * MSE (canter.algos.ppo.losses), so vf_coef is doubled;
# SB3 stops an epoch at the first minibatch whose approx KL exceeds 1.5 * target_kl, canter stops after an epoch whose
# last minibatch's approx KL exceeds ppo.target_kl (canter.algos.ppo.learner), so target_kl is multiplied by 1.5.
TRANSLATED = {"ppo.vf_coef": 2.0, "ppo.target_kl": 1.5}
MARKERS = {
    "commands": ("<!-- report002-commands -->\n", "<!-- /report002-commands -->"),
    "hopper": ("<!-- report002-hopper -->\n", "<!-- /report002-hopper -->"),
    "walker": ("<!-- report002-walker -->\n", "<!-- /report002-walker -->"),
    "tune": ("<!-- report002-tune -->\n", "<!-- /report002-tune -->"),
}


def space_file(algo: str) -> Path:
    return PAGE / f"search_space_{algo}.toml"


# ---------------------------------------------------------------------------------------------------- the commands


def sweep_args() -> list[str]:
    runs = [str(cell.run_dir(Path(WORK) / HOPPER.name, seed)) for cell in HOPPER.cells() for seed in SEEDS]
    vary = f"body_mass:torso={','.join(TORSO_SCALES)}"
    return ["eval", *runs, "--vary", vary, "--episodes", str(TORSO_EPISODES), "--out", str(PAGE_PATH / SWEEP.name)]


def walker_name(algo: str, seed: int) -> str:
    return f"{WALKER}__{algo}__s{seed}"


def walker_args(algo: str, seed: int) -> list[str]:
    preset = WALKER_PRESETS[algo]
    return [WALKER, "--algo", algo, "--preset", preset, "--seed", str(seed), "--total-steps", WALKER_STEPS]


def walker_train_args(algo: str, seed: int) -> list[str]:
    return [*walker_args(algo, seed), "--stop-at-return", "300"]


def walker_command(algo: str, seed: int, folder: str = "", sets: tuple[str, ...] = ()) -> str:
    """The train command as a person would type it: run.py adds --out-dir (timed_train), so the shown command names
    the same folder, which the page's archive is copied from."""
    out = f"{WORK}/{folder}{walker_name(algo, seed)}"
    return "canter train " + " ".join([*walker_train_args(algo, seed), *sets, "--out-dir", out])


def tune_args(algo: str) -> list[str]:
    preset, space = WALKER_PRESETS[algo], str(PAGE_PATH / space_file(algo).name)
    return ["tune", WALKER, "--algo", algo, "--preset", preset, "--space", space, *TUNE_SETTINGS, "--out-dir", WORK]


def curves_args(algo: str) -> list[str]:
    runs = [str(PAGE_PATH / "runs" / walker_name(algo, seed)) for seed in SEEDS]
    return ["plot", *runs, "--smooth", "50", "--metrics", CURVES[algo], "--out", str(PAGE_PATH / curves(algo).name)]


def curves(algo: str) -> Path:
    return PAGE / f"curves_{algo}.png"


def tune_archive(algo: str) -> Path:
    return PAGE / "runs" / f"tune-{algo}"


def run_hopper() -> None:
    run_grid(PAGE, HOPPER, ROOT / WORK)


def run_sweep() -> None:
    if SWEEP.with_suffix(".json").is_file():
        print("torso sweep: archived already", flush=True)
        return
    print(f"torso sweep: $ canter {' '.join(sweep_args())}", flush=True)
    subprocess.run([*canter_command(), *sweep_args()], check=True, cwd=ROOT)


def run_walker(algo: str) -> None:
    for seed in SEEDS:
        timed_train(PAGE, walker_name(algo, seed), walker_train_args(algo, seed), ROOT / WORK, WALKER_EPISODES)
    # Asked again rather than taken from the calls: a seed that another page command trained was skipped here, and
    # whichever command ends last draws the curves.
    if all(archived(PAGE, walker_name(algo, seed)) for seed in SEEDS):
        subprocess.run([*canter_command(), *curves_args(algo)], check=True, cwd=ROOT)


def run_tune(algo: str) -> None:
    if all((tune_archive(algo) / f).is_file() for f in TUNE_FILES):
        print(f"tune-{algo}: archived already", flush=True)
        return
    if out_of_time(f"tune-{algo}"):
        return
    print(f"tune-{algo}: $ canter {' '.join(tune_args(algo))}", flush=True)
    code, stopped = run_to_deadline([*canter_command(), *tune_args(algo)], cwd=ROOT)
    if stopped:  # the study is kept in its SQLite file; the trial in flight is failed and asked again
        print(f"tune-{algo}: stopped at --max-minutes; the same command carries the study on", flush=True)
        return
    if code != 0:
        raise SystemExit(f"tune-{algo}: canter tune exited {code}")
    tune_archive(algo).mkdir(parents=True, exist_ok=True)
    for f in TUNE_FILES:
        shutil.copyfile(ROOT / WORK / f"{WALKER}__{algo}" / f, tune_archive(algo) / f)


@dataclass(frozen=True)
class Step:
    run: Callable[[], None]
    commands: list[str]  # as a person would type them
    seconds: float  # estimated wall time


STEPS = {
    "hopper-trpo": Step(run_hopper, [HOPPER.command(WORK)], HOPPER.env_steps() / SPS["hopper-trpo"]),
    "torso-sweep": Step(run_sweep, ["canter " + " ".join(sweep_args())], SWEEP_SECONDS),
}
for _algo in WALKER_PRESETS:
    STEPS[f"walker-{_algo}"] = Step(
        partial(run_walker, _algo),
        [walker_command(_algo, seed) for seed in SEEDS] + ["canter " + " ".join(curves_args(_algo))],
        len(SEEDS) * float(WALKER_STEPS) / SPS[_algo],
    )
for _algo in WALKER_PRESETS:
    STEPS[f"tune-{_algo}"] = Step(
        partial(run_tune, _algo),
        ["canter " + " ".join(tune_args(_algo))],
        TUNE_TRIALS * (float(TUNE_STEPS) / SPS[_algo] + TRIAL_OVERHEAD_SECONDS),
    )


# ------------------------------------------------------------------------------------------------------ the tables


def _duration(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h" if seconds >= 5400 else f"{seconds / 60:.0f} min"


def _archived(name: str) -> bool:
    if name == "hopper-trpo":
        return all(cell_result(PAGE, HOPPER, cell) is not None for cell in HOPPER.cells())
    if name == "torso-sweep":
        return SWEEP.with_suffix(".json").is_file()
    if name.startswith("walker-"):
        return all(archived(PAGE, walker_name(name.removeprefix("walker-"), s)) for s in SEEDS)
    return all((tune_archive(name.removeprefix("tune-")) / f).is_file() for f in TUNE_FILES)


def _trial_minutes(algo: str) -> tuple[int, float]:
    """The study's complete trials and their minutes, summed from summary.md (pruned and failed trials are not timed
    there)."""
    rows = [line.split("|")[1:-1] for line in (tune_archive(algo) / "summary.md").read_text().splitlines()]
    rows = [[cell.strip() for cell in row] for row in rows if row]
    column = rows[0].index("minutes")
    return len(rows) - 2, sum(float(row[column]) for row in rows[2:])


def archived_wall(name: str) -> str:
    """What an archived step took, as far as its archived files time it."""
    if name == "hopper-trpo":
        [cell] = HOPPER.cells()
        result = cell_result(PAGE, HOPPER, cell)
        return f"{result['wall_minutes']:.0f} min (one process)" if result else ""
    if name.startswith("walker-"):
        runs = [archived(PAGE, walker_name(name.removeprefix("walker-"), seed)) for seed in SEEDS]
        total = sum(run["timing"]["wall_seconds"] for run in runs if run)
        return f"{_duration(total)} (the seeds' `timing.json`, summed)"
    if name.startswith("tune-"):
        trials, minutes = _trial_minutes(name.removeprefix("tune-"))
        return f"{minutes:.0f} min for its {trials} complete trials (`summary.md`)"
    return "not timed"


def commands_table() -> str:
    lines = ["| step | command | estimated wall | archived |", "|---|---|---:|---|"]
    for name, step in STEPS.items():
        shown = "<br>".join(f"`{c}`" for c in step.commands)
        done = f"yes, {archived_wall(name)}" if _archived(name) else "no"
        lines.append(f"| `{name}` | {shown} | {_duration(step.seconds)} | {done} |")
    total = sum(step.seconds for step in STEPS.values())
    lines.append(f"| all | `python {PAGE_PATH}/run.py` | {_duration(total)} | |")
    return "\n".join(lines)


def hopper_text() -> str:
    lines = [
        f"| who | seeds | {EVAL_HEADER} | per seed | train return | wall |",
        "|---|---|---:|---|---:|---:|",
        "| report: sb3-contrib TRPO, 1M steps, 3 models | | no number in the text (its Figure 1) | | | |",
    ]
    [cell] = HOPPER.cells()
    result = cell_result(PAGE, HOPPER, cell)
    seeds = ",".join(map(str, SEEDS))
    if result is None:
        lines.append(f"| canter trpo, `report002-hopper-trpo` | {seeds} | not run yet (`hopper-trpo`) | | | |")
    else:
        per_seed = ", ".join(f"{r['eval_mean']:,.0f}" for r in result["runs"])
        lines.append(
            f"| canter trpo, `report002-hopper-trpo` | {seeds} | {eval_text(result)} | {per_seed} | "
            f"{result['train_return']:,.0f} | "
            f"{result['wall_minutes']:.0f} min |"
        )
    path = SWEEP.with_suffix(".json")
    episodes = json.loads(path.read_text())["episodes"] if path.is_file() else TORSO_EPISODES
    lines += ["", f"Torso mass (`canter eval --vary`, {episodes} deterministic episodes per mass):", ""]
    if not path.is_file():
        header = "| torso mass | " + " | ".join(f"seed {s}" for s in SEEDS) + " |"
        lines += [header, "|---" * (len(SEEDS) + 1) + "|"]
        lines += [f"| {scale}× | not run yet (`torso-sweep`) |" + " |" * (len(SEEDS) - 1) for scale in TORSO_SCALES]
        return "\n".join(lines)
    sweep = json.loads(path.read_text())
    original = float(sweep["original"])  # the torso's mass in the model, kg
    runs = sweep["runs"]
    header = "| torso mass | " + " | ".join(r["run"].rsplit("__", 1)[-1].replace("s", "seed ") for r in runs)
    lines += [header + " | mean |", "|---" + "|---:" * (len(runs) + 1) + "|"]
    for i, point in enumerate(runs[0]["points"]):
        values = [r["points"][i]["return_mean"] for r in runs]
        cells = " | ".join(f"{v:,.0f} ± {r['points'][i]['return_std']:,.0f}" for v, r in zip(values, runs))
        mass = f"{point['scale']:g}× ({point['scale'] * original:.2f} kg)"
        lines.append(f"| {mass} | {cells} | {sum(values) / len(values):,.0f} |")
    lines += ["", f"![torso mass sweep]({SWEEP.name})"]
    return "\n".join(lines)


def _clock(seconds: float) -> str:
    minutes, secs = divmod(round(seconds), 60)
    return f"{minutes // 60}:{minutes % 60:02d}:{secs:02d}"


def walker_row(algo: str, seed: int, folder: str = "") -> str:
    run = archived(PAGE, folder + walker_name(algo, seed))
    if run is None:
        return f"| {algo} | {seed} | not run yet (`walker-{algo}`) | | | | |"
    summary, evaluation = run["summary"], run["eval"]
    reached = summary["stop_reason"] == "stop_at_return"
    steps = f"{summary['global_step'] / 1e6:.2f}M"
    stop = f"**300 reached** at {steps} steps" if reached else f"not reached in {steps} steps"
    lengths = evaluation["lengths"]
    return (
        f"| {algo} | {seed} | {stop} | {_clock(run['timing']['wall_seconds'])}{load_text(run['timing'])} | "
        f"{summary['recent_return']:,.1f} | "
        f"{evaluation['return_mean']:,.1f} ({evaluation['return_std']:,.1f}) | {sum(lengths) / len(lengths):,.1f} |"
    )


def walker_seeds_row(algo: str, folder: str = "") -> list[str]:
    """The seeds together, once all are archived: eval mean ± std over seeds (`eval_text`)."""
    runs = [archived(PAGE, folder + walker_name(algo, seed)) for seed in SEEDS]
    if not all(runs):
        return []
    evals = np.array([run["eval"]["return_mean"] for run in runs if run])
    train = np.mean([run["summary"]["recent_return"] for run in runs if run])
    result = {
        "return_mean": evals.mean(),
        "return_std": evals.std(),
        "mean_interval": aggregates(evals[:, None]).mean,
        "runs": runs,
    }
    return [f"| {algo} | {len(runs)} seeds | | | {train:,.1f} | {eval_text(result)} | |"]


def walker_text() -> str:
    lines = [
        "| algo | seed | stop | wall time to the stop (H:MM:SS) | train return (last 20) | eval return, mean (std); "
        "over seeds: mean ± std (ddof 0) | eval steps |",
        "|---|---|---|---:|---:|---:|---:|",
    ]
    for algo in WALKER_PRESETS:
        for seed in SEEDS:
            lines.append(walker_row(algo, seed))
        lines += walker_seeds_row(algo)
    images = [f"![{algo} curves]({curves(algo).name})" for algo in WALKER_PRESETS if curves(algo).is_file()]
    if images:
        lines += ["", *images]
    first = [walker_row("ppo", seed, FIRST_ATTEMPT + "/") for seed in SEEDS] + walker_seeds_row(
        "ppo", FIRST_ATTEMPT + "/"
    )
    lines += [
        "",
        f"PPO's first attempt, with canter's observation and reward normalization on (archived in "
        f"[`runs/{FIRST_ATTEMPT}/`](runs/{FIRST_ATTEMPT}/), curves in [{FIRST_CURVES}]({FIRST_CURVES})). It ran "
        f"before the preset turned reward normalization off, so today it takes `--set {FIRST_ATTEMPT_SET}` (its "
        "archived config.toml differs from the rerun's in `normalize_reward` alone):",
        "",
        "```",
        *(walker_command("ppo", seed, FIRST_ATTEMPT + "/", ("--set", FIRST_ATTEMPT_SET)) for seed in SEEDS),
        "```",
        "",
        *lines[:2],
        *first,
    ]
    lines += [
        "",
        "Wall times are whole `canter train` processes on this page's 2-core machine. Where other work shared the "
        "cores, the time says so: the cores other processes took while it trained (measured from the machine's and "
        "the process's CPU time), or, for runs timed before that was measured, the 1-minute load average as it "
        "started, which also counts the seed that had just ended before it.",
        "",
        "The report's table 6, beside it (SB3, 4 envs, 3 seeds in parallel on an A40 node; evaluation over 100 "
        "episodes with env seed 1; training time to the end of training):",
        "",
        "| algo | seed | eval return, mean (std) | eval steps | training time |",
        "|---|---|---:|---:|---:|",
        *(f"| {algo} | {seed} | {ret} | {steps} | {time} |" for algo, seed, ret, steps, time in REPORT_WALKER),
    ]
    return "\n".join(lines)


def _value(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def _searched(param: Param) -> str:
    if param.same_as:
        return f"same as {param.same_as}"
    if param.choices:
        return ", ".join(map(_value, param.choices))
    return f"{'log-' if param.log else ''}uniform({_value(param.low)}, {_value(param.high)})"


def _best_trial(best_toml: str) -> str:
    """The best trial's objective, from best.toml's header ('# objective -130.15: deterministic evaluation ...')."""
    for line in best_toml.splitlines():
        if line.startswith("# objective "):
            return line.removeprefix("# objective ").partition(":")[0]
    raise SystemExit("best.toml has no '# objective' line; canter tune's header changed")


def tune_text() -> str:
    parts = []
    for algo, (reward, chosen) in REPORT_TUNE.items():
        space = load_space(space_file(algo), algo)
        folder = tune_archive(algo)
        ran = all((folder / f).is_file() for f in TUNE_FILES)
        best = tomllib.loads((folder / "best.toml").read_text()) if ran else {}
        score = _best_trial((folder / "best.toml").read_text()) if ran else "not run yet"
        lines = [
            f"**{algo}** (`tune-{algo}`): best trial's return during tuning: report {reward} (best of 50 trials), "
            f"canter {score}" + (f" (best of {TUNE_TRIALS} trials)" if ran else "") + ".",
            "",
            f"| key | searched over | report's choice | canter's best ({TUNE_TRIALS} trials) |",
            "|---|---|---:|---:|",
        ]
        for param in space.params:
            section, _, key = param.key.partition(".")
            mine = _value(best[section][key]) if ran else "not run yet"
            theirs = _value(chosen[param.key])
            if param.key in TRANSLATED:
                factor = TRANSLATED[param.key]
                theirs += f" (× {factor:g} = {_value(chosen[param.key] * factor)})"
            lines.append(f"| `{param.key}` | {_searched(param)} | {theirs} | {mine} |")
        if any(param.key in TRANSLATED for param in space.params):
            lines += [
                "",
                "`ppo.vf_coef` and `ppo.target_kl` mean something else in canter than in SB3, so the preset and the "
                "search space translate the report's values and ranges (the ranges above are canter's; table 1's are "
                "uniform(0, 1) and log-uniform(0.001, 0.3)); the translated value is in brackets. SB3's value loss is "
                "the plain mean squared error and canter's is half of it "
                "([`losses.py`](../../../src/canter/algos/ppo/losses.py)), so vf_coef is doubled for the same "
                "gradient. SB3 stops an update's epochs at the first minibatch whose approximate KL exceeds 1.5 × "
                "target_kl; canter stops them after an epoch whose last minibatch's approximate KL exceeds target_kl "
                "([`learner.py`](../../../src/canter/algos/ppo/learner.py)), so target_kl is multiplied by 1.5. "
                "canter's best is in canter's terms.",
            ]
        parts.append("\n".join(lines))
    return "\n\n".join(parts)


def main() -> int:
    blocks = [
        (MARKERS["commands"], commands_table),
        (MARKERS["hopper"], hopper_text),
        (MARKERS["walker"], walker_text),
        (MARKERS["tune"], tune_text),
    ]
    return page_main(__doc__ or "", PAGE, blocks, {name: step.run for name, step in STEPS.items()})


if __name__ == "__main__":
    sys.exit(main())
