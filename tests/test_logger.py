import csv
import json
import math

import pytest

from canter.errors import CanterError
from canter.training.logger import BASE_COLUMNS, MetricsLogger, Totals, totals_until
from canter.training.progress import Progress


def read_rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_metrics_csv_columns_and_append(tmp_path):
    logger = MetricsLogger(tmp_path, ("policy_loss",), ("reward_run",), tensorboard=False)
    row = dict.fromkeys(BASE_COLUMNS, 1.0)
    row.update(global_step=10, episodic_return=math.nan, **{"info/reward_run": 2.5})
    logger.log(row)
    logger.close()
    again = MetricsLogger(tmp_path, ("policy_loss",), ("reward_run",), tensorboard=False)  # a resumed run appends
    again.log(dict(row, global_step=20))
    again.close()
    rows = read_rows(tmp_path / "metrics.csv")
    assert [r["global_step"] for r in rows] == ["10", "20"]
    assert rows[0]["episodic_return"] == "" and rows[0]["info/reward_run"] == "2.5"


def test_progress_bar_shows_steps_sps_and_return_and_quiet_is_silent(capsys):
    quiet = Progress(total=1000, start=0, quiet=True, description="x")
    quiet.update(10, 1.0, None)
    quiet.close()
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == ""
    bar = Progress(total=2_000_000, start=0, quiet=False, description="Hopper-v5 ppo")
    bar.update(500_000, 12345.0, 321.0)
    bar.close()
    out = capsys.readouterr().out
    assert "Hopper-v5 ppo" in out and "500k/2.00M" in out and "12,345 SPS" in out and "ret 321.0" in out
    small = Progress(total=1000, start=0, quiet=False, description="Pendulum-v1 ppo")
    small.update(2048, 5000.0, None)  # one iteration can overshoot a tiny budget
    small.close()
    assert "2,048/1,000" in capsys.readouterr().out


def test_a_resume_drops_rows_after_its_checkpoint(tmp_path):
    logger = MetricsLogger(tmp_path, ("policy_loss",), (), tensorboard=False)
    for iteration in (1, 2, 3):
        logger.log(dict.fromkeys(BASE_COLUMNS, 1.0) | {"global_step": 10 * iteration, "iteration": iteration})
    logger.close()
    again = MetricsLogger(tmp_path, ("policy_loss",), (), tensorboard=False, resume_step=20)
    again.log(dict.fromkeys(BASE_COLUMNS, 1.0) | {"global_step": 30, "iteration": 3})
    again.close()
    assert [r["global_step"] for r in read_rows(tmp_path / "metrics.csv")] == ["10", "20", "30"]


def test_a_resume_notes_the_rows_it_drops_because_their_step_is_damaged(tmp_path, capsys):
    logger = MetricsLogger(tmp_path, ("policy_loss",), (), tensorboard=False)
    for iteration in (1, 2, 3):
        logger.log(dict.fromkeys(BASE_COLUMNS, 1.0) | {"global_step": 10 * iteration, "iteration": iteration})
    logger.close()
    path = tmp_path / "metrics.csv"
    path.write_text(path.read_text().replace("\n10,", "\nabc,", 1).replace("\n20,", "\n-inf,", 1))
    MetricsLogger(tmp_path, ("policy_loss",), (), tensorboard=False, resume_step=30).close()
    assert [r["global_step"] for r in read_rows(path)] == ["30"]
    assert capsys.readouterr().err == (
        f"canter: note: dropped the rows of {path} whose global_step is not a step (line 2: 'abc' and 1 more); the "
        "run's state is in its checkpoint, and only those rows' metrics are lost\n"
    )
    MetricsLogger(tmp_path, ("policy_loss",), (), tensorboard=False, resume_step=30).close()  # nothing to drop now
    assert capsys.readouterr().err == ""


def test_a_resume_of_a_folder_archived_with_gzipped_metrics_continues_them(tmp_path):
    import gzip

    logger = MetricsLogger(tmp_path, ("policy_loss",), (), tensorboard=False)
    for iteration in (1, 2, 3):
        logger.log(dict.fromkeys(BASE_COLUMNS, 1.0) | {"global_step": 10 * iteration, "iteration": iteration})
    logger.close()
    plain = tmp_path / "metrics.csv"
    (tmp_path / "metrics.csv.gz").write_bytes(gzip.compress(plain.read_bytes()))
    plain.unlink()
    again = MetricsLogger(tmp_path, ("policy_loss",), (), tensorboard=False, resume_step=20)
    again.log(dict.fromkeys(BASE_COLUMNS, 1.0) | {"global_step": 30, "iteration": 3})
    again.close()
    assert [r["global_step"] for r in read_rows(plain)] == ["10", "20", "30"]
    assert not (tmp_path / "metrics.csv.gz").exists()


