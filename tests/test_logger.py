import csv
import math

from canter.logger import BASE_COLUMNS, MetricsLogger, Progress


def test_metrics_csv_columns_and_append(tmp_path):
    logger = MetricsLogger(tmp_path, ("policy_loss",), ("reward_run",), tensorboard=False)
    row = {c: 1.0 for c in BASE_COLUMNS}
    row.update(global_step=10, episodic_return=math.nan, **{"info/reward_run": 2.5})
    logger.log(row)
    logger.close()
    again = MetricsLogger(tmp_path, ("policy_loss",), ("reward_run",), tensorboard=False)  # a resumed run appends
    again.log(dict(row, global_step=20))
    again.close()
    rows = list(csv.DictReader(open(tmp_path / "metrics.csv")))
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
