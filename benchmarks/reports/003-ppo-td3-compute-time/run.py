"""Report 003 (PPO vs TD3 on HalfCheetah, Hopper and Walker2d, with compute time) redone with canter.

    python benchmarks/reports/003-ppo-td3-compute-time/run.py            # train what is not archived, then write
    python benchmarks/reports/003-ppo-td3-compute-time/run.py --write    # only rewrite the page's table
    python benchmarks/reports/003-ppo-td3-compute-time/run.py --check    # exit 1 if the table is not the archive's

PPO is trained here, one whole process per env and preset, on the report's v4 envs with seed 100 (chosen before the
runs; the report's seed number means nothing to canter's generators). TD3 is not trained again: its rows are the
1M-step td3 runs of benchmarks/results/offpolicy-1m (v5, seeds 0-2, CleanRL's td3 settings, as the report used).
"""

from __future__ import annotations

import sys
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

PAGE = Path(__file__).resolve().parent
sys.path.insert(0, str(PAGE.parent))  # timed.py
sys.path.insert(0, str(PAGE.parents[1]))  # archive.py
from archive import ROOT, finished_runs  # noqa: E402
from timed import archived, page_main, timed_train, wall_text  # noqa: E402

ENVS = ("HalfCheetah", "Hopper", "Walker2d")
SEED = 100
STEPS = "1e6"
PPO_PRESETS = ("cleanrl", "fast")  # the report's settings (CleanRL's ppo_continuous_action), and canter's default
OFFPOLICY = ROOT / "benchmarks" / "results" / "offpolicy-1m"
MARKERS = ("<!-- report003-table -->\n", "<!-- /report003-table -->")
# The report's own figures (its slides "Results - <env>"): compute time, and reward (CleanRL's logged training return).
REPORT = {
    "HalfCheetah": {"ppo_minutes": 22.71, "td3_hours": 2.403, "ppo": 3786, "td3": 8855},
    "Hopper": {"ppo_minutes": 19.64, "td3_hours": 2.341, "ppo": 1784, "td3": 1978},
    "Walker2d": {"ppo_minutes": 19.28, "td3_hours": 3.265, "ppo": 3549, "td3": 4552},
}


def run_name(env: str, preset: str) -> str:
    return f"{env}-v4__ppo-{preset}__s{SEED}"


def train(work: Path) -> None:
    for env in ENVS:
        for preset in PPO_PRESETS:
            args = [f"{env}-v4", "--algo", "ppo", "--preset", preset, "--seed", str(SEED), "--total-steps", STEPS]
            timed_train(PAGE, run_name(env, preset), args, work)


def _hours(seconds: float) -> str:
    return f"{seconds / 3600:.2f} h"


def _ppo_cell(run: dict[str, Any] | None) -> tuple[str, str]:
    if run is None:
        return "not run yet", "not run yet"
    reward = f"{run['summary']['recent_return']:,.0f} (eval {run['eval']['return_mean']:,.0f})"
    return wall_text(run), reward


def table() -> str:
    td3 = finished_runs(OFFPOLICY, ("td3",), 1_000_000)
    lines = [
        "| env | who | PPO compute time | TD3 compute time | PPO reward | TD3 reward |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for env in ENVS:
        mine = REPORT[env]
        lines.append(
            f"| {env} | report (CleanRL, laptop, v4, 1 seed) | {mine['ppo_minutes']:.2f} min | "
            f"{mine['td3_hours']:.3f} h | {mine['ppo']:,} | {mine['td3']:,} |"
        )
        for preset in PPO_PRESETS:
            wall, reward = _ppo_cell(archived(PAGE, run_name(env, preset)))
            who = "canter, the report's settings (`--preset cleanrl`)" if preset == "cleanrl" else "canter default"
            lines.append(f"| {env} | {who}, v4, seed {SEED} | {wall} | | {reward} | |")
        runs = td3.get(("td3", f"{env}-v5"), [])[:3]
        if runs:
            walls = [r["wall_seconds"] for r in runs]
            train_return = np.mean([r["summary"]["recent_return"] for r in runs])
            evaluation = np.mean([r["eval_mean"] for r in runs])
            lines.append(
                f"| {env} | canter td3 (CleanRL's settings), v5, seeds 0-2 | | {_hours(float(np.mean(walls)))} "
                f"({_hours(min(walls))} to {_hours(max(walls))}) | | "
                f"{train_return:,.0f} (eval {evaluation:,.0f}) |"
            )
    return "\n".join(lines)


def main() -> int:
    return page_main(__doc__ or "", PAGE, [(MARKERS, table)], {"train": partial(train, ROOT / "runs" / "report003")})


if __name__ == "__main__":
    sys.exit(main())
