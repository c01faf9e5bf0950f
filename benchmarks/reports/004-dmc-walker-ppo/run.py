"""Report 004 (DM Control's walker, PPO with tanh, 750 epochs of one 1000-step trajectory) redone with canter.

    python benchmarks/reports/004-dmc-walker-ppo/run.py            # train what is not archived, plot, film, write
    python benchmarks/reports/004-dmc-walker-ppo/run.py --write    # only rewrite the page's table
    python benchmarks/reports/004-dmc-walker-ppo/run.py --check    # exit 1 if the table is not the archive's

Two runs on WalkerWalk-v1 (EnvPool's DM Control walker-walk: 1000-step episodes, rewards in [0, 1]), seed 100,
chosen before the runs: the report's own setup (`--preset report004-walker`, 750k steps) and canter's default preset
at 1M steps. Each gets its training curve (`canter plot`), a 10-episode deterministic evaluation and a video.
Two variants of the report's setup on the same seed, chosen before their runs, test its claims: ReLU instead of
tanh, and no advantage normalization; with them, the report's setup again on their code (`--only variants`).

The search for settings that beat CleanRL's published figures runs on seeds 0 and 1 only, never on the reported
seeds: `canter bench` grids of 2M steps (`--only tuning`), one per preset, archived under runs/tuning-<preset>/. The
settings chosen from it then run on seeds 100-102 at CleanRL's 8M steps (`--only chosen`). canter's sac, untuned, runs
on seeds 109-111 at 500k steps (`--only offpolicy`).
"""

from __future__ import annotations

import math
import statistics
import subprocess
import sys
from collections import deque
from collections.abc import Sequence
from functools import partial
from pathlib import Path
from typing import Any

from canter.training.logger import read_table, run_history
from canter.training.run_folder import metrics_file
from canter.training.seed_run import RECENT_EPISODES

PAGE = Path(__file__).resolve().parent
sys.path.insert(0, str(PAGE.parent))  # timed.py, grids.py
sys.path.insert(0, str(PAGE.parents[1]))  # archive.py
from archive import ROOT  # noqa: E402
from grids import EVAL_HEADER, Grid, cell_result, eval_text, label, run_grid  # noqa: E402
from timed import archived, canter_command, page_main, plot_and_film, timed_train, wall_text  # noqa: E402

