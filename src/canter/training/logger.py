"""Metric outputs: metrics.csv (stable columns that plot and bench read) and TensorBoard events.

metrics.csv has one row per iteration. Columns:
- `global_step`: env steps so far (autoreset steps excluded); `iteration`; `wall_time`: seconds the run has taken
  so far, compile included, summed over its resumed sessions; `sps`: steps per second over this iteration,
  compile excluded.
- `episodes`, `episodic_return`, `episodic_length`: episodes finished in this iteration and their mean raw return
  and length (empty when none finished).
- then the algorithm's diagnostics, in the order of its `metric_names`. For ppo: `policy_loss`, `value_loss`,
  `entropy`, `approx_kl`, `clip_frac`, `grad_norm`, `grad_norm_max`, `explained_variance`, `learning_rate`,
  `epochs_run`, `policy_kl`, `kl_beta`, `sym_loss` (the losses, KL, clip fraction and `grad_norm` are means over
  the iteration's minibatch steps; `grad_norm_max` is the largest step's norm).
- `info/<key>`: per-episode reward terms the env reports (sums for reward/cost terms, per-step means otherwise).
- with `run.eval_every` > 0, `eval/return_mean`, `eval/return_std`, `eval/length_mean`, `eval/episodes`: the
  evaluation during training after this iteration (`canter.training.evaluation`), empty in rows without one.

A row is appended as one whole line or not at all (`canter.files.AppendFile`). A file from a process killed in
the middle of a line (an older canter, or a disk that failed during the write) can end in a half-written line;
readers skip it (`read_rows`), and the next logger cuts it off.

Values computed in float32 are written as the shortest decimal that reads back as the same float32 (`logged`):
float64's repr of a float32 carries eight or nine more digits, all noise, which would double the file.
"""

from __future__ import annotations

import csv
import gzip
import io
import itertools
import math
import os
import sys
from array import array
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from canter.errors import CanterError
from canter.files import AppendFile, atomic_write_bytes, refuse_not_regular
from canter.run_layout import METRICS_FILE, TENSORBOARD_FOLDER
from canter.training.evaluation import EVAL_COLUMNS

BASE_COLUMNS = ("global_step", "iteration", "wall_time", "sps", "episodes", "episodic_return", "episodic_length")


def columns_for(metric_names: tuple[str, ...], info_keys: tuple[str, ...], evaluates: bool = False) -> list[str]:
    evaluation = list(EVAL_COLUMNS) if evaluates else []
    return list(BASE_COLUMNS) + list(metric_names) + [f"info/{k}" for k in info_keys] + evaluation


def logged(value: Any) -> float:
    """A metric as a Python float for a metrics.csv row: a float32 one as its shortest round-tripping decimal."""
    array = np.asarray(value)
    if array.dtype == np.float32:
        return float(str(array[()]))
    return float(array)


def _whole_lines(path: Path) -> bytes:
    """A file's bytes up to its last newline: a half-written last line is left out. A .gz file is read unpacked."""
    try:
        data = gzip.decompress(path.read_bytes()) if path.suffix == ".gz" else path.read_bytes()
    except (gzip.BadGzipFile, EOFError) as exc:
        raise CanterError(f"{path} is not a whole gzip file ({exc}); restore it from a copy, or move it away") from None
    return data[: data.rfind(b"\n") + 1]


def lost_rows(path: Path, step: int) -> str:
    """Why the metrics.csv of a run with a checkpoint at `step` > 0 has no rows, though each iteration logs one before
    its checkpoint: it was emptied or damaged. Only a copy gives its history back."""
    return (
        f"{path} has no logged rows, though the run has a checkpoint at step {step:,}: the file was emptied or "
        f"damaged; restore it from a copy"
    )


