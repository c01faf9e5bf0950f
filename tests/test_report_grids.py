"""A report page's bench grid survives the loss of its work folder: on a fresh machine the runs it archived go back
into the bench folder and are skipped, the runs its deadline stopped carry on from the page's in-flight pack, and
only what it never trained is trained. Real `canter bench` runs on InvertedPendulum-v4, a few hundred steps each."""

import json
import shutil
import subprocess
import sys
import tarfile
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks" / "reports"))

import archive
import grids
from archive import inflight_pack

TINY = ("net.hidden=16,16", "run.tensorboard=false", "env.num_envs=4", "ppo.n_steps=128", "ppo.minibatch_size=256")
TINY += ("ppo.epochs=1",)


def grid(ent_coefs: tuple[str, ...]) -> grids.Grid:
    return grids.Grid("g", "InvertedPendulum-v4", ("ppo",), "fast", (0,), 512, (("ppo.ent_coef", ent_coefs),), TINY)


@pytest.mark.slow  # trains in child processes
def test_archived_runs_are_restored_and_skipped_and_the_rest_trained(tmp_path, capfd):
    page, work = tmp_path / "page", tmp_path / "work"
    first = grid(("0",))
    grids.run_grid(page, first, work)
    [cell] = first.cells()
    archived = cell.run_dir(page / "runs" / "g", 0)
    summary = json.loads((archived / "summary.json").read_text())
    assert summary["global_step"] >= 512 and (archived / "eval.json").is_file()

    shutil.rmtree(work)  # a fresh machine: the bench folder, checkpoints included, is gone
    capfd.readouterr()
    both = grid(("0", "0.01"))
    grids.run_grid(page, both, work)
    out = capfd.readouterr().out
    assert "g: restored 1 archived runs" in out
    assert f"skip {cell.name} (finished)" in out
    assert not (cell.run_dir(work / "g", 0) / "checkpoints").exists()  # restored, not trained again
    assert json.loads((archived / "summary.json").read_text()) == summary
    assert all(len(grids.archived_runs(page, both, c)) == 1 for c in both.cells())
    assert grids.restore(page, both, work) == []  # the bench folder has every run now


@pytest.mark.slow  # trains in child processes
def test_a_grid_stopped_before_its_budget_is_carried_on_from_its_pack_on_a_fresh_machine(tmp_path, capfd):
    page, work = tmp_path / "page", tmp_path / "work"
    # run.max_minutes under a second: each bench call trains one iteration (at most 512 steps), then stops.
    stopping = grids.Grid("g", "InvertedPendulum-v4", ("ppo",), "fast", (0,), 700, (), (*TINY, "run.max_minutes=1e-4"))
    with pytest.raises(SystemExit, match="canter bench exited"):
        grids.run_grid(page, stopping, work)
    pack = inflight_pack(page, "g")
    with tarfile.open(pack) as tar:
        names = set(tar.getnames())
    run = "InvertedPendulum-v4__ppo__s0"
    [packed] = [n for n in names if n.startswith(f"{run}/checkpoints/ckpt_")]
    packed_step = int(packed.removesuffix(".npz").rpartition("_")[2])
    assert 0 < packed_step < 700 and {f"{run}/config.toml", f"{run}/metrics.csv"} <= names
    assert not any("/tb/" in n or n.endswith(".writer.lock") for n in names)

    shutil.rmtree(work)  # a fresh clone: only the page's files are left
    capfd.readouterr()
    grids.run_grid(page, stopping, work)
    assert "g: carrying on 1 runs" in capfd.readouterr().out
    [cell] = stopping.cells()
    [record] = grids.archived_runs(page, stopping, cell)
    steps = [line.split(",")[0] for line in (cell.run_dir(page / "runs" / "g", 0) / "metrics.csv").read_text().split()]
    # Resumed from the pack's checkpoint, not trained again from 0 (which would stop short of 700 once more).
    assert steps[1] == str(packed_step) and int(steps[-1]) == record["summary"]["global_step"] >= 700
    assert not pack.exists()  # finished: nothing is in flight


def test_a_page_computes_the_interval_the_bench_archived_and_shows_it_from_five_seeds_on():
    page = Path(grids.ROOT) / "benchmarks" / "reports" / "000-humanoidstandup-halfcheetah-ppo-rpo-sym"
    hs_ppo = grids.Grid(
        "hs-ppo",
        "HumanoidStandup-v4",
        ("ppo",),
        "report000-humanoidstandup",
        (100, 101, 102),
        5_000_000,
        sets=("sym.coef=0",),
    )
    [cell] = hs_ppo.cells()
    result = grids.cell_result(page, hs_ppo, cell)
    [archived] = json.loads((page / "runs" / "hs-ppo" / "statistics.json").read_text())["cells"]
    mean = archived["return"]["mean"]
    assert result["mean_interval"].low == pytest.approx(mean["low"])
    assert result["mean_interval"].high == pytest.approx(mean["high"])
    # Three seeds: the bootstrap interval of the mean is their min and max, so the page leaves it out.
    assert (mean["low"], mean["high"]) == (min(result["seed_returns"]), max(result["seed_returns"]))
    assert grids.eval_text(result) == "192,660 ± 25,478"
    five = dict(result, runs=result["runs"] * 2)
    assert grids.eval_text(five) == f"192,660 ± 25,478 [{mean['low']:,.0f}, {mean['high']:,.0f}]"


