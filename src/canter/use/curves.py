"""A run folder's logged curves: the numeric columns of its metrics.csv, read with messages that say why a file
cannot be read (a folder in its place, missing, damaged, no rows yet) and what to do."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from canter.config.schema import Config
from canter.errors import CanterError
from canter.files import refuse_not_regular
from canter.training.logger import lost_rows, read_table, run_history
from canter.training.run_folder import list_checkpoints, metrics_file, read_config, step_of


@dataclass(frozen=True)
class RunCurves:
    run_dir: Path
    config: Config
    columns: dict[str, np.ndarray]  # numeric metrics.csv columns, NaN where a row has no value


def _no_rows(path: Path) -> str:
    """Why a metrics.csv without rows has none, and what to do: a run that trained an iteration has logged one."""
    run = path.parent
    checkpoints = list_checkpoints(run)
    newest = step_of(checkpoints[-1]) if checkpoints else 0
    if newest > 0:
        return lost_rows(path, newest)
    # A run stopped in setup or in its first iteration (a signal, a non-finite start) has at most a step-0 checkpoint.
    go_on = f"train it on with canter train --resume {run}" if checkpoints else "train it again"
    return (
        f"{path} has no logged rows: the run has not finished an iteration (it is compiling, or it stopped before its "
        f"first one); leave it out, or {go_on}"
    )


def read_metrics(path: Path) -> dict[str, np.ndarray]:
    """The numeric columns of a metrics.csv; empty cells become NaN, columns with text are left out."""
    path = Path(path)
    refuse_not_regular(path)  # a folder in the file's place: sending the user to another run folder misleads
    if not path.is_file():
        from canter.training.checkpoint import refuse_a_folder_of_runs

        refuse_a_folder_of_runs(path.parent)
        # plot and report both read curves here, so the message names no command.
        raise CanterError(f"no metrics.csv in {path.parent}; pass a run folder written by `canter train`")
    table = read_table(path)  # a half-written last line is left out
    header = table.header
    if header and "global_step" not in header:
        raise CanterError(
            f"{path} has no global_step column in its first line, so it is not a metrics file canter wrote, or it "
            f"was edited or damaged; restore it from a copy"
        )
    if not header or not table.rows:
        raise CanterError(_no_rows(path))
    if table.unreadable:
        line, cell = table.unreadable[0]
        raise CanterError(
            f"{path} has a row whose global_step is {cell!r} (line {line}), not a step: the file was edited or "
            f"damaged; delete that row or restore the file from a copy"
        )
    positions = table.positions
    numbers, text = table.numbers, {column for column, _ in table.text}
    if "iteration" in header:  # a format-1 run may hold rows of work lost before a resume
        history = run_history(table)
        kept = np.zeros(table.rows, dtype=bool)
        kept[history.rows] = True
        text = {column for column, row in table.text if kept[row]}
        if len(history.rows) < table.rows:
            numbers = numbers[:, history.rows]
        if "wall_time" in positions:  # counted from the run's start, to the millisecond, as a resume writes it
            numbers[positions["wall_time"]] = [float(f"{wall:.3f}") for wall in history.wall_seconds.tolist()]
            text.discard(positions["wall_time"])
    return {name: numbers[at] for name, at in positions.items() if at not in text}


def load_run(run_dir: str | Path) -> RunCurves:
    run_dir = Path(run_dir)
    if run_dir.is_file():
        raise CanterError(
            f"{run_dir} is a file, not a run folder; pass the folder that holds config.toml and metrics.csv"
        )
    if not run_dir.is_dir():
        raise CanterError(f"run folder not found: {run_dir}")
    columns = read_metrics(metrics_file(run_dir))
    return RunCurves(run_dir, read_config(run_dir), columns)