def _text_lines(path: Path) -> Iterator[str]:
    """The lines of a metrics.csv (read a line at a time) or an archived metrics.csv.gz, as text, up to its last
    newline: a half-written last line is left out."""
    # utf-8-sig: a spreadsheet that saved the file may have put a byte-order mark before the first column's name.
    if path.suffix == ".gz":  # an archived copy: small, and read whole
        source: IO[str] = io.StringIO(_whole_lines(path).decode("utf-8-sig", errors="replace"), newline="")
    else:
        source = open(path, encoding="utf-8-sig", errors="replace", newline="")  # noqa: SIM115 (closed below)
    with source:
        line_number, pending = 1, []
        for line in source:
            pending.append(line)
            if not line.endswith("\n"):  # a line that ends in a lone \r, or the half-written last line
                continue
            for whole in pending:
                # NUL bytes (a block that a crash or a bad copy zeroed) can replace a line's end, so that two rows
                # read as one: not a file canter wrote, and rows would be lost without a word.
                if "\0" in whole:
                    raise _damaged(path, f"NUL bytes on line {line_number}")
                line_number += whole.count("\n")
                yield whole
            pending.clear()


def _positions(header: list[str]) -> dict[str, int]:
    """Where each column of a header is; a name the header repeats reads from its last column, as a csv.DictReader
    row does."""
    return {name: at for at, name in enumerate(header)}


def _records(path: Path) -> Iterator[list[str]]:
    """The header of a metrics.csv or an archived metrics.csv.gz (none for a missing file), then the cells of each
    row that has a global_step, without a half-written last line."""
    path = Path(path)
    refuse_not_regular(path)
    if not path.is_file():
        return
    lines = _text_lines(path)
    reader = csv.reader(lines)
    try:
        header = next(reader, [])
        yield header
        step = _positions(header).get("global_step")
        for row in reader:
            if len(row) > len(header):
                raise csv.Error(f"line {reader.line_num} has more cells than the header names")
            if step is not None and step < len(row) and row[step]:
                yield row
    except csv.Error as exc:  # also a field past the csv module's limit: not a file canter wrote
        for _ in lines:  # NUL bytes further on are named instead, as when the whole text was looked at first
            pass
        raise _damaged(path, str(exc)) from None


def read_rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    """The header and the rows of a metrics.csv or an archived metrics.csv.gz (none for a missing file), without a
    half-written last line. A row's cells past its end read as None. `read_table` reads large files."""
    records = _records(Path(path))
    header = next(records, [])
    rows = []
    for row in records:
        cells: dict[str, Any] = dict(zip(header, row))
        cells.update(dict.fromkeys(header[len(row) :]))  # None, as csv.DictReader gives
        rows.append(cells)
    return header, rows


@dataclass(frozen=True)
class Table:
    """The rows `read_rows` reads, by column: one float64 array holds every cell as a number, far less memory than a
    dict of strings per row."""

    header: list[str]
    numbers: np.ndarray  # one row per header column: `cell_number` of its cell in each row (NaN past a row's end)
    text: list[tuple[int, int]]  # (column, row) of each cell that holds text that is not a number
    unreadable: list[tuple[int, str]]  # (line, cell) of each row whose global_step is not a finite number
    cells: dict[str, list[str]]  # the cells as written, of the columns read_table was asked to keep so

    @property
    def rows(self) -> int:
        return int(self.numbers.shape[1])

    @property
    def positions(self) -> dict[str, int]:
        """Which row of `numbers` holds each column (`_positions`)."""
        return _positions(self.header)

    def column(self, name: str) -> np.ndarray:
        """A column's numbers; NaN for a column the header does not name."""
        at = self.positions.get(name)
        return self.numbers[at] if at is not None else np.full(self.rows, math.nan)