def test_a_pack_keeps_the_newest_and_best_checkpoints_and_no_more_than_its_limit(tmp_path, monkeypatch):
    run = tmp_path / "work" / "run"
    for name in ("checkpoints/ckpt_000000000001.npz", "checkpoints/ckpt_000000000002.npz", "checkpoints/best.npz"):
        (run / name).parent.mkdir(parents=True, exist_ok=True)
        (run / name).write_bytes(b"x" * 600)
    for name in ("config.toml", "tb/events", ".writer.lock"):
        (run / name).parent.mkdir(parents=True, exist_ok=True)
        (run / name).write_text(name)
    pack = tmp_path / "page" / "inflight" / "run.tar"
    assert archive.write_pack(pack, run.parent, [run])
    with tarfile.open(pack) as tar:
        names = sorted(tar.getnames())
    assert names == ["run/checkpoints/best.npz", "run/checkpoints/ckpt_000000000002.npz", "run/config.toml"]

    fresh = tmp_path / "fresh"
    assert archive.read_pack(pack, fresh) == ["run"]
    assert (fresh / "run" / "checkpoints" / "best.npz").read_bytes() == b"x" * 600
    assert archive.read_pack(pack, fresh) == []  # what the folder has is kept

    monkeypatch.setattr(archive, "PACK_LIMIT_BYTES", 1000)  # a tar of these files is over 1,000 bytes
    assert not archive.write_pack(pack, run.parent, [run])
    assert not pack.exists() and not pack.with_name("run.tar.partial").exists()


HOLD_AND_WRITE = """
import shutil, sys, time
from pathlib import Path
from canter.training import run_lock
run, newer = Path(sys.argv[1]), sys.argv[2]
run_lock.acquire(run)
print("held", flush=True)
time.sleep(2.0)  # a job that got SIGTERM as its bench ended, finishing its iteration
[last] = sorted((run / "checkpoints").glob("ckpt_*.npz"))
shutil.copyfile(last, run / "checkpoints" / newer)
"""


@pytest.mark.slow  # trains in child processes
def test_the_pack_waits_for_jobs_still_writing_their_last_checkpoint(tmp_path):
    page, work = tmp_path / "page", tmp_path / "work"
    stopping = grids.Grid("g", "InvertedPendulum-v4", ("ppo",), "fast", (0,), 700, (), (*TINY, "run.max_minutes=1e-4"))
    with pytest.raises(SystemExit, match="canter bench exited"):
        grids.run_grid(page, stopping, work)
    [cell] = stopping.cells()
    run = cell.run_dir(work / "g", 0)
    newer = "ckpt_000000000699.npz"  # past the stopped run's step, short of its budget
    with subprocess.Popen(
        [sys.executable, "-c", HOLD_AND_WRITE, str(run), newer], stdout=subprocess.PIPE, text=True
    ) as writer:
        assert writer.stdout is not None and writer.stdout.readline().strip() == "held"
        started = time.monotonic()
        assert grids.pack_inflight(page, stopping, work) == [run.name]
        assert time.monotonic() - started > 1.0  # it waited for the writer
    with tarfile.open(inflight_pack(page, "g")) as tar:
        assert f"{run.name}/checkpoints/{newer}" in tar.getnames()


def test_a_pack_carries_a_run_that_ended_without_its_summary_and_skips_one_trained_past_the_grid(tmp_path, capsys):
    import numpy as np

    from canter.config.build import build_config
    from canter.config.serialize import to_toml
    from canter.training import checkpoint, run_folder

    def saved(run, step, budget):
        header = {"global_step": step, "config": to_toml(build_config("Hopper-v5", total_steps=budget))}
        checkpoint.save(run_folder.checkpoint_path(run, step), {"x": np.zeros(1)}, header)

    ended, past = tmp_path / "ended", tmp_path / "past"
    saved(ended, 512, 512)  # its final checkpoint, and no summary.json
    saved(past, 4096, 8192)
    assert grids._carried_on(ended, 512, None)
    assert not grids._carried_on(past, 512, None)
    assert "past: not packed (" in capsys.readouterr().out