def test_a_resume_whose_columns_differ_keeps_every_value_under_its_own_name(tmp_path):
    """A run folder made by a canter that logged other diagnostics, resumed by this one: the file gets one header
    that holds both sets, the old rows keep their values, and the new rows land under their own names."""
    before = MetricsLogger(tmp_path, ("policy_loss", "old_metric"), (), tensorboard=False)
    before.log(
        dict.fromkeys(BASE_COLUMNS, 1.0) | {"global_step": 10, "iteration": 1, "policy_loss": 0.5, "old_metric": 7.0}
    )
    before.close()
    after = MetricsLogger(tmp_path, ("policy_loss", "grad_norm"), (), tensorboard=False, resume_step=10)
    after.log(
        dict.fromkeys(BASE_COLUMNS, 1.0) | {"global_step": 20, "iteration": 2, "policy_loss": 0.25, "grad_norm": 3.0}
    )
    after.close()
    with open(tmp_path / "metrics.csv") as f:
        header = next(csv.reader(f))
    assert header == [*BASE_COLUMNS, "policy_loss", "grad_norm", "old_metric"]
    rows = read_rows(tmp_path / "metrics.csv")
    assert [(r["global_step"], r["policy_loss"], r["old_metric"], r["grad_norm"]) for r in rows] == [
        ("10", "0.5", "7.0", ""),
        ("20", "0.25", "", "3.0"),
    ]
    again = MetricsLogger(tmp_path, ("policy_loss", "grad_norm"), (), tensorboard=False, resume_step=20)
    again.close()
    assert len(read_rows(tmp_path / "metrics.csv")) == 2


def test_a_spreadsheets_byte_order_mark_keeps_the_rows_and_a_header_without_global_step_is_refused(tmp_path):
    """A metrics.csv saved again by a spreadsheet starts with a byte-order mark: its rows stay through a resume
    whose columns differ. A file whose first line names no global_step is refused, untouched."""
    old = ",".join([*BASE_COLUMNS, "old_metric"])
    first_row = ",".join(["10", "1", *["1.0"] * (len(BASE_COLUMNS) - 2), "7.0"])
    (tmp_path / "metrics.csv").write_text("\ufeff" + old + "\n" + first_row + "\n", encoding="utf-8")
    MetricsLogger(tmp_path, ("grad_norm",), (), tensorboard=False, resume_step=10).close()
    rows = read_rows(tmp_path / "metrics.csv")
    assert [(r["global_step"], r["old_metric"], r["grad_norm"]) for r in rows] == [("10", "7.0", "")]

    headless = tmp_path / "headless"
    headless.mkdir()
    text = "step,iteration\n10,1\n"
    (headless / "metrics.csv").write_text(text)
    with pytest.raises(CanterError, match=r"metrics.csv has no global_step column in its first line"):
        MetricsLogger(headless, ("grad_norm",), (), tensorboard=False, resume_step=10)
    assert (headless / "metrics.csv").read_text() == text


def _old_style_rows(tmp_path):
    """Three sessions as older runs logged them, each restarting wall_time at 0: a SIGTERM after iteration 4
    (step 500), then a kill after iteration 6 that lost it; the resume from the checkpoint at iteration 5 redid
    iteration 6 as step 650."""
    lines = [
        "global_step,iteration,wall_time,sps,episodes,episodic_return,episodic_length",
        "100,1,12.0,10.0,1,5.0,100",
        "200,2,22.0,10.0,2,5.0,100",
        "500,4,2.0,20.0,,,",
        "600,5,7.0,20.0,1,5.0,100",
        "700,6,12.0,20.0,4,5.0,100",
        "650,6,6.0,25.0,1,5.0,100",
        "800,7,10.0,50.0,3,5.0,100",
    ]
    (tmp_path / "metrics.csv").write_text("\n".join(lines) + "\n")
    return tmp_path / "metrics.csv"


