"""The gait study of gait.md: how often canter's `cleanrl` preset and SB3, with the same PPO settings, find
HalfCheetah-v4's fast gait in 1M steps. The runs are run.py's (`--no-write`, since their timings are not clean);
this script gathers them into one archive and renders gait.md's results from it:

    .venv/bin/python benchmarks/ppo_speed/gait.py --archive benchmarks/runs/<stamp> [benchmarks/runs/<stamp> ...]
    .venv/bin/python benchmarks/ppo_speed/gait.py --write benchmarks/ppo_speed/gait_logs/<stamp> [--check]

The seeds, the threshold and the test were fixed in gait.md before the runs.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from datetime import datetime
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/, for speed_archive and archive
import speed_archive

HERE = Path(__file__).resolve().parent
PAGE = HERE / "gait.md"
LOGS = HERE / "gait_logs"
MARKERS = ("<!-- gait-results -->", "<!-- /gait-results -->")
SEEDS = tuple(range(10, 20))
TOOLS = ("canter-cleanrl", "sb3")
FAST_GAIT = 3000.0  # a deterministic evaluation mean at or above it is the fast gait
SIGNIFICANCE = 0.05


def fisher_exact_two_sided(hits_a: int, n_a: int, hits_b: int, n_b: int) -> float:
    """Two-sided Fisher exact p-value of the 2x2 table (hits_a, n_a - hits_a; hits_b, n_b - hits_b): the
    probability, with the margins fixed, of a table no more likely than the observed one."""
    if not (0 <= hits_a <= n_a and 0 <= hits_b <= n_b):
        raise ValueError(f"hits must lie in 0..n, got {hits_a}/{n_a} and {hits_b}/{n_b}")
    hits = hits_a + hits_b
    total = math.comb(n_a + n_b, hits)

    def weight(k: int) -> int:  # tables with k hits in group a, as a count of equally likely draws
        return math.comb(n_a, k) * math.comb(n_b, hits - k)

    observed = weight(hits_a)
    possible = range(max(0, hits - n_b), min(n_a, hits) + 1)
    # Exact integers, so "no more likely" needs no floating-point tolerance.
    return sum(w for w in map(weight, possible) if w <= observed) / total


def gait_counts(rows: list[dict]) -> dict[str, tuple[int, int]]:
    """Per tool, (runs at the fast gait, runs evaluated). A failed run counts in neither."""
    counts = {}
    for tool in TOOLS:
        scores = [row["eval_mean"] for row in rows if row["tool"] == tool and row.get("ok")]
        counts[tool] = (sum(score >= FAST_GAIT for score in scores), len(scores))
    return counts


def merge(records: list[dict]) -> dict:
    """One rows.json record of several run.py records: the earliest start, every row in seed order, and each
    source's start and command."""
    rows = sorted((row for record in records for row in record["rows"]), key=lambda r: (r["seed"], r["tool"]))
    started = min(datetime.fromisoformat(record["started"]) for record in records)
    settings = {
        "seeds": sorted({row["seed"] for row in rows}),
        "tools": sorted({row["tool"] for row in rows}),
        "total_steps": sorted({record["settings"]["total_steps"] for record in records}),
        "fast_gait": FAST_GAIT,
        "sources": [
            {"started": r["started"], "command": r["command"], "commit": r["commit"], "settings": r["settings"]}
            for r in records
        ],
    }
    return speed_archive.record("ppo_gait", started, settings, rows)


def archive(runs_folders: list[Path]) -> Path:
    """Archive the raw files of run.py's folders into gait_logs/<stamp>/ with the merged rows.json."""
    records = [json.loads((folder / speed_archive.ROWS_FILE).read_text()) for folder in runs_folders]
    content = merge(records)
    dest = LOGS / datetime.fromisoformat(content["started"]).strftime("%Y%m%d-%H%M%S")
    machine_info = speed_archive.machine()
    for folder in runs_folders:
        speed_archive.archive(folder, dest, content, machine_info)
    return dest


def _score(row: dict) -> str:
    if not row.get("ok"):
        return f"failed: {row.get('error', '')}"
    gait = "fast" if row["eval_mean"] >= FAST_GAIT else "flipped"
    return f"{row['eval_mean']:,.0f} ± {row['eval_std']:,.0f} | {row['train_return']:,.0f} | {gait}"


