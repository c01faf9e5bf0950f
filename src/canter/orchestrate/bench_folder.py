"""Who works on a bench's --out folder: one local bench alone, or any number of workers of one grid shared through
--storage, never both at once. Each trains the run folders of the folder's cells and writes its results files, so
a local bench beside a shared grid's worker would fail the jobs the other one holds and overwrite its tables.

Both lock the folder's writer lock file (`canter.training.run_lock`): a local bench holds the exclusive writer lock,
a worker of a shared grid a shared flock on the same file, which the grid's other workers share with it. A worker
records itself in the file as a writer does, with the storage it shares the grid through, so that a refused local
bench names it.

A folder that another command writes is no bench folder: a run folder, and a study folder of `canter tune` or the
--out-dir that holds its study folders, are refused as --out (`refuse_run_or_study_folder`), as tune refuses a bench
folder (`bench_files_in`); `canter.orchestrate.study.study_files_in` tells a study folder.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from canter.errors import CanterError, joined
from canter.files import WriteError, is_write_error
from canter.orchestrate.study import redacted, study_files_in
from canter.run_layout import surely_a_run
from canter.training import run_lock
from canter.training.resume import NEW_RUN_DIR

STORAGE_KEY = "storage"  # in the lock file's record: a worker of a shared grid, not a local bench
CELLS_FOLDER = ".cells"  # each job's job.json and train.log (`bench_local`, `bench_distributed`)


def bench_files_in(folder: Path) -> list[str]:
    """What marks `folder` as a bench's --out folder: its jobs' .cells/ folder, its tables, or a writer lock that a
    bench took; empty for any other folder. A results.md alone may be the user's own notes, so the tables count only
    together with results.csv."""
    from canter.orchestrate.bench_results import RESULT_FILES, RESULTS_CSV, RESULTS_TABLE

    folder = Path(folder)
    held = [f"{CELLS_FOLDER}/"] * (folder / CELLS_FOLDER).is_dir()
    tables = [name for name in RESULT_FILES if (folder / name).is_file()]
    if {RESULTS_TABLE, RESULTS_CSV} <= set(tables):
        held += tables
    holder = run_lock.read_holder(folder)
    if STORAGE_KEY in holder or str(holder.get("command", "")).split()[:2] == ["canter", "bench"]:
        held.append(f"a bench's {run_lock.LOCK_FILE}")
    return held


def refuse_run_or_study_folder(bench_dir: Path) -> None:
    """Refuse a run folder or tune's folders given as --out: the bench would write its tables and job folders among
    the run's files, and take over the writer lock of the run (its own lock file, `canter.training.run_lock`), or
    write them beside a study's database and trials."""
    from canter.run_layout import CHECKPOINT_FOLDER, RUN_OWN_FILES, run_files_in

    # A config.toml alone may be the user's own base config for the bench (--config OUT/config.toml); a bench folder
    # never holds a checkpoints/ folder of its own.
    found = run_files_in(bench_dir)
    held = sorted(found & RUN_OWN_FILES) + ["checkpoints/"] * (bench_dir / CHECKPOINT_FOLDER).exists()
    if surely_a_run(bench_dir) or (bench_dir / CHECKPOINT_FOLDER).exists():
        raise CanterError(
            f"--out {bench_dir} is a run folder (it holds {' and '.join(held)}), not a bench folder; give a new "
            f"--out, in which the bench makes a run folder for each cell and seed"
        )
    _refuse_tune_folder(bench_dir)


def refuse_as_run_dir(run_dir: str | Path) -> None:
    """Refuse a bench's --out folder, or a study folder of tune, given as a new run's run_dir=: the run would write
    its files among the bench's or the study's, which would then read its config.toml and checkpoints as their own.
    A folder of runs is refused for the new run already (`canter.training.resume`); these may hold none yet."""
    run_dir = Path(run_dir)
    if surely_a_run(run_dir):  # refused as a run (its lock may name the bench that trained it)
        return
    kinds = {
        "a bench's --out folder": bench_files_in(run_dir),
        "a study folder of canter tune": study_files_in(run_dir),
    }
    for kind, held in kinds.items():
        if held:
            raise CanterError(f"{run_dir} is {kind} (it holds {joined(held)}); {NEW_RUN_DIR}")