ENV = "WalkerWalk-v1"
SEED = 100
RUNS = {  # name -> (who, canter train arguments)
    f"{ENV}__report004__s{SEED}": ("the report's setup (`report004-walker`)", ["--preset", "report004-walker"]),
    f"{ENV}__fast__s{SEED}": ("canter's default preset", ["--preset", "fast", "--total-steps", "1e6"]),
}
# The report's one comparison ("tanh ... seemed to lead to better results" than ReLU) and the step it calls crucial
# (normalized advantages), each undone on exactly the report's setup and its seed. Both chosen before their runs,
# with the same seed (100) as the report's-setup run above (`--only variants`). The third, the report's setup itself
# again, was added after those two had run: a rerun of that setup here (5cc8943, with uncommitted edits under src/
# by then; not archived) did not repeat the archived run (trained at 4a3cd17 on another machine; its first
# episode's return already differs, and its training return was 294 against 265, evaluation 347). 4a3cd17 run here
# gives the rerun's numbers, so the machine, not the code, moved it; the variants need a baseline from this one.
VARIANTS = {
    f"{ENV}__report004-rerun__s{SEED}": (
        "the report's setup again, on the variants' code",
        ["--preset", "report004-walker"],
    ),
    f"{ENV}__report004-relu__s{SEED}": (
        "the report's setup with ReLU instead of tanh",
        ["--preset", "report004-walker", "--set", "net.activation=relu"],
    ),
    f"{ENV}__report004-noadvnorm__s{SEED}": (
        "the report's setup without advantage normalization",
        ["--preset", "report004-walker", "--set", "ppo.norm_adv=false"],
    ),
}
MARKERS = ("<!-- report004-table -->\n", "<!-- /report004-table -->")
TUNING_MARKERS = ("<!-- report004-tuning -->\n", "<!-- /report004-tuning -->")
WORK = ROOT / "runs" / "report004"
# Tuning seeds, never reported as results; 2M steps, a quarter of CleanRL's budget, to rank settings cheaply.
TUNING_SEEDS, TUNING_STEPS = (0, 1), 2_000_000
TUNING = (
    Grid("tuning-report004-walker", ENV, ("ppo", "rpo"), "report004-walker", TUNING_SEEDS, TUNING_STEPS),
    Grid("tuning-cleanrl", ENV, ("rpo",), "cleanrl", TUNING_SEEDS, TUNING_STEPS),  # CleanRL's own RPO recipe
    Grid("tuning-fast", ENV, ("rpo",), "fast", TUNING_SEEDS, TUNING_STEPS),
    # Second round, after CleanRL's RPO recipe at 8M fell short of its 787 (723 on seeds 100-102): wider networks,
    # which PPO on DM Control often uses. A cell that beats that recipe's 610 here goes to 8M on seeds 103-105.
    Grid(
        "tuning-cleanrl-256", ENV, ("ppo", "rpo"), "cleanrl", TUNING_SEEDS, TUNING_STEPS, sets=("net.hidden=256,256",)
    ),
    # Third round, after that pick tied CleanRL's RPO at 8M on CleanRL's own measure (training return 787 on seeds
    # 103-105): smaller RPO shifts than the recipe's 0.5. That measure scores the sampled actions, and the recipe's
    # policy entropy climbs throughout, which a smaller shift may curb. A cell whose training return here beats
    # alpha 0.5's 784 (second round) goes to 8M on seeds 106-108.
    Grid(
        "tuning-cleanrl-256-alpha",
        ENV,
        ("rpo",),
        "cleanrl",
        TUNING_SEEDS,
        TUNING_STEPS,
        (("rpo.alpha", ("0.1", "0.3")),),
        ("net.hidden=256,256",),
    ),
    # Fourth round: the third curbed the entropy (3.6 and 10 nats at 2M against 13.5 with alpha 0.5) and lowered the
    # training return with it (465 and 589 against 784), so larger shifts. The same rule as the third round's.
    Grid(
        "tuning-cleanrl-256-alpha-up",
        ENV,
        ("rpo",),
        "cleanrl",
        TUNING_SEEDS,
        TUNING_STEPS,
        (("rpo.alpha", ("0.7", "1.0")),),
        ("net.hidden=256,256",),
    ),
    # Fifth round: of the shifts tried, the recipe's 0.5 trains best, and the one lever that has helped so far is the
    # network (64-64 to 256-256 raised the training return from 521 to 784). So wider and deeper networks with
    # alpha 0.5. The same rule: a cell whose training return here beats 784 goes to 8M on seeds 106-108; if both do,
    # only the higher (an 8M run of these networks takes about 5 hours here). Added while 256-256-256 ran, after
    # 512-512 had beaten 784.
    Grid(
        "tuning-cleanrl-net",
        ENV,
        ("rpo",),
        "cleanrl",
        TUNING_SEEDS,
        TUNING_STEPS,
        (("net.hidden", ("512-512", "256-256-256")),),
    ),
)
# The tuning's best, chosen before these runs: CleanRL's RPO recipe at CleanRL's budget, on the reported seeds.
CHOSEN = Grid("rpo-cleanrl-8m", ENV, ("rpo",), "cleanrl", (100, 101, 102), 8_000_000)
# The second round's pick by its rule (rpo with 256-256 networks: 747 on seeds 0-1 against the recipe's 610), on
# seeds not seen before.
CHOSEN_WIDE = Grid(
    "rpo-cleanrl-256-8m", ENV, ("rpo",), "cleanrl", (103, 104, 105), 8_000_000, sets=("net.hidden=256,256",)
)
# The fifth round's pick by its rule (512-512 networks: training return 814 on seeds 0-1 against 784; 256-256-256
# gave 261), on seeds not seen before.
CHOSEN_WIDER = Grid(
    "rpo-cleanrl-512-8m", ENV, ("rpo",), "cleanrl", (106, 107, 108), 8_000_000, sets=("net.hidden=512,512",)
)
CHOSEN_GRIDS = (CHOSEN, CHOSEN_WIDE, CHOSEN_WIDER)
CHOSEN_MARKERS = ("<!-- report004-chosen -->\n", "<!-- /report004-chosen -->")
# Not PPO: canter's sac with its default preset (CleanRL's SAC settings), untuned, at DM Control's common 500k-step
# budget, on seeds not seen before. The rule, set before it ran: it beats CleanRL's RPO if its mean training return
# exceeds 787 by two standard errors of the difference (CleanRL's 126 over sqrt(10), and its own std over sqrt(3)).
OFFPOLICY = (Grid("sac-500k", ENV, ("sac",), "fast", (109, 110, 111), 500_000),)
# CleanRL's RPO on walker-walk at 8M steps: training return, mean and std over its seeds, and their number.
CLEANRL_RPO = (787.0, 126.0, 10)
OFFPOLICY_MARKERS = ("<!-- report004-offpolicy -->\n", "<!-- /report004-offpolicy -->")
# CleanRL's PPO and RPO on dm_control walker-walk at 8M steps (docs/rl-algorithms/rpo.md, dm_control table: training
# return, mean ± std over 10 seeds).
PUBLISHED = "CleanRL at 8M steps: PPO 306 ± 92, RPO 787 ± 126 (training return, mean ± std over 10 seeds)"


