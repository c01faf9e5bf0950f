"""Every report page's tables are what its archive gives: each benchmarks/reports/*/run.py --check, in this process
(no training, no child processes)."""

import importlib.util
import sys
from pathlib import Path

import pytest

REPORTS = Path(__file__).resolve().parents[1] / "benchmarks" / "reports"
PAGES = sorted(REPORTS.glob("*/run.py"))


def test_every_report_page_is_found():
    assert {p.parent.name for p in PAGES} >= {
        "000-humanoidstandup-halfcheetah-ppo-rpo-sym",
        "002-hopper-trpo-bipedalwalker",
        "003-ppo-td3-compute-time",
    }


@pytest.mark.parametrize("script", PAGES, ids=lambda p: p.parent.name)
def test_report_page_tables_match_the_archive(script, monkeypatch, capsys):
    page = _load_page(script, monkeypatch)
    monkeypatch.setattr(sys, "argv", [str(script), "--check"])
    assert page.main() == 0, capsys.readouterr().err


def _load_page(script: Path, monkeypatch):
    name = f"report_page_{script.parent.name[:3]}"
    spec = importlib.util.spec_from_file_location(name, script)
    assert spec and spec.loader
    page = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, name, page)  # dataclasses look their module up there
    spec.loader.exec_module(page)
    return page


def test_the_limb_measure_finds_each_of_its_runs_among_the_pages_grids(monkeypatch):
    """Page 000's limbs.py names each run by a cell of the page's grids (or a committed seed-0 run). The page's
    archive holds every grid run's folder as the bench names it, so with the archive as the work folder each is
    found, and a cell or seed the grid does not have fails."""
    page = _load_page(REPORTS / "000-humanoidstandup-halfcheetah-ppo-rpo-sym" / "run.py", monkeypatch)
    monkeypatch.setattr(page.limbs, "WORK", page.PAGE / "runs")
    for label, seed, where in page.limbs.RUNS:
        found = page.limbs.run_folder(where, seed, page.GRIDS)
        assert found is not None and f"__s{seed}" in found.name, (label, seed)
    missing = page.limbs.GridRun("hs-sym", (("sym.coef", "0.03"),))
    with pytest.raises(ValueError):
        page.limbs.run_folder(missing, 100, page.GRIDS)
    assert page.limbs.run_folder(page.limbs.GridRun("hs-sym", (("sym.coef", "0.0"),)), 101, page.GRIDS) is None


def test_the_walker_pages_bar_against_cleanrl_is_two_standard_errors_of_the_difference(monkeypatch):
    page = _load_page(REPORTS / "004-dmc-walker-ppo" / "run.py", monkeypatch)
    mean, bar = page.bar_to_beat([900.0, 950.0, 1000.0], (787.0, 126.0, 10))
    # By hand: sample std 50, so sqrt(126^2 / 10 + 50^2 / 3) = sqrt(1587.6 + 833.33) = 49.203.
    assert mean == 950.0
    assert bar == pytest.approx(787.0 + 2 * 49.203, abs=1e-2)


def test_the_walker_pages_first_crossing_follows_the_last_episodes(monkeypatch, tmp_path):
    page = _load_page(REPORTS / "004-dmc-walker-ppo" / "run.py", monkeypatch)
    rows = [(1000.0, 1, 100.0, 1.0), (2000.0, 2, 700.0, 2.0), (3000.0, 1, 900.0, 3.0)]
    # Over the last 3 episodes: 500 after the second row, (700 + 700 + 900) / 3 = 766.7 after the third.
    assert page.first_crossing(rows, 700.0, window=3) == (3000.0, 3.0)
    assert page.first_crossing(rows, 800.0, window=3) is None
    (tmp_path / "metrics.csv").write_text(
        "global_step,iteration,wall_time,sps,episodes,episodic_return\n"
        "1000,1,5.0,200,1,28.5\n"
        "2000,2,10.0,200,0,\n"
        "3000,3,15.0,200,2,640.0\n"
    )
    assert page.training_rows(tmp_path) == [(1000.0, 1, 28.5, 5.0), (3000.0, 2, 640.0, 15.0)]
