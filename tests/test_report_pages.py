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
    name = f"report_page_{script.parent.name[:3]}"
    spec = importlib.util.spec_from_file_location(name, script)
    assert spec and spec.loader
    page = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, name, page)  # dataclasses look their module up there
    spec.loader.exec_module(page)
    monkeypatch.setattr(sys, "argv", [str(script), "--check"])
    assert page.main() == 0, capsys.readouterr().err