def train(work: Path, runs: dict[str, tuple[str, list[str]]]) -> None:
    for name, (_, args) in runs.items():
        if timed_train(PAGE, name, [ENV, "--algo", "ppo", "--seed", str(SEED), *args], work):
            plot_and_film(PAGE, name, work)


def run_grids(grids: tuple[Grid, ...]) -> None:
    for grid in grids:
        run_grid(PAGE, grid, WORK)


def film_first_seed(grid: Grid) -> None:
    """One episode of the grid's first seed, filmed from its checkpoint in the bench folder (`canter video`), as
    <page>/<env>__<algo>__s<seed>.mp4 once that seed is archived, unless the file exists."""
    name = f"{ENV}__{grid.algos[0]}__s{grid.seeds[0]}"
    out = PAGE / f"{name}.mp4"
    if out.is_file() or not (PAGE / "runs" / grid.name / name).is_dir():
        return
    run_dir = WORK / grid.name / name
    if not run_dir.is_dir():
        raise SystemExit(f"{name}: its run folder {run_dir} is gone; train it again to film it")
    command = [*canter_command(), "video", str(run_dir), "--episodes", "1", "--out", str(out)]
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)


def run_offpolicy() -> None:
    run_grids(OFFPOLICY)
    for grid in OFFPOLICY:
        film_first_seed(grid)


def bar_to_beat(returns: Sequence[float], published: tuple[float, float, int]) -> tuple[float, float]:
    """(the mean of `returns`, the bar it must exceed to beat `published`): the published mean plus two standard
    errors of the difference, from the published std over the root of its seed count and the returns' own sample
    std over the root of theirs."""
    mean, std, seeds = published
    spread = statistics.stdev(returns) if len(returns) > 1 else 0.0
    return statistics.fmean(returns), mean + 2 * math.sqrt(std**2 / seeds + spread**2 / len(returns))


def first_crossing(
    rows: Sequence[tuple[float, int, float, float]], bar: float, window: int = RECENT_EPISODES
) -> tuple[float, float] | None:
    """The first (env step, wall seconds) at which the mean return of the last `window` episodes reaches `bar`, from
    rows of (env step, episodes ended in the row, their mean return, wall seconds); a row's episodes count at its
    mean, which is exact where each row ends at most one episode (one env, 1000-step episodes, 1000-step rows)."""
    recent: deque[float] = deque(maxlen=window)
    for step, episodes, mean_return, wall in rows:
        recent.extend([mean_return] * episodes)
        if len(recent) == window and statistics.fmean(recent) >= bar:
            return step, wall
    return None


def training_rows(run_dir: Path) -> list[tuple[float, int, float, float]]:
    """(env step, episodes, mean return, wall seconds from the run's start over all its sessions) per metrics row
    that ended an episode."""
    table = read_table(metrics_file(run_dir))
    history = run_history(table)
    episodes, returns = (table.column(name)[history.rows] for name in ("episodes", "episodic_return"))
    return [
        (float(step), int(count), float(mean_return), float(wall))
        for step, count, mean_return, wall in zip(history.global_step, episodes, returns, history.wall_seconds)
        if count > 0 and not math.isnan(mean_return)
    ]


