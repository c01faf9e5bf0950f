"""`canter bench` grids for the report pages, each archived beside its page.

A grid is one `canter bench` command. Its cells (their names, configs and checks) come from canter's own
`make_cells`, so the page's command, the run folders it archives and the table's rows cannot disagree. Each finished
run (trained to the budget and evaluated) is copied to `<page>/runs/<grid name>/<cell>__s<seed>/`: config.toml,
eval.json, metrics.csv, summary.json and versions.json, no checkpoints; the bench's curves, results.md and
statistics.json go beside them. A grid whose runs are all archived is not
run again. One that is partly archived is run whole: its archived runs are first put back into the bench folder where
that folder lacks them (a fresh machine, whose work folders are gone), so the bench skips them as finished, and it
carries on what its folder has checkpointed.

A grid that the page's --max-minutes stops is kept in the page's folder as well: `<page>/inflight/<grid name>.tar`
holds each unfinished run's folder with its newest checkpoint (archive.py's in-flight packs). It is committed with
the page, so the same command carries the runs on from a fresh clone, and it is deleted when the grid's runs have
all finished."""

from __future__ import annotations

import contextlib
import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from archive import ROOT, copy_run, has_run_files, inflight_pack, read_pack, write_pack
from timed import STOP_GRACE_SECONDS, canter_command, out_of_time, run_to_deadline

from canter.errors import CanterError
from canter.orchestrate.bench_grid import BenchSettings, Cell, make_cells
from canter.orchestrate.bench_results import combine_records, seed_record
from canter.orchestrate.run_status import read_json, run_status
from canter.training import run_lock
from canter.use.statistics import MIN_RUNS_FOR_INTERVAL, Interval, aggregates

BENCH_FILES = ("results.md", "statistics.json")


@dataclass(frozen=True)
class Grid:
    name: str  # the archive folder <page>/runs/<name>, and the bench's --out folder <work>/<name>
    env: str
    algos: tuple[str, ...]
    preset: str
    seeds: tuple[int, ...]
    total_steps: int
    axes: tuple[tuple[str, tuple[str, ...]], ...] = ()  # --grid KEY=V1,V2,...
    sets: tuple[str, ...] = ()  # --set SECTION.KEY=VALUE

    def args(self, out: str) -> list[str]:
        args = ["bench", "--algos", ",".join(self.algos), "--envs", self.env, "--preset", self.preset]
        args += ["--seeds", ",".join(map(str, self.seeds)), "--total-steps", steps_text(self.total_steps)]
        for key, values in self.axes:
            args += ["--grid", f"{key}={','.join(values)}"]
        for item in self.sets:
            args += ["--set", item]
        return [*args, "--out", out]

    def command(self, work: str) -> str:
        return "canter " + " ".join(self.args(f"{work}/{self.name}"))

    def cells(self) -> list[Cell]:
        settings = BenchSettings(
            algos=self.algos,
            envs=(self.env,),
            seeds=self.seeds,
            total_steps=self.total_steps,
            grid=self.axes,
            preset=self.preset,
            sets=self.sets,
        )
        return make_cells(settings)

    def env_steps(self) -> int:
        return len(self.cells()) * len(self.seeds) * self.total_steps


def steps_text(steps: int) -> str:
    """5000000 -> '5e6', as a person types it (canter reads both)."""
    digits, zeros = str(steps).rstrip("0"), len(str(steps)) - len(str(steps).rstrip("0"))
    return f"{digits}e{zeros}" if zeros >= 3 else str(steps)


def label(cell: Cell, cells: list[Cell]) -> str:
    """The cell's algorithm (when the grid has several) and grid values, or its algorithm alone."""
    parts = [cell.algo] if len({c.algo for c in cells}) > 1 else []
    return ", ".join(parts + [f"{key}={value}" for key, value in cell.values]) or cell.algo


def finished(folder: Path, total_steps: int) -> bool:
    summary = read_json(folder / "summary.json") or {}
    return has_run_files(folder) and summary.get("global_step", 0) >= total_steps


