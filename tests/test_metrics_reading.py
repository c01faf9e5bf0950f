"""metrics.csv read at scale: by column, in a few times the file's size of memory, and once per resume. A run logs a
row per iteration, so a long one holds a million rows; read as a dict of strings per row, its curves took 12 times
the file in memory, and a resume read the file five times."""

import csv
import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from canter.training.logger import BASE_COLUMNS, MetricsLogger, cell_number, read_table
from canter.use.curves import read_metrics

METRICS = tuple(f"loss_{k}" for k in range(17))  # as many columns as a PPO run with evaluations logs


def _write_run_rows(path: Path, rows: int) -> None:
    """Rows as canter logs them: wall_time rounded to the millisecond, one column without values."""
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow([*BASE_COLUMNS, *METRICS])
        for i in range(1, rows + 1):
            base = [100 * i, i, round(0.031 * i, 3), 25493.9, 1, 1000.0, ""]
            writer.writerow(base + [-0.00041033048 * i] * len(METRICS))


def _bytes_read() -> int:
    """The bytes this process has read from files so far."""
    with open("/proc/self/io") as f:
        return int(next(line for line in f if line.startswith("rchar:")).split()[1])


def test_curves_take_a_few_times_the_files_size_of_memory(tmp_path):
    path = tmp_path / "metrics.csv"
    _write_run_rows(path, 3000)
    tracemalloc.start()
    try:
        columns = read_metrics(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 4 * path.stat().st_size, peak / path.stat().st_size  # a dict per row took 12 times
    assert len(columns["global_step"]) == 3000 and columns["loss_3"][-1] == -0.00041033048 * 3000


def test_a_resume_reads_its_metrics_once_and_again_only_to_rewrite_them(tmp_path):
    """A resume of a file with nothing to change reads it once, and leaves it as it was: the logger writes 12.5 where
    a rewrite writes 12.500, the same time, so no resume rewrites a file for that. Counted in bytes the process
    reads."""
    if not Path("/proc/self/io").is_file():
        pytest.skip("the system reports no bytes read per process")
    path = tmp_path / "metrics.csv"
    _write_run_rows(path, 5000)
    size, written = path.stat().st_size, path.read_bytes()
    inode = path.stat().st_ino
    for _ in range(2):
        before = _bytes_read()
        MetricsLogger(tmp_path, METRICS, (), tensorboard=False, resume_step=500_000).close()
        assert _bytes_read() - before < 1.5 * size, (_bytes_read() - before) / size  # the file was read 4 times
    assert path.read_bytes() == written and path.stat().st_ino == inode  # an atomic rewrite gives a new inode


def test_a_resume_rewrites_rows_whose_wall_time_restarted(tmp_path):
    """A resumed session of an old canter restarted wall_time: the rewrite counts it from the run's start."""
    path = tmp_path / "metrics.csv"
    header = ",".join(BASE_COLUMNS)
    path.write_text(f"{header}\n100,1,1.5,1,1,1,1\n200,2,3.25,1,1,1,1\n300,3,0.5,1,1,1,1\n")
    MetricsLogger(tmp_path, (), (), tensorboard=False, resume_step=300).close()
    with open(path, newline="") as f:
        walls = [row["wall_time"] for row in csv.DictReader(f)]
    assert walls == ["1.500", "3.250", "3.750"]


def test_a_table_holds_each_cell_as_a_dict_reader_gives_it(tmp_path):
    """Against csv.DictReader, on a file with the cells canter's readers must survive: empty, text, a step that is
    not a number, a short row, a quoted cell that spans lines, a repeated column, a half-written last line."""
    path = tmp_path / "metrics.csv"
    path.write_bytes(
        b"\xef\xbb\xbfglobal_step,iteration,note,x,x\r\n"
        b"10,1,,1.5,2\r\n"
        b"20,2,text,nan,-inf\r\n"
        b'abc,3,"two\r\nlines",1e3, 4 \r\n'
        b",4,no step,1,1\r\n"
        b"50,5\r\n"
        b"60,6,,7,8,9"  # half-written
    )
    table = read_table(path, cells=("note",))
    with open(path, newline="", encoding="utf-8-sig") as f:
        rows = [row for row in csv.DictReader(f) if row["global_step"]][:-1]
    assert table.header == ["global_step", "iteration", "note", "x", "x"] and table.rows == len(rows) == 4
    for name in ("global_step", "iteration", "note", "x"):
        expected = [cell_number(row[name]) for row in rows]
        np.testing.assert_array_equal(table.column(name), expected)
    assert np.isnan(table.column("missing")).all()
    assert table.unreadable == [(4, "abc")]
    assert table.text == [(2, 1), (0, 2), (2, 2)]  # (column, row): `note` of the rows of steps 20 and abc, and abc
    assert table.cells == {"note": ["", "text", "two\r\nlines", ""]}
    assert math.isnan(table.column("x")[3])  # the short row's missing cells


def test_curves_drop_a_column_only_for_text_in_the_rows_the_run_kept(tmp_path):
    """A format-1 file holds rows of work lost before a resume: text in one of those leaves the column drawn."""
    path = tmp_path / "metrics.csv"
    path.write_text(
        "global_step,iteration,wall_time,loss,name\n10,1,1.0,0.5,a\n20,2,2.0,oops,b\n10,1,0.5,0.25,c\n20,2,1.25,0.125,d\n"
    )
    columns = read_metrics(path)
    assert list(columns) == ["global_step", "iteration", "wall_time", "loss"]
    np.testing.assert_array_equal(columns["loss"], [0.25, 0.125])
    np.testing.assert_array_equal(columns["wall_time"], [0.5, 1.25])
