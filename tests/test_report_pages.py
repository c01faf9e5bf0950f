"""Every report page's tables are what its archive gives: each benchmarks/reports/*/run.py --check, in this process
(no training, no child processes)."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from canter.algos.ppo.symmetry import parse_groups
from canter.errors import CanterError

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


def _limbs(monkeypatch):
    """Page 000's limb measures (limbs.py), which only that page uses."""
    return _load_page(REPORTS / "000-humanoidstandup-halfcheetah-ppo-rpo-sym" / "run.py", monkeypatch).limbs


def test_effort_asymmetry_hand_values(monkeypatch):
    limbs = _limbs(monkeypatch)
    pairs = parse_groups("0:2=2:4,4=5", negate=(3,))
    actions = np.array([[1.0, 1.0, 0.5, -0.5, 0.0, 0.0], [1.0, 1.0, -0.5, 0.5, 0.0, 0.0]])
    legs, still = limbs.effort_asymmetry(actions, pairs)
    # Left: mean square 1.0; right: 0.25, whatever the signs: (1 - 0.25) / 1.25.
    assert legs == pytest.approx(0.6) and still == 0.0
    assert limbs.effort_asymmetry(np.array([[0.3, -0.2, 0.2, 0.3, 0.4, 0.0]]), pairs) == pytest.approx((0.0, 1.0))


def test_effort_asymmetry_rejects_bad_shapes(monkeypatch):
    limbs = _limbs(monkeypatch)
    pairs = parse_groups("0=1")
    with pytest.raises(CanterError, match=r"shaped \[steps, act_dim\]"):
        limbs.effort_asymmetry(np.zeros(2), pairs)
    with pytest.raises(CanterError, match="out of the action range"):
        limbs.effort_asymmetry(np.zeros((3, 1)), pairs)


def test_mirror_mismatch_hand_values(monkeypatch):
    limbs = _limbs(monkeypatch)
    pairs = parse_groups("0:2=2:4", negate=(3,))
    mirrored = np.array([[0.5, -1.0, 0.5, 1.0], [2.0, 3.0, 2.0, -3.0]])
    assert limbs.mirror_mismatch(mirrored, pairs) == (0.0,)
    assert limbs.mirror_mismatch(-mirrored * np.array([1, 1, -1, -1]), pairs) == pytest.approx((2.0,))  # opposite
    # Row 1: L (1, 0), sR (0, 1): gap 2; row 2: L (1, 1), sR (1, 1): gap 0. Energies: L 1 + 2, R 1 + 2 (means 1.5).
    actions = np.array([[1.0, 0.0, 0.0, -1.0], [1.0, 1.0, 1.0, -1.0]])
    assert limbs.mirror_mismatch(actions, pairs) == pytest.approx((1.0 / 3.0,))
    assert limbs.mirror_mismatch(np.zeros((2, 4)), pairs) == (0.0,)
    with pytest.raises(CanterError, match="mirror_mismatch needs actions"):
        limbs.mirror_mismatch(np.zeros(4), pairs)


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


def test_provenance_groups_runs_by_commit_machine_and_versions_with_their_days(tmp_path):
    import json

    sys.path.insert(0, str(REPORTS.parent))
    from archive import provenance_table

    def run(name, created=None, log=None, **versions):
        folder = tmp_path / name
        folder.mkdir(parents=True)
        base = {"canter_commit": None, "canter_dirty": None, "cpu": "AMD EPYC", "cpu_count": 2, "gpu": None}
        base |= {"jax": "0.10.2", "envpool": "1.2.5", "mujoco": "3.6.0"} | versions
        (folder / "versions.json").write_text(json.dumps(base | ({"created": created} if created else {})))
        if log:
            (folder / "train.log").write_text(log)

    sha = "0123456789abcdef0123456789abcdef01234567"
    run("grid/Hopper-v5__ppo__s0", created="2026-11-29T10:00:00Z", canter_commit=sha, canter_dirty=False)
    run("grid/Hopper-v5__ppo__s1", created="2026-11-30T01:00:00Z", canter_commit=sha, canter_dirty=False)
    run(
        "renamed",
        log="run: /x/Hopper-v5__ppo__fast__s100__20261126-182911-42f3\n",
        canter_commit=sha,
        canter_dirty=True,
    )
    run("old/Hopper-v5__ppo__s2")
    run("gpu", created="2026-11-27T00:00:00Z", canter_commit=sha, canter_dirty=False, gpu="NVIDIA H200", jax="0.11.2")
    platform = "Linux-6.18.44-fc-v669-x86_64-with-glibc2.36"
    run("other", created="2026-11-28T00:00:00Z", canter_commit=sha, canter_dirty=False, platform=platform)
    libraries = "jax 0.10.2, envpool 1.2.5, mujoco 3.6.0"
    assert provenance_table([tmp_path, tmp_path / "missing"]).splitlines() == [
        "| canter commit | runs | trained | machine | versions |",
        "|---|---:|---|---|---|",
        f"| not recorded (runs before 2026-11-26) | 1 | not recorded | AMD EPYC, 2 cores | {libraries} |",
        f"| 0123456 with uncommitted changes | 1 | 2026-11-26 | AMD EPYC, 2 cores | {libraries} |",
        "| 0123456 | 1 | 2026-11-27 | AMD EPYC, 2 cores, NVIDIA H200 | jax 0.11.2, envpool 1.2.5, mujoco 3.6.0 |",
        f"| 0123456 | 1 | 2026-11-28 | AMD EPYC, 2 cores, `Linux-6.18.44-fc-v669` | {libraries} |",
        f"| 0123456 | 2 | 2026-11-29 to 2026-11-30 | AMD EPYC, 2 cores | {libraries} |",
    ]