def test_totals_of_old_style_rows_leave_out_the_lost_iteration(tmp_path):
    path = _old_style_rows(tmp_path)
    whole = totals_until(path, 10_000)
    assert whole.wall_seconds == pytest.approx(22 + 7 + 10)
    assert whole.train_seconds == pytest.approx(10 + 10 + 15 + 5 + 2 + 3)
    assert whole.episodes == 1 + 2 + 1 + 1 + 3
    until_650 = totals_until(path, 650)
    assert (until_650.wall_seconds, until_650.train_seconds, until_650.episodes) == pytest.approx((35.0, 42.0, 5))
    assert totals_until(path, 99) == Totals()


def test_resuming_old_style_rows_rewrites_them_as_one_history(tmp_path):
    _old_style_rows(tmp_path)
    MetricsLogger(tmp_path, (), (), tensorboard=False, resume_step=650).close()
    rows = read_rows(tmp_path / "metrics.csv")
    assert [(r["global_step"], float(r["wall_time"])) for r in rows] == [
        ("100", 12.0),
        ("200", 22.0),
        ("500", 24.0),
        ("600", 29.0),
        ("650", 35.0),
    ]


def _significant_digits(text):
    return len(text.lstrip("-").split("e")[0].replace(".", "").strip("0"))


def test_float32_metrics_are_written_as_their_shortest_round_tripping_decimal(tiny_run):
    import numpy as np

    from canter.training.logger import logged

    rng = np.random.default_rng(0)
    for value in np.concatenate([rng.normal(size=200) * 10.0 ** rng.integers(-8, 8, size=200), [0.0, 1e-30]]):
        single = np.float32(value)
        assert np.float32(logged(single)) == single  # reads back as the same float32
        # ... and is written with no more digits than numpy's shortest repr of the float32 takes
        assert float(repr(logged(single))) == float(str(single))
        assert _significant_digits(repr(logged(single))) == _significant_digits(str(single))
    assert logged(np.float64(0.1) / 3) == 0.1 / 3  # a float64 keeps every digit
    assert logged(np.int32(7)) == 7.0
    # A real run's metrics.csv: every loss and return column holds such decimals (at most 9 significant digits).
    rows = read_rows(tiny_run.run_dir / "metrics.csv")
    for column in ("episodic_return", "policy_loss", "value_loss", "entropy", "approx_kl"):
        for row in rows:
            assert row[column] and _significant_digits(row[column]) <= 9, (column, row[column])


def test_tensorboard_files_progress_under_charts_and_the_update_under_losses(tmp_path):
    from test_faults import _event_records

    logger = MetricsLogger(tmp_path, ("approx_kl", "gradient_steps"), ("reward_run",), tensorboard=True)
    logger.log(
        dict.fromkeys(BASE_COLUMNS, 1.0)
        | {"global_step": 10, "approx_kl": 0.01, "gradient_steps": 4.0, "info/reward_run": 2.5}
    )
    logger.close()
    tags = {tag for events in (tmp_path / "tb").glob("events.*") for tag, _, _ in _event_records(events)}
    assert {"charts/wall_time", "charts/sps", "charts/gradient_steps", "losses/approx_kl", "info/reward_run"} <= tags
    assert not {"losses/wall_time", "losses/gradient_steps"} & tags


def test_totals_go_through_a_checkpoint_header_unchanged_and_fill_what_an_older_header_left_out(tmp_path):
    from canter.training.logger import checkpoint_totals

    totals = Totals(wall_seconds=12.5, train_seconds=9.25, episodes=7, recent_returns=(1.5, -2.0), compile_seconds=3.0)
    header = totals.header()
    assert list(header) == ["wall_seconds", "train_seconds", "episodes", "recent_returns", "compile_seconds"]
    assert json.loads(json.dumps(header)) == header and Totals.from_header(header) == totals
    assert Totals.from_header({"wall_seconds": 4, "episodes": 2.0}) == Totals(wall_seconds=4.0, episodes=2)
    # A format-1 checkpoint holds none: metrics.csv gives them up to its step.
    path = _old_style_rows(tmp_path)
    assert checkpoint_totals({"global_step": 650}, path) == totals_until(path, 650)
    assert checkpoint_totals({"global_step": 650, "totals": header}, path) == totals
