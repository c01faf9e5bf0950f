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