def _refuse_tune_folder(bench_dir: Path) -> None:
    """Refuse a study folder of `canter tune`, or its --out-dir, given as --out."""
    study = study_files_in(bench_dir)
    if study:
        raise CanterError(
            f"--out {bench_dir} is a study folder of canter tune (it holds {' and '.join(study)}), not a bench "
            f"folder; give a new --out, in which the bench makes a run folder for each cell and seed"
        )
    if not bench_dir.is_dir():
        return
    studies = sorted(p.name for p in bench_dir.iterdir() if p.is_dir() and study_files_in(p))
    if studies:
        shown = ", ".join(f"{name}/" for name in studies[:3]) + (
            f" and {len(studies) - 3} more" if len(studies) > 3 else ""
        )
        raise CanterError(
            f"--out {bench_dir} is an --out-dir of canter tune (it holds the study folder{'s' * (len(studies) > 1)} "
            f"{shown}), not a bench folder; give a new --out, in which the bench makes a run folder for each cell "
            f"and seed"
        )


def _who(holder: dict[str, Any]) -> str:
    return f" (process {holder.get('pid')} on {holder.get('host')}: {holder.get('command')})" if holder else ""


@contextlib.contextmanager
def holding_bench_folder(bench_dir: Path) -> Iterator[None]:
    """A local bench holds its --out folder's writer lock while it runs: a second one on the same folder would fail
    each cell the first one trains, with the first one's lock error, and write a table of the rest; and so would a
    worker of a grid shared through --storage (`sharing_bench_folder`)."""
    try:
        run_lock.acquire(bench_dir)
    except WriteError:  # a full or read-only disk, not another bench
        raise
    except CanterError:
        holder = run_lock.read_holder(bench_dir)
        if STORAGE_KEY in holder:
            raise CanterError(
                f"{bench_dir} is in use by a bench that shares its grid through --storage {holder[STORAGE_KEY]}"
                f"{_who(holder)}; wait for it to finish, or run this command with the same --storage to share the grid"
            ) from None
        raise CanterError(
            f"{bench_dir} is in use by another bench{_who(holder)}; wait for it to finish, or run both with --storage "
            f"to share the grid between them"
        ) from None
    try:
        yield
    finally:
        run_lock.release(bench_dir)


@contextlib.contextmanager
def sharing_bench_folder(bench_dir: Path, storage_url: str) -> Iterator[None]:
    """A worker of a grid shared through --storage holds a shared flock on the folder's writer lock file while it
    runs: the grid's other workers take it too, on this machine or another, and a local bench on the folder refuses
    it and is refused."""
    fd = run_lock.open_lock_file(bench_dir)
    try:
        if not _share(fd, bench_dir):
            holder = run_lock.read_holder(bench_dir)
            raise CanterError(
                f"{bench_dir} is in use by a bench without --storage{_who(holder)}; wait for it to finish, or stop "
                f"it and run both with --storage to share the grid between them"
            )
        hidden = redacted(storage_url)
        command = run_lock.command_line().replace(storage_url, hidden)
        try:
            # One live worker's record names the grid; the others leave it whole rather than write over it at once.
            holder = run_lock.read_holder(bench_dir)
            if STORAGE_KEY not in holder or not run_lock.alive_here(holder):
                run_lock.write_holder(fd, command=command, **{STORAGE_KEY: hidden})
        except OSError as exc:
            if is_write_error(exc):
                raise WriteError(bench_dir / run_lock.LOCK_FILE, exc) from None
            raise
        yield
    finally:
        os.close(fd)  # releases the flock


def _share(fd: int, bench_dir: Path) -> bool:
    """Take the shared flock; False while a local bench holds the folder."""
    shared = run_lock.flock(fd, shared=True)
    if shared is None:
        # Without flock only the record tells: a local bench alive on this host, or one on another, which cannot be
        # checked from here and counts as alive, as it does for a run folder's writer lock.
        holder = run_lock.read_holder(bench_dir)
        return STORAGE_KEY in holder or not run_lock.alive_here(holder)
    return shared
