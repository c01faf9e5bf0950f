"""canter report when things go wrong: a `--video` report stopped by SIGTERM or Ctrl-C leaves nothing in the temp
dir, neither the half-written video nor the folder it renders into."""

import os
import shutil
import sys

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
