from pathlib import Path

import pytest

from canter.docs import render
from script_modules import BENCHMARKS, load_script

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_config_table_is_generated_from_the_dataclasses():
    text = README.read_text()
    assert render(text) == text, "README.md is stale: run `make docs`"


def test_readme_names_the_two_commands():
    text = README.read_text()
    assert "make demo" in text and "make test" in text


# Every table of README.md sits between the marker comments of a block that a script writes from archived files, and
# the tests regenerate each block: the script named here (with --check), `make docs` for the config table.
README_BLOCKS = {
    "bench-headline": "benchmarks/ppo_speed/run.py",  # checked by tests/test_speed_archive.py
    "score-table": "benchmarks/onpolicy_tables.py",
    "offpolicy-readme-table": "benchmarks/offpolicy_tables.py",
    "config-table": "src/canter/docs.py",
}
TABLE_SCRIPTS = ("benchmarks/offpolicy_tables.py", "benchmarks/onpolicy_tables.py")


def test_every_readme_table_is_in_a_block_that_a_script_writes():
    import re

    block = None
    for number, line in enumerate(README.read_text().splitlines(), 1):
        marker = re.match(r"<!-- (/?)([a-z0-9-]+)(?::(begin|end))?", line)
        if marker:
            closing = marker[1] == "/" or marker[3] == "end"
            block = None if closing else marker[2]
        if line.startswith("|---"):
            assert block in README_BLOCKS, f"README.md line {number}: a table outside the generated blocks"
    for name, script in README_BLOCKS.items():
        assert f"<!-- {name}" in (README.parent / script).read_text(), f"{script} does not write <!-- {name} -->"


@pytest.mark.slow
@pytest.mark.parametrize("script", TABLE_SCRIPTS)
def test_tables_match_the_archived_runs(script):
    import subprocess
    import sys

    done = subprocess.run([sys.executable, str(README.parent / script), "--check"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def _offpolicy_tables():
    return load_script("offpolicy_tables", BENCHMARKS / "offpolicy_tables.py")


def _record(seed, mean, lengths):
    evaluation = {"mean": mean, "std": 1.0, "returns": [mean]} | ({"lengths": [1000]} if lengths else {})
    return {
        "seed": seed,
        "eval_mean": mean,
        "evaluation": evaluation,
        "summary": {"recent_return": mean},
        "wall_seconds": 60.0,
        "sps": 100.0,
    }


def test_offpolicy_tables_mark_evaluations_without_lengths_and_late_seeds():
    tables = _offpolicy_tables()
    rows = [_record(0, 1000.0, False), _record(1, 2000.0, True), _record(2, 3000.0, True), _record(3, 4000.0, True)]
    found = {variant: {} for variant in tables.VARIANTS} | {"": {("td3", "Walker2d-v5"): rows}}
    readme = tables.readme_table(found)
    assert "1,000 (s0)†, 2,000 (s1), 3,000 (s2), 4,000 (s3)" in readme
    assert "| 4 (seed 3 added after the first results, one at a time, until the mean met the target) |" in readme
    assert "**2,500** (seeds 0-2 alone: 2,000)" in readme
    assert readme.endswith(tables.NO_LENGTHS_NOTE)
    results = tables.results_table(found)
    assert "| 0 | **1,000 ± 1**† |" in results and "| 1 | **2,000 ± 1** |" in results
    assert "mean of 4 (seed 3 added after the first results" in results and results.endswith(tables.NO_LENGTHS_NOTE)
    # Every evaluation with lengths and no late seeds: no marks and no note.
    found[""] = {("td3", "Hopper-v5"): [r for r in rows if r["seed"]]}
    assert "†" not in tables.readme_table(found) + tables.results_table(found)
    assert tables.seed_span((3, 4, 5)) == "3-5" and tables.seed_span((3, 5)) == "3, 5"


def test_the_readme_says_which_td3_walker2d_seeds_came_after_the_first_results():
    [row] = [line for line in README.read_text().splitlines() if line.startswith("| Walker2d-v5 | td3 |")]
    assert "seeds 3-5 added after the first results" in row