def archived_runs(page: Path, grid: Grid, cell: Cell) -> list[dict[str, Any]]:
    """One record per archived seed of the cell: canter bench's `seed_record` (final eval mean, wall seconds of
    every session, SPS) with the run's eval.json and summary.json added."""
    records = []
    for seed in grid.seeds:
        folder = cell.run_dir(page / "runs" / grid.name, seed)
        if finished(folder, grid.total_steps):
            record = seed_record(folder, seed)
            record.update(evaluation=read_json(folder / "eval.json"), summary=read_json(folder / "summary.json"))
            records.append(record)
    return records


def cell_result(page: Path, grid: Grid, cell: Cell) -> dict[str, Any] | None:
    """canter bench's result row for the cell (eval mean ± std over seeds, wall minutes), with the per-seed records
    under `runs`, the mean training return and rliable's interval of the mean (`mean_interval`, None for one seed);
    None until every seed of the cell is archived."""
    records = archived_runs(page, grid, cell)
    if len(records) < len(grid.seeds):
        return None
    result = combine_records(cell, records)
    result["runs"] = records
    result["train_return"] = sum(r["summary"]["recent_return"] for r in records) / len(records)
    # The same interval as the bench's statistics.json, from the same function, seed and resamples.
    scores = np.array([[r["eval_mean"]] for r in records])
    result["mean_interval"] = aggregates(scores).mean if len(records) > 1 else None
    return result


EVAL_HEADER = (
    f"eval (mean ± population std over seeds; [95% interval of the mean] from {MIN_RUNS_FOR_INTERVAL} seeds on)"
)


def eval_text(result: dict[str, Any]) -> str:
    """A cell's final evaluation as the pages show it: '1,234 ± 56', and from MIN_RUNS_FOR_INTERVAL seeds on
    '1,234 ± 56 [1,180, 1,290]', the bracket being rliable's stratified-bootstrap 95% interval of the mean over
    seeds (over 2 or 3 seeds it is their min and max, and over 4 little more); one seed's mean alone."""
    interval: Interval | None = result["mean_interval"]
    if interval is None:
        return f"{result['return_mean']:,.0f}"
    text = f"{result['return_mean']:,.0f} ± {result['return_std']:,.0f}"
    if len(result["runs"]) < MIN_RUNS_FOR_INTERVAL:
        return text
    return f"{text} [{interval.low:,.0f}, {interval.high:,.0f}]"


def curves(page: Path, grid: Grid) -> Path:
    """The bench's training curves (plot_<env>.png), archived with the runs."""
    return page / "runs" / grid.name / f"plot_{grid.env}.png"


def collect(page: Path, grid: Grid, work: Path) -> list[str]:
    """Copy each finished run of the bench folder, and its curves, into the page's archive; returns the runs
    copied."""
    copied = []
    for cell in grid.cells():
        for seed in grid.seeds:
            source = cell.run_dir(work / grid.name, seed)
            if not finished(source, grid.total_steps):
                continue
            target = cell.run_dir(page / "runs" / grid.name, seed)
            copy_run(source, target)
            copied.append(target.name)
    if copied:
        # The curves, and the bench's table and rliable statistics (IQM, mean, median with bootstrap intervals).
        for name in (curves(page, grid).name, *BENCH_FILES):
            if (work / grid.name / name).is_file():
                shutil.copyfile(work / grid.name / name, page / "runs" / grid.name / name)
    return copied


def restore(page: Path, grid: Grid, work: Path) -> list[str]:
    """Copy each archived run into the bench folder where that folder has no run of its own, so the bench skips it
    instead of training it again; returns the runs restored. A run folder the bench already has is left as it is."""
    restored = []
    for cell in grid.cells():
        for seed in grid.seeds:
            source = cell.run_dir(page / "runs" / grid.name, seed)
            target = cell.run_dir(work / grid.name, seed)
            if finished(source, grid.total_steps) and not target.exists():
                shutil.copytree(source, target)
                restored.append(target.name)
    return restored