def read_table(path: Path, cells: tuple[str, ...] = ()) -> Table:
    """The rows of a metrics.csv or an archived metrics.csv.gz that `read_rows` reads, read by column in one pass,
    keeping the cells as written of the columns named in `cells`."""
    records = _records(Path(path))
    header = next(records, [])
    width, positions = len(header), _positions(header)
    step = positions.get("global_step", 0)  # a file without one has no rows
    kept = {name: positions[name] for name in cells if name in positions}
    written: dict[str, list[str]] = {name: [] for name in kept}
    blocks: list[np.ndarray] = []
    block: list[list[float]] = []
    text: list[tuple[int, int]] = []
    unreadable: list[tuple[int, str]] = []
    for index, row in enumerate(records):
        if len(row) < width:
            row += [""] * (width - len(row))
        try:
            numbers = [float(cell) if cell else math.nan for cell in row]
        except ValueError:  # a cell with text: an edited file, or a column of names
            numbers = [cell_number(cell) for cell in row]
            text += [(at, index) for at, cell in enumerate(row) if cell.strip() and not _is_number(cell)]
        if not math.isfinite(numbers[step]):
            unreadable.append((index + 2, row[step]))
        for name, at in kept.items():
            written[name].append(row[at])
        block.append(numbers)
        if len(block) == 1024:  # a block of rows at a time: a Python float per cell takes four times its 8 bytes
            blocks.append(np.array(block).T)
            block = []
    if block:
        blocks.append(np.array(block).T)
    numbers_by_column = np.concatenate(blocks, axis=1) if blocks else np.empty((width, 0))
    return Table(header, numbers_by_column, text, unreadable, written)


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _two_lines(path: Path) -> bool:
    """Whether a file holds two whole lines, reading no further than their end."""
    if path.suffix == ".gz":  # an archived copy: small, and read whole as every reader reads it
        return _whole_lines(path).count(b"\n") >= 2
    with open(path, "rb") as f:
        return sum(line.endswith(b"\n") for line in itertools.islice(f, 2)) == 2


def _whole_length(path: Path) -> int:
    """How many bytes of a file its whole lines take: up to its last newline, found by reading back from its end."""
    with open(path, "rb") as f:
        end = f.seek(0, os.SEEK_END)
        while end > 0:
            start = max(end - 65536, 0)
            f.seek(start)
            newline = f.read(end - start).rfind(b"\n")
            if newline >= 0:
                return start + newline + 1
            end = start
    return 0


def _damaged(path: Path, why: str) -> CanterError:
    return CanterError(f"{path} is damaged ({why}); restore it from a copy, or move it away")


def _header(path: Path) -> list[str]:
    """A metrics.csv's column names, read from its first line only (none for a missing or empty file)."""
    refuse_not_regular(path)
    if not path.is_file():
        return []
    if path.suffix == ".gz":  # an archived copy: small, and read whole as every reader reads it
        lines = _whole_lines(path).decode("utf-8-sig", errors="replace").splitlines()
        return _first_row(path, lines[:1])
    with open(path, newline="", encoding="utf-8-sig", errors="replace") as f:
        return _first_row(path, f)


def _first_row(path: Path, lines: Any) -> list[str]:
    try:
        header = next(csv.reader(lines), [])
    except csv.Error as exc:
        raise _damaged(path, str(exc)) from None
    if any("\0" in name for name in header):
        raise _damaged(path, "NUL bytes on line 1")
    return header


def cell_number(text: str | None) -> float:
    """A metrics.csv cell as a number: NaN where it is empty or not a number (an edited or damaged file)."""
    try:
        return float(text) if text else math.nan
    except ValueError:
        return math.nan


def row_steps(rows: list[dict[str, str]]) -> list[float]:
    """The global_step of each row whose step is a finite number, in the file's order."""
    return [step for step in (cell_number(row.get("global_step")) for row in rows) if math.isfinite(step)]


@dataclass(frozen=True)
class History:
    """The rows of the training a run kept (`run_history`), in the file's order, with the run's totals so far at
    each."""

    rows: np.ndarray  # which rows of the table
    global_step: np.ndarray
    wall_seconds: np.ndarray  # the row's wall_time, counted from the run's start
    train_seconds: np.ndarray
    episodes: np.ndarray


