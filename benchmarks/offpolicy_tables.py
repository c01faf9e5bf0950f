"""Rebuild the off-policy score tables of README.md and benchmarks/results/README.md from the archived runs.

Each finished 1M-step run of `canter bench --algos td3,ddpg,sac ... --out runs/offpolicy-1m` is archived as
benchmarks/results/offpolicy-1m/<env>__<algo>__s<seed>/ (config.toml, eval.json, metrics.csv, summary.json,
versions.json). Runs made with another preset live in an archive of their own (VARIANTS) and get rows of their
own, labelled with the preset. This script turns those folders into the two tables, between their marker
comments, and rewrites each archive's own bench files (results.md, results.csv and one curve per env, as
`canter bench` writes them), so that the bench's training runs need not be repeated to refresh them:

    python benchmarks/offpolicy_tables.py           # rewrite the tables, results.md/.csv and the curves
    python benchmarks/offpolicy_tables.py --check   # exit 1 if a table or results.md/.csv differs from the archive
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from canter.orchestrate.bench import (
    combine_records,
    plot_env,
    published_for,
    seed_record,
)
from canter.orchestrate.bench import results_table as bench_table

ROOT = Path(__file__).resolve().parent.parent
ARCHIVE = ROOT / "benchmarks" / "results" / "offpolicy-1m"
# preset name -> archive of runs made with it ("" is the default preset, whose runs are in ARCHIVE).
VARIANTS = {"": ARCHIVE, "tianshou": ROOT / "benchmarks" / "results" / "sac-tianshou"}
ALGOS = ("td3", "ddpg", "sac")
ENVS = ("HalfCheetah-v5", "Hopper-v5", "Walker2d-v5")
BUDGET = 1_000_000
RESULTS_MARKER = "<!-- offpolicy-table -->\n"
README_MARKER = "<!-- offpolicy-readme-table -->\n"


def label(algo: str, variant: str) -> str:
    return f"{algo}, preset {variant}" if variant else algo


def finished_runs(archive: Path) -> dict[tuple[str, str], list[dict]]:
    """(algo, env) -> one record per finished seed, sorted by seed."""
    found: dict[tuple[str, str], list[dict]] = {}
    for folder in sorted(archive.iterdir()):
        match = re.fullmatch(r"(.+)__(td3|ddpg|sac)__s(\d+)", folder.name)
        if not match or not (folder / "eval.json").is_file() or not (folder / "summary.json").is_file():
            continue
        summary = json.loads((folder / "summary.json").read_text())
        if summary.get("global_step", 0) < BUDGET:
            continue
        seed = int(match[3])
        record = seed_record(folder, seed)
        record.update(evaluation=json.loads((folder / "eval.json").read_text()), summary=summary, folder=folder)
        found.setdefault((match[2], match[1]), []).append(record)
    return {key: sorted(rows, key=lambda r: r["seed"]) for key, rows in found.items()}


def cells(found: dict[str, dict]):
    """(algo, env, variant, rows) in table order: by algo, then env, a preset's rows after the default's."""
    for algo in ALGOS:
        for env in ENVS:
            for variant in VARIANTS:
                rows = found[variant].get((algo, env), [])
                if rows:
                    yield algo, env, variant, rows


def results_table(found: dict[str, dict]) -> str:
    lines = [
        "| env | algo | seed | eval return (10 episodes, deterministic) | train return (last 20 eps) | wall min "
        "| SPS | published (1M) |",
        "|---|---|---:|---:|---:|---:|---:|---|",
    ]
    for algo, env, variant, rows in cells(found):
        published = published_for(algo, env, BUDGET)
        name = label(algo, variant)
        for r in rows:
            e, s = r["evaluation"], r["summary"]
            lines.append(
                f"| {env} | {name} | {r['seed']} | **{e['mean']:,.0f} ± {e['std']:,.0f}** | "
                f"{s['recent_return']:,.0f} | {r['wall_seconds'] / 60:.1f} | {r['sps']:.0f} | "
                f"{published} |"
            )
        if len(rows) > 1:
            means = [r["eval_mean"] for r in rows]
            lines.append(
                f"| {env} | {name} | mean of {len(rows)} | **{np.mean(means):,.0f} ± {np.std(means):,.0f}**"
                f" (median {np.median(means):,.0f}) | | | | {published} |"
            )
    return "\n".join(lines)


def readme_table(found: dict[str, dict]) -> str:
    lines = ["| env | algo | seeds | return per seed | mean | published (1M) |", "|---|---|---:|---|---:|---|"]
    for algo, env, variant, rows in cells(found):
        per_seed = ", ".join(f"{r['eval_mean']:,.0f} (s{r['seed']})" for r in rows)
        mean = np.mean([r["eval_mean"] for r in rows])
        lines.append(
            f"| {env} | {label(algo, variant)} | {len(rows)} | {per_seed} | **{mean:,.0f}** | "
            f"{published_for(algo, env, BUDGET)} |"
        )
    return "\n".join(lines)


def bench_files(runs: dict[tuple[str, str], list[dict]]) -> dict[str, str]:
    """One archive's results.md and results.csv as `canter bench` writes them for its cells (no grid, seeds
    apart)."""
    results = []
    for algo in ALGOS:
        for env in ENVS:
            if (algo, env) in runs:
                cell = SimpleNamespace(name=f"{env}__{algo}", env_id=env, algo=algo, values=())
                results.append(combine_records(cell, runs[(algo, env)]))
    markdown, table_csv = bench_table(results, [], BUDGET)
    return {"results.md": markdown, "results.csv": table_csv}


def replace_after(text: str, marker: str, table: str) -> str:
    """Put `table` between `marker` and the next blank line."""
    start = text.index(marker) + len(marker)
    end = text.index("\n\n", start)
    return text[:start] + table + text[end:]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only check that the tables match the archive")
    args = parser.parse_args()
    found = {variant: finished_runs(archive) for variant, archive in VARIANTS.items()}
    stale = []
    # Bytes, not text: results.csv has \r\n line ends, which text mode would translate.
    read = lambda path: path.read_bytes().decode() if path.is_file() else ""  # noqa: E731
    wanted = {
        path: replace_after(read(path), marker, table)
        for path, marker, table in (
            (ROOT / "benchmarks" / "results" / "README.md", RESULTS_MARKER, results_table(found)),
            (ROOT / "README.md", README_MARKER, readme_table(found)),
        )
    }
    for variant, archive in VARIANTS.items():
        wanted.update({archive / name: content for name, content in bench_files(found[variant]).items()})
    for path, new in wanted.items():
        if new != read(path):
            stale.append(path.relative_to(ROOT))
            if not args.check:
                path.write_bytes(new.encode())
    if not args.check:
        for variant, archive in VARIANTS.items():
            for env in ENVS:
                folders = [r["folder"] for algo in ALGOS for r in found[variant].get((algo, env), [])]
                if folders:
                    plot_env(folders, archive / f"plot_{env}.png")
    if args.check and stale:
        print(
            f"stale off-policy tables in {', '.join(map(str, stale))}; run python benchmarks/offpolicy_tables.py",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
