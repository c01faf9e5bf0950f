"""Rebuild the on-policy score table of README.md and benchmarks/results/README.md from the archived runs.

The runs are those of two `canter bench` commands on seeds that no preset was tuned on, chosen before the runs
(SEEDS):

    canter bench --algos ppo,rpo,trpo --envs HalfCheetah-v5,Hopper-v5,Walker2d-v5 --seeds 100,101,102,103,104 \\
        --total-steps 1e6 --out runs/onpolicy-1m-heldout
    canter bench --algos ppo --envs Ant-v5,Humanoid-v5 --seeds 100,101,102,103,104 --total-steps 1e6 \\
        --out runs/reports-ppo-1m

Each finished run is archived as benchmarks/results/onpolicy-1m-heldout/<env>__<algo>__s<seed>/ (config.toml,
eval.json, metrics.csv, summary.json, versions.json; no checkpoints). This script copies them there from the
bench folder (`--collect`), writes the two tables between their marker comments, and the archive's own bench files
(results.md with its rliable statistics, results.csv, statistics.json and one curve per env):

    python benchmarks/onpolicy_tables.py --collect runs/onpolicy-1m-heldout runs/reports-ppo-1m   # archive, then write
    python benchmarks/onpolicy_tables.py            # rewrite the tables and bench files from the archive
    python benchmarks/onpolicy_tables.py --check    # exit 1 if any of them differs from what the archive gives
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # archive.py, when loaded from elsewhere (the tests)
from archive import ROOT, copy_run, finished_runs, read_text, replace_between, sync

from canter.orchestrate.bench_results import combine_records, plot_env, published_for, results_markdown

ARCHIVE = ROOT / "benchmarks" / "results" / "onpolicy-1m-heldout"
ALGOS = ("ppo", "rpo", "trpo")
ENVS = ("HalfCheetah-v5", "Hopper-v5", "Walker2d-v5", "Ant-v5", "Humanoid-v5")
BUDGET = 1_000_000
SEEDS = (100, 101, 102, 103, 104)  # chosen before the runs; no preset was tuned on them (README, "Tuning seeds")
README_MARKERS = ("<!-- score-table -->\n", "<!-- /score-table -->")
RESULTS_MARKERS = ("<!-- onpolicy-heldout-table -->\n", "<!-- /onpolicy-heldout-table -->")
FULL_LENGTH = 1000  # the v5 tasks' time limit


def collect(bench_dir: Path) -> list[str]:
    """Copy each finished run's files from a bench folder into the archive; returns the runs copied."""
    copied = []
    for algo in ALGOS:
        for env in ENVS:
            for seed in SEEDS:
                name = f"{env}__{algo}__s{seed}"
                if copy_run(bench_dir / name, ARCHIVE / name):
                    copied.append(name)
    return copied


def cells(found: dict[tuple[str, str], list[dict[str, Any]]]):
    """(algo, env, rows) in table order."""
    for algo in ALGOS:
        for env in ENVS:
            if found.get((algo, env)):
                yield algo, env, found[(algo, env)]


def full_length(rows: list[dict[str, Any]]) -> str:
    """How many evaluation episodes ran to the time limit, e.g. 48/50."""
    lengths = [n for r in rows for n in r["evaluation"]["lengths"]]
    return f"{sum(n >= FULL_LENGTH for n in lengths)}/{len(lengths)}"


def iqm_interval(returns: list[float]) -> str:
    from canter.use.statistics import aggregates

    return aggregates(np.asarray(returns, float)[:, None]).iqm.show(0, runs=len(returns))


def cell_result(algo: str, env: str, rows: list[dict[str, Any]]) -> dict[str, Any]:
    return combine_records(SimpleNamespace(name=f"{env}__{algo}", env_id=env, algo=algo, values=()), rows)


def readme_table(found: dict[tuple[str, str], list[dict[str, Any]]]) -> str:
    lines = [
        "| env | algo | return per seed | mean ± std | IQM [95% CI] | episodes of 1,000 steps | cell wall min "
        "| cell SPS | published (1M) |",
        "|---|---|---|---:|---:|---:|---:|---:|---|",
    ]
    for algo, env, rows in cells(found):
        returns = [r["eval_mean"] for r in rows]
        cell = cell_result(algo, env, rows)
        per_seed = ", ".join(f"{r['eval_mean']:,.0f}" for r in rows)
        lines.append(
            f"| {env} | {algo} | {per_seed} | **{np.mean(returns):,.0f}** ± {np.std(returns):,.0f} | "
            f"{iqm_interval(returns)} | {full_length(rows)} | {cell['wall_minutes']:.1f} | {cell['sps']:,.0f} | "
            f"{published_for(algo, env, BUDGET)} |"
        )
    return "\n".join(lines)


def results_table(found: dict[tuple[str, str], list[dict[str, Any]]]) -> str:
    """Per seed: the evaluation's mean ± std over its 10 episodes, its shortest episode, and the training return."""
    lines = [
        "| env | algo | seed | eval return (10 episodes, deterministic) | shortest episode | train return "
        "(last 20 eps) | commit |",
        "|---|---|---:|---:|---:|---:|---|",
    ]
    for algo, env, rows in cells(found):
        for r in rows:
            e, s = r["evaluation"], r["summary"]
            commit = _commit(r["folder"])
            lines.append(
                f"| {env} | {algo} | {r['seed']} | {e['mean']:,.0f} ± {e['std']:,.0f} | {min(e['lengths'])} | "
                f"{s['recent_return']:,.0f} | {commit} |"
            )
    return "\n".join(lines)


def _commit(folder: Path) -> str:
    versions = json.loads((folder / "versions.json").read_text())
    commit = str(versions.get("canter_commit") or "?")[:7]
    return commit + (" (dirty)" if versions.get("canter_dirty") else "")


def bench_files(found: dict[tuple[str, str], list[dict[str, Any]]]) -> dict[Path, str]:
    """The archive's results.md, results.csv and statistics.json, as `canter bench` writes them."""
    results = [cell_result(algo, env, rows) for algo, env, rows in cells(found)]
    markdown, table_csv, statistics_json = results_markdown(results, [], BUDGET)
    return {
        ARCHIVE / "results.md": markdown,
        ARCHIVE / "results.csv": table_csv,
        ARCHIVE / "statistics.json": statistics_json,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only check that the tables match the archive")
    parser.add_argument(
        "--collect", type=Path, nargs="+", metavar="BENCH_DIR", help="archive the finished runs of these benches"
    )
    args = parser.parse_args()
    for bench_dir in args.collect or []:
        print(f"archived {len(collect(bench_dir))} runs of {bench_dir} into {ARCHIVE.relative_to(ROOT)}")
    found = finished_runs(ARCHIVE, ALGOS, BUDGET)
    wanted = {
        path: replace_between(read_text(path), markers, table)
        for path, markers, table in (
            (ROOT / "README.md", README_MARKERS, readme_table(found)),
            (ROOT / "benchmarks" / "results" / "README.md", RESULTS_MARKERS, results_table(found)),
        )
    }
    wanted.update(bench_files(found))
    if args.check:
        return sync(wanted, True, "benchmarks/onpolicy_tables.py")
    sync(wanted, False, "benchmarks/onpolicy_tables.py")
    for env in ENVS:
        folders = [r["folder"] for algo in ALGOS for r in found.get((algo, env), [])]
        if folders:
            plot_env(folders, ARCHIVE / f"plot_{env}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