def run_history(table: Table, rows: np.ndarray | None = None) -> History:
    """The rows (of `rows`, by default all) of the training a run kept, each with its run totals so far (wall
    seconds, training seconds, episodes).

    Rows logged after a run's last checkpoint are lost work when the process dies without saving. A resume drops
    them (`MetricsLogger`), but a format-1 run folder (docs/architecture.md) can still hold them, followed by the
    resumed session's rows, whose `iteration` restarts below theirs; such a folder may also restart `wall_time` at
    0 on every resume."""
    rows = np.arange(table.rows) if rows is None else rows
    steps, iterations, raw_walls, speeds, counts = (
        table.column(name)[rows].tolist() for name in ("global_step", "iteration", "wall_time", "sps", "episodes")
    )
    kept: list[int] = []  # positions in `rows`, and each one's totals:
    global_step, wall_seconds, train_seconds = array("d"), array("d"), array("d")
    episodes: list[int] = []
    wall_offset = previous_wall = 0.0
    for at, (step, iteration, raw_wall, sps, count) in enumerate(zip(steps, iterations, raw_walls, speeds, counts)):
        if kept and iteration <= iterations[kept[-1]]:
            while kept and iterations[kept[-1]] >= iteration:
                for totals in (kept, global_step, wall_seconds, train_seconds, episodes):
                    totals.pop()
            wall_offset = wall_seconds[-1] if kept else 0.0
        elif kept and raw_wall < previous_wall:  # a resume after a clean stop, which loses no rows
            wall_offset = wall_seconds[-1]
        previous_wall = raw_wall if raw_wall == raw_wall else previous_wall
        before = (global_step[-1], wall_seconds[-1], train_seconds[-1], episodes[-1]) if kept else (0.0, 0.0, 0.0, 0)
        kept.append(at)
        global_step.append(step)
        wall_seconds.append(wall_offset + raw_wall if raw_wall == raw_wall else before[1])
        train_seconds.append(before[2] + ((step - before[0]) / sps if sps > 0 else 0.0))
        episodes.append(before[3] + (int(count) if math.isfinite(count) else 0))
    return History(
        rows[kept], np.array(global_step), np.array(wall_seconds), np.array(train_seconds), np.array(episodes)
    )


@dataclass(frozen=True)
class Totals:
    """What the sessions of a run add up to at a checkpoint, whose header holds them so that a resume carries them
    on: wall seconds (compile included), training seconds, episodes, the recent returns that stop_at_return and
    the result average, and the last session's compile seconds."""

    wall_seconds: float = 0.0
    train_seconds: float = 0.0
    episodes: int = 0
    recent_returns: tuple[float, ...] = ()
    compile_seconds: float = 0.0

    def header(self) -> dict[str, Any]:
        """As a checkpoint header holds them."""
        return {
            "wall_seconds": self.wall_seconds,
            "train_seconds": self.train_seconds,
            "episodes": self.episodes,
            "recent_returns": list(self.recent_returns),
            "compile_seconds": self.compile_seconds,
        }

    @classmethod
    def from_header(cls, saved: Mapping[str, Any]) -> Totals:
        """From a checkpoint header's `totals`, where an older canter may have left some out."""
        return cls(
            wall_seconds=float(saved.get("wall_seconds", 0.0)),
            train_seconds=float(saved.get("train_seconds", 0.0)),
            episodes=int(saved.get("episodes", 0)),
            recent_returns=tuple(float(x) for x in saved.get("recent_returns") or ()),
            compile_seconds=float(saved.get("compile_seconds", 0.0)),
        )


def totals_until(path: Path, step: int) -> Totals:
    """Wall seconds, training seconds and episodes of a run up to its checkpoint at `step`. A resume reads these
    from the checkpoint; this rebuilds them from metrics.csv for a format-1 checkpoint that does not hold them."""
    history = run_history(read_table(Path(path)))
    within = np.flatnonzero(history.global_step <= step)
    if not within.size:
        return Totals()
    last = within[-1]
    return Totals(
        wall_seconds=float(history.wall_seconds[last]),
        train_seconds=float(history.train_seconds[last]),
        episodes=int(history.episodes[last]),
    )


def checkpoint_totals(header: Mapping[str, Any], metrics: Path) -> Totals:
    """The totals a checkpoint's header holds, or for a format-1 checkpoint, those metrics.csv gives up to its step."""
    saved = header.get("totals")
    return Totals.from_header(saved) if saved else totals_until(metrics, int(header["global_step"]))


# TensorBoard sections, as CleanRL names them: progress under charts/, what the update computes under losses/.
TENSORBOARD_CHARTS = frozenset(
    {
        "episodic_return",
        "episodic_length",
        "sps",
        "learning_rate",
        "episodes",
        "wall_time",
        "gradient_steps",
        "buffer_size",
    }
)


_MOVE_IT_AWAY = "move it away to resume with rows from step {step:,} on"  # the file starts again at the checkpoint


