"""The helpers of the benchmarks that time two source trees side by side, and that each such script loads."""

import json

import pytest

from script_modules import BENCHMARKS, load_script


@pytest.fixture(scope="module")
def two_trees():
    return load_script("two_trees", BENCHMARKS / "two_trees.py")


def test_results_get_their_title_once_and_each_raw_row_the_shared_fields(tmp_path, two_trees):
    for n in (1, 2):
        lines = [two_trees.heading("abc1234", "def5678"), "", f"| section {n} |"]
        two_trees.append_results(tmp_path, "A title", lines, "raw.jsonl", [{"n": n}, {"n": n + 10}], before="def5678")
    text = (tmp_path / "results.md").read_text()
    assert text.startswith("# A title\n\n## ") and text.count("# A title") == 1
    assert text.count(" against def5678\n\n| section ") == 2 and text.endswith("| section 2 |\n")
    rows = [json.loads(line) for line in (tmp_path / "raw.jsonl").read_text().splitlines()]
    assert rows == [{"n": n, "before": "def5678"} for n in (1, 11, 2, 12)]


def test_the_src_of_a_ref_is_that_commits_tree(tmp_path, two_trees):
    src = two_trees.extract_src("HEAD", tmp_path)
    committed = two_trees.git("show", "HEAD:src/canter/__init__.py")
    assert src == tmp_path / "src" and (src / "canter" / "__init__.py").read_text().rstrip("\n") == committed
    before, now = two_trees.commits("HEAD")
    assert before == now and len(now) >= 7


@pytest.mark.parametrize("script", ["load_cost", "scoreboard_cost", "checkpoint_size"])
def test_each_side_by_side_script_loads_with_its_helpers(script):
    module = load_script(f"bench_{script}", BENCHMARKS / script / "run.py")
    assert callable(module.main) and module.append_results.__module__ == "two_trees"
