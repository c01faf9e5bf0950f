"""The gait study (benchmarks/ppo_speed/gait.py): its Fisher exact test against hand-computed values and SciPy, and
its archive and page rendered from run.py's rows.json."""

import json
import random
from datetime import UTC, datetime

import pytest
from scipy.stats import fisher_exact

from script_modules import BENCHMARKS, load_script

gait = load_script("gait_study", BENCHMARKS / "ppo_speed" / "gait.py")


@pytest.mark.parametrize(
    ("table", "expected"),
    [
        ((1, 6, 2, 3), 19 / 84),  # the runs of 2026-11-22: hypergeometric weights 20, 45, 18, 1 out of 84
        ((0, 10, 10, 10), 2 / 184_756),  # only the two extreme tables, each 1 / C(20, 10)
        ((5, 10, 5, 10), 1.0),
        ((0, 3, 0, 4), 1.0),  # no hits at all: one possible table
    ],
)
def test_fisher_exact_matches_hand_computed_values(table, expected):
    assert gait.fisher_exact_two_sided(*table) == pytest.approx(expected, rel=1e-12)


def test_fisher_exact_matches_scipy_and_is_symmetric_in_the_groups():
    rng = random.Random(0)
    for _ in range(200):
        n_a, n_b = rng.randint(1, 15), rng.randint(1, 15)
        a, b = rng.randint(0, n_a), rng.randint(0, n_b)
        expected = fisher_exact([[a, n_a - a], [b, n_b - b]]).pvalue
        assert gait.fisher_exact_two_sided(a, n_a, b, n_b) == pytest.approx(expected, rel=1e-9)
        assert gait.fisher_exact_two_sided(b, n_b, a, n_a) == pytest.approx(expected, rel=1e-9)


def test_fisher_exact_refuses_more_hits_than_runs():
    with pytest.raises(ValueError, match=r"hits must lie in 0\.\.n"):
        gait.fisher_exact_two_sided(4, 3, 0, 3)


def _row(tool, seed, score, ok=True):
    return {
        "tool": tool,
        "seed": seed,
        "ok": ok,
        "error": "" if ok else "sb3_ppo.py exited 1",
        "eval_mean": score,
        "eval_std": 10.0,
        "train_return": None if score is None else score - 100,
        "process_wall": 100.0,
        "sps": 1000.0,
    }


def test_counts_use_the_declared_threshold_and_leave_failed_runs_out():
    rows = [
        _row("canter-cleanrl", 10, 3000.0),  # at the threshold: fast
        _row("canter-cleanrl", 11, 2999.9),
        _row("sb3", 10, 5200.0),
        _row("sb3", 11, None, ok=False),
    ]
    assert gait.gait_counts(rows) == {"canter-cleanrl": (1, 2), "sb3": (1, 1)}


def _runs_folder(tmp_path, name, started, rows):
    folder = tmp_path / name
    for row in rows:
        (folder / f"{row['tool']}__s{row['seed']}").mkdir(parents=True)
        (folder / f"{row['tool']}__s{row['seed']}" / "train.log").write_text(f"seed {row['seed']}\n")
        (folder / f"{row['tool']}__s{row['seed']}" / "checkpoint.npz").write_bytes(b"left out")
    settings = {"total_steps": 1_000_000, "seeds": [row["seed"] for row in rows], "tools": [rows[0]["tool"]]}
    content = gait.speed_archive.record("ppo_speed", started, settings, rows)
    (folder / "rows.json").write_text(json.dumps(content))
    return folder


def test_the_archive_merges_run_folders_and_the_page_is_rendered_and_checked_from_it(tmp_path, monkeypatch):
    page = tmp_path / "gait.md"
    page.write_text("# study\n\n<!-- gait-results -->\nNot run yet.\n\n<!-- /gait-results -->\n")
    monkeypatch.setattr(gait, "PAGE", page)
    monkeypatch.setattr(gait, "LOGS", tmp_path / "gait_logs")
    canter = _runs_folder(
        tmp_path,
        "a",
        datetime(2026, 11, 29, 21, 20, 1, tzinfo=UTC),
        [_row("canter-cleanrl", s, 1700.0) for s in (10, 11)],
    )
    sb3 = _runs_folder(
        tmp_path,
        "b",
        datetime(2026, 11, 29, 21, 20, 26, tzinfo=UTC),
        [_row("sb3", 10, 5300.0), _row("sb3", 11, 5100.0)],
    )

    dest = gait.archive([sb3, canter])
    assert dest.name == "20261129-212001"  # named by the earliest start
    content = json.loads((dest / "rows.json").read_text())
    assert [(r["seed"], r["tool"]) for r in content["rows"]] == [
        (10, "canter-cleanrl"),
        (10, "sb3"),
        (11, "canter-cleanrl"),
        (11, "sb3"),
    ]
    assert len(content["settings"]["sources"]) == 2
    assert (dest / "sb3__s11" / "train.log").read_text() == "seed 11\n"
    assert not (dest / "sb3__s11" / "checkpoint.npz").exists()

    assert gait.write(dest, check=True) == 1  # the page still says "Not run yet."
    assert gait.write(dest, check=False) == 0
    text = page.read_text()
    assert "canter-cleanrl 0 of 2, sb3 2 of 2" in text
    assert f"p = {1 / 3:.3f}" in text  # only the observed and the reverse table: 2 x C(2,2)C(2,0) / C(4,2)
    assert "| 11 | 1,700 ± 10 | 1,600 | flipped | 5,100 ± 10 | 5,000 | fast |" in text
    assert "2 processes side by side: " in text and "canter-cleanrl seeds 10, 11 (commit " in text
    assert gait.write(dest, check=True) == 0


def test_the_committed_page_is_what_its_archive_gives():
    (archive,) = sorted(gait.LOGS.iterdir())
    assert gait.write(archive, check=True) == 0