class MetricsLogger:
    """Appends to metrics.csv and TensorBoard. A resumed run passes `resume_step`: rows and events logged after
    that checkpoint belong to training that was lost with the process, so they are dropped and redone."""

    def __init__(
        self,
        run_dir: Path,
        metric_names: tuple[str, ...],
        info_keys: tuple[str, ...],
        tensorboard: bool,
        resume_step: int | None = None,
        evaluates: bool = False,
    ) -> None:
        self.path = Path(run_dir) / METRICS_FILE
        self.columns = columns_for(metric_names, info_keys, evaluates)
        packed = self.path.with_name(self.path.name + ".gz")
        source = packed if packed.is_file() and not self.path.exists() else self.path
        # Checked before anything is changed: a refused file, archived or not, stays as it is.
        self._check_header(source)
        table = None  # read once: a resumed run's file can hold a million rows
        if resume_step:
            self._note_a_lost_history(source, resume_step)
            table = read_table(source, cells=("wall_time",))
            self._refuse_rows_cut_back(source, table, resume_step)
        self._unpack_archived()
        self._cut_half_written_line()
        if resume_step is not None:
            if table is None:  # else the same rows: unpacking or cutting a half-written line changes none
                table = read_table(self.path, cells=("wall_time",))
            self._drop_rows_after(resume_step, table)
        self._widen_header()
        exists = self.path.is_file() and self.path.stat().st_size > 0
        self._file = AppendFile(self.path)  # held open until close()
        if not exists:
            self._file.append(self._line(dict(zip(self.columns, self.columns))))
        self._tb = None
        if tensorboard:
            from canter.training.tensorboard import EventFile

            purge = None if resume_step is None else resume_step + 1
            self._tb = EventFile(Path(run_dir) / TENSORBOARD_FOLDER, purge_step=purge)

    def _line(self, row: dict[str, Any]) -> bytes:
        text = io.StringIO(newline="")
        csv.DictWriter(text, fieldnames=self.columns, extrasaction="ignore").writerow(row)
        return text.getvalue().encode()

    def _unpack_archived(self) -> None:
        """A folder archived with metrics.csv.gz only continues that file: appending to a new metrics.csv would hide
        its history from every reader, which take the plain file where both exist."""
        packed = self.path.with_name(self.path.name + ".gz")
        if self.path.exists() or not packed.is_file():
            return
        rows = _whole_lines(packed)
        atomic_write_bytes(self.path, lambda f: f.write(rows))
        packed.unlink()

    def _note_a_lost_history(self, source: Path, step: int) -> None:
        """A file without a row, of a run that trained to a checkpoint at `step`: emptied or damaged, or begun again
        by a resume that was killed before its first row, after the file had been moved away (canter's own advice).
        The two cannot be told apart, so the resume logs on from the checkpoint and says what the file lacks."""
        if source.is_file() and not _two_lines(source):  # the header and a row at least
            print(
                f"canter: note: {lost_rows(source, step)} to keep the rows before step {step:,}; the resume logs "
                f"its rows from there",
                file=sys.stderr,
            )

    def _refuse_rows_cut_back(self, source: Path, table: Table, step: int) -> None:
        """A file whose last row comes before the checkpoint's own row was cut back by something else than a stopped
        process (which stops after the row it had logged before its checkpoint): the rows it lost are not logged
        again, and appending after them would hide the gap. Rows with unreadable steps are noted when dropped."""
        steps = table.column("global_step")
        steps = steps[np.isfinite(steps)]
        last = float(steps.max()) if steps.size else 0.0
        if table.rows and last < step and not table.unreadable:
            raise CanterError(
                f"{source} ends at step {last:,.0f}, before the row of step {step:,} that the checkpoint the run "
                f"goes on from follows: the file was cut back; restore it from a copy, or "
                f"{_MOVE_IT_AWAY.format(step=step)}"
            )

    def _cut_half_written_line(self) -> None:
        if not self.path.is_file():
            return
        whole = _whole_length(self.path)
        if whole >= self.path.stat().st_size:
            return
        with open(self.path, "r+b") as f:
            f.truncate(whole)
        # A row is logged before its iteration's checkpoint, so a process stopped while writing one stopped after the
        # newest checkpoint, which the resume goes on from, logging that row again (`_refuse_rows_cut_back` refused
        # a file cut back further).
        print(
            f"canter: note: dropped the half-written last row of {self.path} (a process stopped while writing "
            f"it); no training is lost: the run goes on from its checkpoint, which holds its state",
            file=sys.stderr,
        )

    def _check_header(self, source: Path) -> None:
        """Rows are told apart by their global_step, so a file whose first line names no such column would lose
        every row in a rewrite: refuse it, untouched."""
        header = _header(source)
        if header and "global_step" not in header:
            raise CanterError(
                f"{source} has no global_step column in its first line, so its rows cannot be kept; restore its "
                f"header line (canter writes global_step first), or move the file away to start a new one"
            )

    def _drop_rows_after(self, step: int, table: Table) -> None:
        """Keep the rows of the training the run kept up to its checkpoint at `step`, their wall_time counted from the
        run's start (`run_history`) and written with three decimals; rows whose global_step is not a step go."""
        history = run_history(table, np.flatnonzero(np.isfinite(table.column("global_step"))))
        within = history.global_step <= step
        kept, walls = history.rows[within], history.wall_seconds[within].tolist()
        written = table.cells.get("wall_time", [""] * table.rows)  # a row without one gets one
        # Compared as numbers: the logger writes 12.5 for the 12.500 a rewrite writes, and both hold the same time.
        unchanged = all(float(f"{w:.3f}") == cell_number(c) for w, c in zip(walls, written))
        if not table.header or (len(kept) == table.rows and unchanged):
            return
        if damaged := table.unreadable:
            line, cell = damaged[0]
            more = f" and {len(damaged) - 1} more" if len(damaged) > 1 else ""
            print(
                f"canter: note: dropped the rows of {self.path} whose global_step is not a step (line {line}: "
                f"{cell!r}{more}); the run's state is in its checkpoint, and only those rows' metrics are lost",
                file=sys.stderr,
            )
        wall_times: list[float | None] = [None] * table.rows
        for row, wall in zip(kept.tolist(), walls):
            wall_times[row] = wall
        self._rewrite(table.header, wall_times)

    def _widen_header(self) -> None:
        """Give the file of a run made by another canter version one header that fits the rows this logger
        appends: its own columns first, then any older ones it does not write, whose values stay in the earlier
        rows and are left empty in new ones."""
        header = _header(self.path)
        if not header:
            return
        self.columns += [c for c in header if c not in self.columns]
        if header != self.columns:
            self._rewrite(self.columns)

    def _rewrite(self, header: list[str], wall_times: list[float | None] | None = None) -> None:
        """Write the file again, a row at a time, under `header`: each row that has a global_step, with its cells
        under the columns of their names (empty under a column the file has not). With `wall_times`, one per row,
        only the rows that have one, with it as their wall_time."""

        def write(f: Any) -> None:
            text = io.TextIOWrapper(f, encoding="utf-8", newline="")
            writer = csv.writer(text)
            writer.writerow(header)
            records = _records(self.path)
            positions = _positions(next(records, []))
            columns = [positions.get(name) for name in header]
            walls = [at for at, name in enumerate(header) if name == "wall_time"]
            for index, row in enumerate(records):
                cells = [row[at] if at is not None and at < len(row) else "" for at in columns]
                if wall_times is not None:
                    wall = wall_times[index]
                    if wall is None:
                        continue
                    for at in walls:
                        cells[at] = f"{wall:.3f}"
                writer.writerow(cells)
            text.detach()  # flushed, and `f` left open for atomic_write_bytes to sync

        atomic_write_bytes(self.path, write)

    def log(self, row: dict[str, Any]) -> None:
        clean = {k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()}
        self._file.append(self._line(clean))
        if self._tb is not None:
            scalars = {}
            for key, value in row.items():
                if key in ("global_step", "iteration") or value is None:
                    continue
                if isinstance(value, float) and math.isnan(value):
                    continue
                tag = key if "/" in key else f"charts/{key}" if key in TENSORBOARD_CHARTS else f"losses/{key}"
                scalars[tag] = value
            self._tb.add_scalars(int(row["global_step"]), scalars)

    def sync(self) -> None:
        """Make the rows logged so far durable: each comes before its iteration's checkpoint, which is fsynced, and a
        resume after a machine crash would otherwise find a checkpoint past the rows that reached the disk."""
        self._file.sync()

    def close(self) -> None:
        self._file.close()
        if self._tb is not None:
            self._tb.close()
