"""Rebuild the off-policy score tables of README.md and benchmarks/results/README.md from the archived runs.

Each finished 1M-step run of `canter bench --algos td3,ddpg,sac ... --out runs/offpolicy-1m` is archived as
benchmarks/results/offpolicy-1m/<env>__<algo>__s<seed>/ (config.toml, eval.json, metrics.csv, summary.json,
versions.json). Runs made with another preset live in an archive of their own (VARIANTS) and get rows of their
own, labelled with the preset. This script turns those folders into the two tables, between their marker
comments (a seed whose eval.json lacks episode lengths is marked, and a cell that got seeds after its first results
says so), and rewrites each archive's own bench files (results.md, results.csv and one curve per env, as
`canter bench` writes them), so that the bench's training runs need not be repeated to refresh them:

    python benchmarks/offpolicy_tables.py           # rewrite the tables, results.md/.csv and the curves
    python benchmarks/offpolicy_tables.py --check   # exit 1 if a table or results.md/.csv differs from the archive
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # archive.py, when loaded from elsewhere (the tests)
from archive import ROOT, finished_runs, read_text, replace_between, sync

from canter.orchestrate.bench_results import combine_records, plot_env, published_for
from canter.orchestrate.bench_results import results_table as bench_table

ARCHIVE = ROOT / "benchmarks" / "results" / "offpolicy-1m"
# preset name -> archive of runs made with it ("" is the default preset, whose runs are in ARCHIVE).
VARIANTS = {"": ARCHIVE, "tianshou": ROOT / "benchmarks" / "results" / "sac-tianshou"}
ALGOS = ("td3", "ddpg", "sac")
ENVS = ("HalfCheetah-v5", "Hopper-v5", "Walker2d-v5")
BUDGET = 1_000_000
# Each generated block sits between its start and end marker comments.
RESULTS_MARKERS = ("<!-- offpolicy-table -->\n", "<!-- /offpolicy-table -->")
README_MARKERS = ("<!-- offpolicy-readme-table -->\n", "<!-- /offpolicy-readme-table -->")
# Seeds added to a cell after its first results were in, and why: the cell itself says so
# (benchmarks/results/README.md tells the whole story).
LATE_SEEDS: dict[tuple[str, str, str], tuple[tuple[int, ...], str]] = {
    ("td3", "Walker2d-v5", ""): ((3, 4, 5), "one at a time, until the mean met the target"),
}
# Marks a seed whose eval.json has no episode lengths: it was written before the bench recorded them, and old runs
# are not retrained only to add them.
NO_LENGTHS = "†"
NO_LENGTHS_NOTE = (
    f"{NO_LENGTHS} This run's eval.json holds each evaluation episode's return but not its length: it was written "
    "before `canter bench` recorded lengths, and the run was not retrained only to add them."
)


def label(algo: str, variant: str) -> str:
    return f"{algo}, preset {variant}" if variant else algo


def cells(found: dict[str, dict]):
    """(algo, env, variant, rows) in table order: by algo, then env, a preset's rows after the default's."""
    for algo in ALGOS:
        for env in ENVS:
            for variant in VARIANTS:
                rows = found[variant].get((algo, env), [])
                if rows:
                    yield algo, env, variant, rows


def lacks_lengths(record: dict) -> bool:
    return "lengths" not in record["evaluation"]


def marked(text: str, record: dict) -> str:
    return text + NO_LENGTHS if lacks_lengths(record) else text


def seed_span(seeds: tuple[int, ...]) -> str:
    """Seeds as the tables name them: 3-5 for three or more consecutive seeds, else 3, 5."""
    consecutive = len(seeds) > 2 and list(seeds) == list(range(seeds[0], seeds[-1] + 1))
    return f"{seeds[0]}-{seeds[-1]}" if consecutive else ", ".join(map(str, seeds))


def late_seeds_note(algo: str, env: str, variant: str, rows: list[dict]) -> tuple[str, str]:
    """For a cell that got seeds after its first results: what the cell says of them, and the mean of the seeds it
    had before them. Empty strings for every other cell."""
    late, why = LATE_SEEDS.get((algo, env, variant), ((), ""))
    late = tuple(r["seed"] for r in rows if r["seed"] in late)
    first = [r for r in rows if r["seed"] not in late]
    if not late or not first:
        return "", ""
    note = f"seed{'s' if len(late) > 1 else ''} {seed_span(late)} added after the first results, {why}"
    first_mean = np.mean([r["eval_mean"] for r in first])
    before = f"seeds {seed_span(tuple(r['seed'] for r in first))} alone: {first_mean:,.0f}"
    return note, before


def footnote(found: dict[str, dict]) -> str:
    """The note under a table that marks a seed whose eval.json lacks lengths, when one does."""
    rows = [r for _, _, _, cell_rows in cells(found) for r in cell_rows]
    return f"\n\n{NO_LENGTHS_NOTE}" if any(lacks_lengths(r) for r in rows) else ""


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
            score = marked(f"**{e['mean']:,.0f} ± {e['std']:,.0f}**", r)
            lines.append(
                f"| {env} | {name} | {r['seed']} | {score} | "
                f"{s['recent_return']:,.0f} | {r['wall_seconds'] / 60:.1f} | {r['sps']:.0f} | "
                f"{published} |"
            )
        if len(rows) > 1:
            means = [r["eval_mean"] for r in rows]
            late, before = late_seeds_note(algo, env, variant, rows)
            lines.append(
                f"| {env} | {name} | mean of {len(rows)}{f' ({late})' if late else ''} | "
                f"**{np.mean(means):,.0f} ± {np.std(means):,.0f}** (median {np.median(means):,.0f}"
                f"{f'; {before}' if before else ''}) | | | | {published} |"
            )
    return "\n".join(lines) + footnote(found)


def readme_table(found: dict[str, dict]) -> str:
    lines = ["| env | algo | seeds | return per seed | mean | published (1M) |", "|---|---|---:|---|---:|---|"]
    for algo, env, variant, rows in cells(found):
        per_seed = ", ".join(marked(f"{r['eval_mean']:,.0f} (s{r['seed']})", r) for r in rows)
        mean = np.mean([r["eval_mean"] for r in rows])
        late, before = late_seeds_note(algo, env, variant, rows)
        lines.append(
            f"| {env} | {label(algo, variant)} | {len(rows)}{f' ({late})' if late else ''} | {per_seed} | "
            f"**{mean:,.0f}**{f' ({before})' if before else ''} | {published_for(algo, env, BUDGET)} |"
        )
    return "\n".join(lines) + footnote(found)


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


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only check that the tables match the archive")
    args = parser.parse_args()
    found = {variant: finished_runs(archive, ALGOS, BUDGET) for variant, archive in VARIANTS.items()}
    wanted = {
        path: replace_between(read_text(path), markers, table)
        for path, markers, table in (
            (ROOT / "benchmarks" / "results" / "README.md", RESULTS_MARKERS, results_table(found)),
            (ROOT / "README.md", README_MARKERS, readme_table(found)),
        )
    }
    for variant, archive in VARIANTS.items():
        wanted.update({archive / name: content for name, content in bench_files(found[variant]).items()})
    if args.check:
        return sync(wanted, True, "benchmarks/offpolicy_tables.py")
    sync(wanted, False, "benchmarks/offpolicy_tables.py")
    for variant, archive in VARIANTS.items():
        for env in ENVS:
            folders = [r["folder"] for algo in ALGOS for r in found[variant].get((algo, env), [])]
            if folders:
                plot_env(folders, archive / f"plot_{env}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
