"""Run folders with damaged or unreadable files, and outputs that cannot go where asked: a one-line error and exit
2, never a traceback; outputs as readable as any file the user writes."""

from __future__ import annotations

import csv
import errno
import gzip
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from canter.cli.main import main
from canter.errors import CanterError
from canter.files import WriteError, check_writable, write_output
from canter.training.logger import read_rows, read_table, run_history
from canter.training.run_folder import run_format


def _one_line_error(capsys, code: int) -> str:
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith("canter: error: "), err
    return err


@pytest.mark.parametrize("command", ["plot", "report", "eval"])
@pytest.mark.parametrize("seed", ["-1", "4294967296"])
def test_a_seed_outside_32_bits_is_refused_before_any_work(archived_run, tmp_path, capsys, command, seed):
    out = {"plot": ["--out", str(tmp_path / "p.png")], "report": ["--out", str(tmp_path / "r.html")], "eval": []}
    err = _one_line_error(
        capsys, main([command, str(archived_run), str(archived_run), f"--seed={seed}", *out[command]])
    )
    assert f"argument --seed: expected a seed from 0 to 4294967295, got '{seed}'" in err


def test_a_file_this_user_may_not_read_is_one_line(archived_run, tmp_path, capsys, monkeypatch):
    # Tests may run as root, which reads any file, so the refusal the OS would give is raised where it would be.
    read_text = Path.read_text

    def refused(path, *args, **kwargs):
        if path.name == "config.toml":
            raise PermissionError(13, "Permission denied", str(path))
        return read_text(path, *args, **kwargs)

    monkeypatch.setattr(Path, "read_text", refused)
    err = _one_line_error(capsys, main(["plot", str(archived_run), "--out", str(tmp_path / "p.png")]))
    assert f"{archived_run / 'config.toml'}: permission denied; give this user access to it" in err


def test_a_checkpoint_this_user_may_not_read_is_not_called_corrupt(archived_run, capsys, monkeypatch):
    load = np.load

    def refused(path, *args, **kwargs):
        if str(path).endswith(".npz"):
            raise PermissionError(13, "Permission denied", str(path))
        return load(path, *args, **kwargs)

    monkeypatch.setattr(np, "load", refused)
    err = _one_line_error(capsys, main(["eval", str(archived_run), "--episodes", "1"]))
    assert "permission denied; give this user access to it" in err and "corrupt" not in err


def test_a_damaged_metrics_archive_is_one_line(archived_run, tmp_path, capsys):
    (archived_run / "metrics.csv").unlink()
    (archived_run / "metrics.csv.gz").write_bytes(gzip.compress(b"global_step,iteration\n1,1\n")[:-6])
    err = _one_line_error(capsys, main(["plot", str(archived_run), "--out", str(tmp_path / "p.png")]))
    assert "metrics.csv.gz is not a whole gzip file" in err and "restore it from a copy" in err


def test_an_unreadable_episode_count_counts_as_none(archived_run):
    path = archived_run / "metrics.csv"
    header, rows = read_rows(path)
    rows[1]["episodes"] = "nan"
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, header)
        writer.writeheader()
        writer.writerows(rows)
    totals = run_history(read_table(path)).episodes.tolist()
    plain = [int(r["episodes"]) if r["episodes"] not in ("", "nan") else 0 for r in rows]
    assert totals == [sum(plain[: i + 1]) for i in range(len(rows))]


@pytest.mark.parametrize("value", ['"x"', "null", "0", "-1", "true", "2.5", '"2"', "1.0"])
def test_a_run_format_that_is_not_a_number_is_one_line(archived_run, value):
    (archived_run / "versions.json").write_text(f'{{"run_format": {value}}}')
    with pytest.raises(CanterError, match=r"versions.json has run_format .* not a whole number from 1; restore it"):
        run_format(archived_run)


def test_a_summary_that_is_not_an_object_reads_as_missing(archived_run):
    from canter.use.report import run_facts

    (archived_run / "summary.json").write_text("null")
    assert run_facts(archived_run).summary == {}


def test_summary_values_that_are_not_numbers_show_as_dashes(archived_run):
    from canter.use.report import run_facts, runs_section

    (archived_run / "summary.json").write_text(
        '{"global_step": "x", "wall_seconds": null, "sps": "zzz", "stop_reason": 3}'
    )
    table = runs_section([run_facts(archived_run)])
    assert table.count("<td class='num'>–</td>") == 3 and "zzz" not in table


@pytest.mark.parametrize("damage", ["smooth", "metrics"])
def test_a_report_refuses_what_it_cannot_draw_before_it_evaluates(archived_run, tmp_path, capsys, monkeypatch, damage):
    import canter.use.report as report

    def evaluated(*args, **kwargs):
        raise AssertionError("the runs were evaluated before the refusal")

    monkeypatch.setattr(report, "evaluate_runs", evaluated)
    argv = ["report", str(archived_run), "--out", str(tmp_path / "r.html")]
    if damage == "smooth":
        argv += ["--smooth", "0"]
    else:
        (archived_run / "metrics.csv").unlink()
    err = _one_line_error(capsys, main(argv))
    assert ("--smooth must be >= 1 rows, got 0" if damage == "smooth" else "no metrics.csv in") in err


def test_an_output_path_that_is_a_folder_is_refused_before_the_work(tmp_path):
    with pytest.raises(CanterError, match=r"it is a folder; give a file name"):
        check_writable(tmp_path)


def test_outputs_are_as_readable_as_a_plainly_written_file(tmp_path):
    plain = tmp_path / "plain"
    plain.write_bytes(b"x")
    out = tmp_path / "out.json"
    out.write_bytes(b"old")
    out.chmod(0o444)
    write_output(out, b"new")
    assert out.read_bytes() == b"new"
    assert stat.S_IMODE(os.stat(out).st_mode) == stat.S_IMODE(os.stat(plain).st_mode)


def test_a_refused_write_into_missing_folders_names_the_folder_that_exists(tmp_path):
    refused = PermissionError(errno.EACCES, "Permission denied")
    error = WriteError(tmp_path / "new" / "deeper" / "out.json", refused)
    assert f"make {tmp_path} writable (or pick another path)" in str(error)
    assert str(WriteError(tmp_path / "out.json", refused)).endswith(
        f"make {tmp_path} writable (or pick another path), then run the command again"
    )


@pytest.mark.parametrize("command", ["plot", "report", "eval"])
def test_a_run_folder_given_twice_is_refused_rather_than_counted_as_two_seeds(archived_run, tmp_path, capsys, command):
    out = {"plot": ["--out", str(tmp_path / "p.png")], "report": ["--out", str(tmp_path / "r.html")], "eval": []}
    again = archived_run.parent / ".." / archived_run.parent.name / archived_run.name
    err = _one_line_error(capsys, main([command, str(archived_run), str(again), *out[command]]))
    assert f"run folders '{archived_run}' and '{again}', the same folder: each run counts once; drop the repeat" in err
    err = _one_line_error(capsys, main([command, str(archived_run), str(archived_run), *out[command]]))
    assert f"run folders '{archived_run}' twice" in err