@contextlib.contextmanager
def writers_done(folders: list[Path], grace: float = STOP_GRACE_SECONDS) -> Iterator[None]:
    """Hold the writer lock of every existing run folder in `folders`, waiting up to `grace` seconds for processes
    still writing them: a stopped `canter bench` ends at once, and its jobs write their last checkpoints after."""
    end, taken = time.monotonic() + grace, []
    try:
        for folder in (f for f in folders if f.is_dir()):
            while True:
                try:
                    run_lock.acquire(folder)
                except CanterError:
                    if time.monotonic() > end:
                        raise SystemExit(f"{folder}: still written by another process after {grace:.0f} s") from None
                    time.sleep(0.5)
                    continue
                taken.append(folder)
                break
        yield
    finally:
        for folder in taken:
            run_lock.release(folder)


def pack_inflight(page: Path, grid: Grid, work: Path) -> list[str]:
    """Write the grid's in-flight pack from the bench folder's unfinished, checkpointed runs (once their jobs have
    stopped writing them), or delete it when there are none or it would be too large; returns the runs packed."""
    folders = [cell.run_dir(work / grid.name, seed) for cell in grid.cells() for seed in grid.seeds]
    with writers_done(folders):
        return _pack(page, grid, work)


def _pack(page: Path, grid: Grid, work: Path) -> list[str]:
    runs = [
        cell.run_dir(work / grid.name, seed)
        for cell in grid.cells()
        for seed in grid.seeds
        if _carried_on(cell.run_dir(work / grid.name, seed), grid.total_steps, cell.config.run.stop_at_return)
    ]
    path = inflight_pack(page, grid.name)
    if not runs:
        path.unlink(missing_ok=True)
        return []
    if not write_pack(path, work / grid.name, runs):
        print(f"{grid.name}: its runs are too large to keep; a fresh machine starts them again", flush=True)
        return []
    return [r.name for r in runs]


def _carried_on(run_dir: Path, total_steps: int, stop_at_return: float | None) -> bool:
    """Whether a run is one the next call carries on: stopped after a checkpoint, or ended without its summary."""
    try:
        return run_status(run_dir, total_steps, stop_at_return) in ("partial", "ended")
    except CanterError as exc:  # trained past the grid's budget by hand: not the grid's to pack
        print(f"{run_dir.name}: not packed ({exc})", flush=True)
        return False


def run_grid(page: Path, grid: Grid, work: Path) -> None:
    """Run the grid's bench command (unless every run is archived), one job at a time, then archive its runs."""
    cells = grid.cells()
    if all(len(archived_runs(page, grid, cell)) == len(grid.seeds) for cell in cells):
        print(f"{grid.name}: archived already", flush=True)
        inflight_pack(page, grid.name).unlink(missing_ok=True)
        return
    if out_of_time(grid.name):
        return
    restored = restore(page, grid, work)
    if restored:
        print(f"{grid.name}: restored {len(restored)} archived runs into {work / grid.name}", flush=True)
    unpacked = read_pack(inflight_pack(page, grid.name), work / grid.name)
    if unpacked:
        print(f"{grid.name}: carrying on {len(unpacked)} runs from {inflight_pack(page, grid.name)}", flush=True)
    command = [*canter_command(), *grid.args(str(work / grid.name))]
    print(f"{grid.name}: $ canter {' '.join(command[len(canter_command()) :])}", flush=True)
    code, stopped = run_to_deadline(command, cwd=ROOT)
    print(f"{grid.name}: archived {len(collect(page, grid, work))} runs", flush=True)
    packed = pack_inflight(page, grid, work)
    if packed:
        print(f"{grid.name}: {len(packed)} unfinished runs kept in {inflight_pack(page, grid.name)}", flush=True)
    if stopped:
        print(f"{grid.name}: stopped at --max-minutes, checkpointed; the same command carries it on", flush=True)
    elif code != 0:
        raise SystemExit(f"{grid.name}: canter bench exited {code}")