def offpolicy_text() -> str:
    """The off-policy table, then the rule's verdict against CleanRL's RPO and when each seed's training return
    first reached 787."""
    lines = [grids_table(OFFPOLICY, "offpolicy")]
    target = CLEANRL_RPO[0]
    for grid in OFFPOLICY:
        cell = grid.cells()[0]
        result = cell_result(PAGE, grid, cell)
        if result is None:
            continue
        returns = [r["summary"]["recent_return"] for r in result["runs"]]
        mean, bar = bar_to_beat(returns, CLEANRL_RPO)
        verdict = "beats" if mean > bar else "does not beat"
        crossings = []
        for record in result["runs"]:
            crossing = first_crossing(training_rows(cell.run_dir(PAGE / "runs" / grid.name, record["seed"])), target)
            crossings.append(
                f"seed {record['seed']} never"
                if crossing is None
                else f"seed {record['seed']} at {crossing[0]:,.0f} steps ({crossing[1] / 60:.0f} min)"
            )
        per_seed = ", ".join(f"{r:,.0f}" for r in returns)
        lines.append(
            f"By the rule, `{grid.algos[0]}`'s mean training return **{mean:,.0f}** ({per_seed}) against a bar "
            f"of **{bar:,.0f}** ({target:.0f} plus two standard errors of the difference): it **{verdict}** "
            f"CleanRL's RPO. The mean of the last {RECENT_EPISODES} training episodes first reached {target:.0f}: "
            f"{'; '.join(crossings)}."
        )
    return "\n\n".join(lines)


def _row(name: str, who: str, run: dict[str, Any] | None) -> str:
    if run is None:
        return f"| {who} | not run yet | | | | |"
    steps = run["summary"]["global_step"]
    evaluation = f"{run['eval']['return_mean']:,.0f} ± {run['eval']['return_std']:,.0f}"
    return (
        f"| {who} | {steps:,} | {wall_text(run)} | {run['summary']['recent_return']:,.0f} | {evaluation} | "
        f"[curve]({name}.png), [video]({name}.mp4) |"
    )


def table() -> str:
    lines = [
        "| who | steps | wall time | training return (last 20 episodes) | eval (10 episodes, deterministic) | see |",
        "|---|---:|---:|---:|---:|---|",
        "| report (its own PPO after Spinning Up's, dm_control) | 750,000 | not given "
        "| its curve only, no figure in the text | not given | |",
    ]
    lines += [_row(name, who, archived(PAGE, name)) for name, (who, _) in (RUNS | VARIANTS).items()]
    return "\n".join(lines) + f"\n\nPublished: {PUBLISHED}."


def grids_table(grids: tuple[Grid, ...], step: str) -> str:
    """One row per cell of each grid (eval mean ± std over seeds, per seed, training return, wall), and the grids'
    commands."""
    lines = [
        f"| preset | cell | seeds | {EVAL_HEADER} | per seed | training return | wall | see |",
        "|---|---|---|---:|---|---:|---:|---|",
    ]
    for grid in grids:
        cells = grid.cells()
        for cell in cells:
            result = cell_result(PAGE, grid, cell)
            preset = " + ".join([f"`{grid.preset}`", *(f"`{item}`" for item in grid.sets)])
            who = f"| {preset} | {label(cell, cells)} | {','.join(map(str, grid.seeds))} |"
            if result is None:
                lines.append(f"{who} not run yet (`{step}`) | | | | |")
                continue
            per_seed = ", ".join(f"{r['eval_mean']:,.0f}" for r in result["runs"])
            # A cell whose seeds trained apart (sac's, one process each) has the bench's per-seed mean, not the
            # time of one process that trained them all, as the other rows; the row says which it is.
            wall = f"{result['wall_minutes']:.0f} min" + (
                f" per seed (mean of {len(result['runs'])} processes)" if result["per_seed"] else ""
            )
            lines.append(
                f"{who} {eval_text(result)} | {per_seed} | "
                f"{result['train_return']:,.0f} | {wall} | "
                f"[curves](runs/{grid.name}/plot_{ENV}.png) |"
            )
    commands = "\n".join(grid.command("runs/report004") for grid in grids)
    return "\n".join(lines) + f"\n\n```\n{commands}\n```"


def main() -> int:
    blocks = [
        (MARKERS, table),
        (TUNING_MARKERS, partial(grids_table, TUNING, "tuning")),
        (CHOSEN_MARKERS, partial(grids_table, CHOSEN_GRIDS, "chosen")),
        (OFFPOLICY_MARKERS, offpolicy_text),
    ]
    steps = {
        "train": partial(train, WORK, RUNS),
        "variants": partial(train, WORK, VARIANTS),
        "tuning": partial(run_grids, TUNING),
        "chosen": partial(run_grids, CHOSEN_GRIDS),
        "offpolicy": run_offpolicy,
    }
    return page_main(__doc__ or "", PAGE, blocks, steps)


if __name__ == "__main__":
    sys.exit(main())
