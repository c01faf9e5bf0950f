"""Archives keep a long metrics.csv gzipped (benchmarks/archive.py), and canter reads metrics.csv.gz wherever it reads
metrics.csv: the same rows, the same curves, the same bench records."""

import gzip
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from canter.orchestrate.bench_results import seed_record
from canter.training.logger import read_rows, totals_until
from canter.training.run_folder import metrics_file
from canter.use.curves import read_metrics

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from archive import PACKED_METRICS_OVER, RUN_FILES, copy_run, has_run_files

HEADER = "global_step,iteration,wall_time,sps,episodes,episodic_return,eval/return_mean\n"


def _metrics(rows: int) -> str:
    lines = [
        f"{i * 2048},{i},{i * 0.5 + 3.0},{4096.0 + i % 7},{i * 3},{100.0 + i},{'' if i % 10 else 7.5 * i}\n"
        for i in range(1, rows + 1)
    ]
    return HEADER + "".join(lines)


def _run(folder: Path, metrics: str) -> Path:
    folder.mkdir(parents=True)
    (folder / "metrics.csv").write_text(metrics + "999424,488,24")  # a half-written last line, as a killed run leaves
    (folder / "config.toml").write_text('[env]\nid = "Hopper-v5"\n\n[run]\nalgo = "ppo"\n')
    steps = int(metrics.rstrip().rsplit("\n", 1)[1].split(",")[0])
    (folder / "summary.json").write_text(json.dumps({"global_step": steps, "wall_seconds": 1.0, "sps": 1.0}))
    (folder / "eval.json").write_text(json.dumps({"mean": 1.0, "std": 0.0, "returns": [1.0], "lengths": [1000]}))
    (folder / "versions.json").write_text("{}")
    return folder


def test_a_gzipped_metrics_file_reads_as_the_plain_one(tmp_path):
    run = _run(tmp_path / "run", _metrics(50))
    plain = read_rows(run / "metrics.csv")
    packed = run / "metrics.csv.gz"
    packed.write_bytes(gzip.compress((run / "metrics.csv").read_bytes()))
    assert read_rows(packed) == plain and len(plain[1]) == 50  # the half-written line is left out of both
    assert totals_until(packed, 60 * 2048) == totals_until(run / "metrics.csv", 60 * 2048)
    plain_columns, packed_columns = read_metrics(run / "metrics.csv"), read_metrics(packed)
    assert plain_columns.keys() == packed_columns.keys()
    for name in plain_columns:
        np.testing.assert_array_equal(plain_columns[name], packed_columns[name])

    assert metrics_file(run) == run / "metrics.csv"  # the plain file wins where both are there
    (run / "metrics.csv").unlink()
    assert metrics_file(run) == packed
    packed.unlink()
    assert metrics_file(run) == run / "metrics.csv"  # neither: the usual name, for the usual error


@pytest.mark.parametrize("rows, packed", [(20, False), (6000, True)])
def test_the_archive_gzips_a_long_metrics_file_and_reads_the_same_record(tmp_path, rows, packed):
    source = _run(tmp_path / "live" / "Hopper-v5__ppo__s3", _metrics(rows))
    assert ((source / "metrics.csv").stat().st_size > PACKED_METRICS_OVER) == packed
    target = tmp_path / "archive" / source.name
    target.mkdir(parents=True)
    (target / ("metrics.csv" if packed else "metrics.csv.gz")).write_text("stale")  # from an earlier copy

    assert copy_run(source, target)
    assert has_run_files(target)
    assert (target / "metrics.csv.gz").is_file() == packed and (target / "metrics.csv").is_file() != packed
    if packed:
        assert gzip.decompress((target / "metrics.csv.gz").read_bytes()) == (source / "metrics.csv").read_bytes()
    assert seed_record(target, 3) == seed_record(source, 3)


def test_an_archive_missing_a_file_is_not_complete(tmp_path):
    source = _run(tmp_path / "live", _metrics(5))
    (source / "eval.json").unlink()
    assert not copy_run(source, tmp_path / "archive")
    assert not (tmp_path / "archive").exists()
    assert not has_run_files(source) and has_run_files(source, tuple(f for f in RUN_FILES if f != "eval.json"))


@pytest.mark.parametrize(
    ("metrics", "refusal"),
    [
        ("step,iteration\n2048,1\n", "has no global_step column"),  # not a header canter writes
        (HEADER + "2048,1,3.5,4096.0,3,101.0,\n", "ends at step 2,048, before the row of step 4,096"),  # cut back
    ],
)
def test_a_resume_refused_by_its_archived_metrics_leaves_them_archived(tmp_path, metrics, refusal):
    """The checks that refuse a resume read metrics.csv.gz as it is: the refused folder keeps it packed, with no
    metrics.csv beside it."""
    from canter.errors import CanterError
    from canter.training.logger import MetricsLogger

    run = tmp_path / "run"
    run.mkdir()
    packed = run / "metrics.csv.gz"
    packed.write_bytes(gzip.compress(metrics.encode()))
    before = packed.read_bytes()
    with pytest.raises(CanterError, match=refusal):
        MetricsLogger(run, ("sps",), (), tensorboard=False, resume_step=4096)
    assert packed.read_bytes() == before and not (run / "metrics.csv").exists()
