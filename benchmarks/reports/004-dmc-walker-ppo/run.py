"""Report 004 (DM Control's walker, PPO with tanh, 750 epochs of one 1000-step trajectory) redone with canter.

    python benchmarks/reports/004-dmc-walker-ppo/run.py            # train what is not archived, plot, film, write
    python benchmarks/reports/004-dmc-walker-ppo/run.py --write    # only rewrite the page's table
    python benchmarks/reports/004-dmc-walker-ppo/run.py --check    # exit 1 if the table is not the archive's

Two runs on WalkerWalk-v1 (EnvPool's DM Control walker-walk: 1000-step episodes, rewards in [0, 1]), seed 100,
chosen before the runs: the report's own setup (`--preset report004-walker`, 750k steps) and canter's default preset
at 1M steps. Each gets its training curve (`canter plot`), a 10-episode deterministic evaluation and a video.
"""

from __future__ import annotations

import sys
from functools import partial
from pathlib import Path
from typing import Any

PAGE = Path(__file__).resolve().parent
sys.path.insert(0, str(PAGE.parent))  # timed.py
sys.path.insert(0, str(PAGE.parents[1]))  # archive.py
from archive import ROOT  # noqa: E402
from timed import archived, page_main, plot_and_film, timed_train, wall_text  # noqa: E402

ENV = "WalkerWalk-v1"
SEED = 100
RUNS = {  # name -> (who, canter train arguments)
    f"{ENV}__report004__s{SEED}": ("the report's setup (`report004-walker`)", ["--preset", "report004-walker"]),
    f"{ENV}__fast__s{SEED}": ("canter's default preset", ["--preset", "fast", "--total-steps", "1e6"]),
}
MARKERS = ("<!-- report004-table -->\n", "<!-- /report004-table -->")
# CleanRL's PPO and RPO on dm_control walker-walk at 8M steps (docs/rl-algorithms/rpo.md, 10 seeds, training return).
PUBLISHED = "CleanRL at 8M steps: PPO 306, RPO 787"


def train(work: Path) -> None:
    for name, (_, args) in RUNS.items():
        timed_train(PAGE, name, [ENV, "--algo", "ppo", "--seed", str(SEED), *args], work)
        plot_and_film(PAGE, name, work)


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
    lines += [_row(name, who, archived(PAGE, name)) for name, (who, _) in RUNS.items()]
    return "\n".join(lines) + f"\n\nPublished: {PUBLISHED}."


def main() -> int:
    return page_main(__doc__ or "", PAGE, [(MARKERS, table)], {"train": partial(train, ROOT / "runs" / "report004")})


if __name__ == "__main__":
    sys.exit(main())
