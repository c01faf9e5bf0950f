"""canter report when things go wrong: a `--video` report stopped by SIGTERM or Ctrl-C leaves nothing in the temp
dir, neither the half-written video nor the folder it renders into."""

import os
import shutil
import sys
from pathlib import Path

import pytest

from test_video_faults import STOPPED, _check_stopped, _signal_once_rendering

# `canter report` with each frame slowed: one Pendulum episode renders in a second or two, and the signal must land
# while it is going.
SLOWED_REPORT = (
    "import sys, time; from canter.use import video_file; append = video_file.AtomicVideo.append; "
    "video_file.AtomicVideo.append = lambda self, frame: (time.sleep(0.05), append(self, frame)); "
    "from canter.cli.main import main; sys.exit(main(sys.argv[1:]))"
)
# When the signal lands: as soon as the temp folder is made (before the render has its writer), or mid-render.
MADE, RENDERING = "canter-report-*", "canter-report-*/.run1.*.tmp.mp4"
TERM, INT = STOPPED  # (signal, exit status, the end of stderr)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("moment", "stop"),
    [(MADE, TERM), (RENDERING, TERM), (RENDERING, INT)],
    ids=["SIGTERM-folder-made", "SIGTERM-rendering", "SIGINT-rendering"],
)
def test_a_stopped_canter_report_video_leaves_no_temp_folder(tiny_run, tmp_path, moment, stop):
    """SIGTERM's default action, delivered once the unfinished video is removed, would end the process before the
    temp folder it was in is removed, leaving an empty canter-report-* folder after every stopped report."""
    sig, code, said = stop
    temp = tmp_path / "tmp"
    temp.mkdir()
    out = tmp_path / "r.html"
    argv = [sys.executable, "-c", SLOWED_REPORT, "report", str(tiny_run.run_dir), "--episodes", "0", "--video"]
    env = dict(os.environ, TMPDIR=str(temp))
    ended = _signal_once_rendering([*argv, "--out", str(out)], temp, moment, sig, env)
    _check_stopped(ended, code, said)  # SIGTERM: the process ended by the signal, 143 in a shell
    assert list(temp.glob("canter-report-*")) == [] and not out.exists()


def test_a_report_that_plays_nothing_still_tells_a_missing_folder_and_a_benchs(tmp_path, capsys):
    from canter.cli.main import main
    from conftest import ARCHIVED_RUN

    bench = tmp_path / "bench"
    shutil.copytree(ARCHIVED_RUN, bench / "a")
    out = str(tmp_path / "r.html")
    for folder, expected in (
        (tmp_path / "missing", f"run folder not found: {tmp_path / 'missing'}"),
        (bench, f"{bench} is not a run folder but holds 1 run folder (a bench's?): pass them, such as {bench / 'a'}"),
    ):
        assert main(["report", str(folder), "--episodes", "0", "--out", out]) == 2
        assert capsys.readouterr().err == f"canter: error: {expected}\n"


def test_a_report_of_a_run_on_an_uninstalled_backend_names_its_extra_and_no_backend_flag(
    archived_run, tmp_path, capsys, monkeypatch
):
    """A run evaluates on the backend it trained on; report has no --backend (canter eval's fix) to pass instead, so
    it names the extra, and --episodes 0 to report without playing."""
    from canter.config.build import build_config
    from canter.envs.registry import get_backend
    from canter.use import report
    from conftest import error_line

    # The archived run as a run of the mjx backend (its checkpoint says EnvPool, so its config is not edited).
    trained_on_mjx = build_config("InvertedPendulum-v5", sets=["env.backend=mjx"])
    monkeypatch.setattr(
        report, "run_facts", lambda run_dir, which: report.RunFacts(Path(run_dir), trained_on_mjx, {}, (), ())
    )
    monkeypatch.setattr(type(get_backend("mjx")), "available", lambda self: False)
    assert error_line(capsys, ["report", str(archived_run), "--out", str(tmp_path / "report.html")]) == (
        f"MJX is not installed here, and the report evaluates {archived_run} on it, as it trained; "
        "pip install 'canter[mjx]', or pass --episodes 0 to report it without an evaluation"
    )