def _seeds_by_commit(source: dict, by_key: dict) -> str:
    """`source`'s seeds grouped by the commit each ran at. A run.py process records the commit it ended at, and
    commits can land while its runs go on, so a canter run is named by the commit in its own versions.json (which
    run.py copies into the row). A run that records none (SB3's) is named by the process's commit."""
    groups: dict[str, list[int]] = {}
    for seed in source["settings"]["seeds"]:
        for tool in source["settings"]["tools"]:
            versions = by_key.get((tool, seed), {}).get("extra", {}).get("versions", {})
            if versions.get("canter_commit"):
                modified = ", src modified" if versions.get("canter_dirty") else ""
                label = f"commit {versions['canter_commit'][:7]}{modified}"
            else:
                label = f"commit {source['commit']} when the process ended"
            seeds = groups.setdefault(label, [])
            if seed not in seeds:
                seeds.append(seed)
    return ", ".join(f"seeds {', '.join(map(str, seeds))} ({label})" for label, seeds in groups.items())


def results(content: dict, machine_info: dict, logs: str) -> str:
    """gait.md's results: one row per seed, the counts and the test, with the machine and the archive."""
    rows = content["rows"]
    by_key = {(row["tool"], row["seed"]): row for row in rows}
    seeds = content["settings"]["seeds"]
    sources = "; ".join(
        f"{', '.join(source['settings']['tools'])} {_seeds_by_commit(source, by_key)}"
        for source in content["settings"]["sources"]
    )
    processes = len(content["settings"]["sources"])
    lines = [
        "",
        f"Runs of {content['started'][:10]} on {machine_info['cpu']} ({machine_info['cores']}), {processes} processes"
        f" side by side: {sources}; raw logs: [{logs}]({logs}). Each cell: deterministic evaluation mean ± std over"
        " 10 episodes | mean of the last 20 training episodes | gait.",
        "",
        "| seed | " + " | ".join(f"{tool} eval | train | gait" for tool in TOOLS) + " |",
        "|---:|" + "---:|---:|---|" * len(TOOLS),
    ]
    for seed in seeds:
        cells = [_score(by_key[tool, seed]) if (tool, seed) in by_key else "not run | | " for tool in TOOLS]
        lines.append(f"| {seed} | " + " | ".join(cells) + " |")
    counts = gait_counts(rows)
    (hits_a, n_a), (hits_b, n_b) = (counts[tool] for tool in TOOLS)
    p = fisher_exact_two_sided(hits_a, n_a, hits_b, n_b)
    verdict = (
        f"p < {SIGNIFICANCE}: the tools differ"
        if p < SIGNIFICANCE
        else f"p ≥ {SIGNIFICANCE}: these runs show no difference between the tools"
    )
    lines += [
        "",
        f"- **Fast gait (evaluation ≥ {FAST_GAIT:,.0f}):** {TOOLS[0]} {hits_a} of {n_a}, {TOOLS[1]} {hits_b} of {n_b}.",
        f"- **Two-sided Fisher exact test:** p = {p:.3f} ({verdict}).",
    ]
    return "\n".join(lines) + "\n"


def write(folder: Path, check: bool) -> int:
    from archive import replace_between  # benchmarks/archive.py

    content, machine_info = speed_archive.load(folder)
    text = results(content, machine_info, speed_archive.shown(folder))
    page = PAGE.read_text()
    updated = replace_between(page, MARKERS, text)
    if check:
        if updated != page:
            print(
                f"{speed_archive.shown(PAGE)} differs from {speed_archive.shown(folder)}; run --write", file=sys.stderr
            )
            return 1
        return 0
    PAGE.write_text(updated)
    print(text)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    action = p.add_mutually_exclusive_group(required=True)
    action.add_argument("--archive", nargs="+", type=Path, metavar="RUNS", help="run.py folders to gather")
    action.add_argument("--write", type=Path, metavar="LOGS", help="render gait.md's results from an archive")
    p.add_argument("--check", action="store_true", help="with --write: exit 1 where gait.md differs")
    args = p.parse_args(argv)
    if args.archive:
        dest = archive(args.archive)
        print(f"archived into {speed_archive.shown(dest)}")
        return 0
    return write(args.write, args.check)


if __name__ == "__main__":
    sys.exit(main())
