"""Videos when things go wrong: a render stopped by SIGTERM leaves no temp file (as Ctrl-C did), and the readers of
RUN/videos/ skip the temp file of a render still going or killed."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from canter.cli.main import main
from canter.use import video_file
from canter.use.report import run_facts
from signals import with_sigint

KILLED_RENDER = (
    ".step_000000001427.5gma70b4.tmp.mp4"  # the name in the fault report: a renderer killed with its trainer
)


def test_a_videos_temp_file_is_not_a_finished_video(tmp_path):
    writer = video_file.AtomicVideo(tmp_path / "videos" / "step_000000001427.mp4", fps=10)
    try:
        assert video_file.is_unfinished_video(writer.tmp)
        assert not video_file.is_unfinished_video(writer.out)
    finally:
        writer.abort()
    assert video_file.is_unfinished_video(Path(KILLED_RENDER))
    assert not video_file.is_unfinished_video(Path("clip.tmp.mp4"))  # not hidden: a file of the user's, not canter's


@pytest.fixture
def run_copy(tiny_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(tiny_run.run_dir, run)
    (run / "videos").mkdir()
    return run


@pytest.mark.slow
def test_a_report_embeds_no_killed_renderers_temp_file(run_copy, tmp_path, capsys):
    (run_copy / "videos" / KILLED_RENDER).write_bytes(b"half a video")
    assert run_facts(run_copy, None).videos == ()
    assert main(["report", str(run_copy), "--episodes", "0", "--out", str(tmp_path / "a.html")]) == 0
    page = (tmp_path / "a.html").read_text()
    assert ".tmp" not in page and "No video in these runs' videos/ folders." in page

    (run_copy / "videos" / "step_000000000100.mp4").write_bytes(b"a whole video")
    assert run_facts(run_copy, None).videos == (run_copy / "videos" / "step_000000000100.mp4",)
    assert main(["report", str(run_copy), "--episodes", "0", "--out", str(tmp_path / "b.html")]) == 0
    page = (tmp_path / "b.html").read_text()
    assert ".tmp" not in page and "run 1: step_000000000100.mp4</figcaption>" in page, capsys.readouterr().err


# ------------------------------------------------------------------------------------------------------ SIGTERM


def _renders_to(path: Path) -> list[int]:
    """The processes whose command line names `path`: a render still going."""
    found = []
    for entry in Path("/proc").iterdir():
        try:
            if entry.name.isdigit() and str(path) in (entry / "cmdline").read_bytes().decode(errors="replace"):
                found.append(int(entry.name))
        except OSError:  # ended while listed
            continue
    return found


def _rendering(argv: list[str], folder: Path, pattern: str, env: dict | None = None, sigint=signal.SIG_DFL):
    """Start `argv` with SIGINT handled as `sigint` (SIG_IGN: as a job that a script starts with `&`; SIG_DFL,
    whatever this test process was started with) and return it once a temp file matching `pattern` appears under
    `folder`: a render that has just begun, the moment a signal was once lost in."""
    command = with_sigint(argv, sigint)
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        deadline = time.monotonic() + 600
        while not list(folder.glob(pattern)):
            assert process.poll() is None, process.communicate()[1]
            assert time.monotonic() < deadline, "no temp file appeared"
            time.sleep(0.01)
    except BaseException:
        _end(process)
        raise
    return process


def _end(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.kill()
        process.wait()


def _signal_once_rendering(argv: list[str], folder: Path, pattern: str, sig: int, env: dict | None = None):
    """Send `argv` `sig` once it is `_rendering`, and return its exit status and stderr."""
    process = _rendering(argv, folder, pattern, env)
    try:
        process.send_signal(sig)
        _, err = process.communicate(timeout=120)
    finally:
        _end(process)
    return process.returncode, err


# SIGTERM ends the process by the signal, as it ends any command (143 in a shell); Ctrl-C exits 130.
STOPPED = [(signal.SIGTERM, -signal.SIGTERM, ""), (signal.SIGINT, 130, "canter: interrupted\n")]


def _check_stopped(ended: tuple[int, str], code: int, said: str) -> None:
    assert ended[0] == code and ended[1].endswith(said) and "Traceback" not in ended[1], ended


# `canter video` as where mujoco was imported with another GL platform: it renders in a child process.
IN_A_SUBPROCESS = (
    "import sys; from canter.use import video; video.headless_in_this_process = lambda: False; "
    "from canter.cli.main import main; sys.exit(main(sys.argv[1:]))"
)
# The ways a video renders: in the process that asks for it, or in a child process of it.
WHERE = {"in process": ["-m", "canter.cli.main"], "in a subprocess": ["-c", IN_A_SUBPROCESS]}


def _video_argv(run_dir: Path, out: Path) -> list[str]:
    # Enough frames that the render is still going when the signal lands.
    return ["video", str(run_dir), "--out", str(out), "--episodes", "50", "--width", "64", "--height", "48"]


@pytest.mark.slow
@pytest.mark.parametrize(("sig", "code", "said"), STOPPED, ids=["SIGTERM", "SIGINT"])
def test_a_stopped_canter_video_leaves_no_temp_file(tiny_run, tmp_path, sig, code, said):
    out = tmp_path / "vid" / "v.mp4"
    argv = [sys.executable, "-m", "canter.cli.main", *_video_argv(tiny_run.run_dir, out)]
    _check_stopped(_signal_once_rendering(argv, out.parent, ".v.*.tmp.mp4", sig), code, said)
    assert list(out.parent.iterdir()) == []


@pytest.mark.slow
@pytest.mark.parametrize(("sig", "code", "said"), STOPPED, ids=["SIGTERM", "SIGINT"])
def test_a_stopped_canter_video_stops_its_render_subprocess(tiny_run, tmp_path, sig, code, said):
    """Where mujoco was imported with another GL platform, the video renders in a child process: a signal to the
    parent stops that child too, and its temp file goes, rather than an orphan rendering on."""
    out = tmp_path / "vid" / "v.mp4"
    argv = [sys.executable, "-c", IN_A_SUBPROCESS, *_video_argv(tiny_run.run_dir, out)]
    _check_stopped(_signal_once_rendering(argv, out.parent, ".v.*.tmp.mp4", sig), code, said)
    orphans = _renders_to(out)
    for pid in orphans:
        os.kill(pid, signal.SIGKILL)
    assert orphans == [] and list(out.parent.iterdir()) == []


@pytest.mark.slow
@pytest.mark.parametrize("where", WHERE)
def test_a_canter_video_started_ignoring_sigint_renders_on_after_it(tiny_run, tmp_path, where):
    """A job that a script starts with `&` ignores SIGINT, so that a Ctrl-C meant for the foreground leaves it
    running: canter video left it ignored (it stopped, as if Ctrl-C'd). SIGTERM still stops it, temp file and all."""
    out = tmp_path / "vid" / "v.mp4"
    argv = [sys.executable, *WHERE[where], *_video_argv(tiny_run.run_dir, out)]
    process = _rendering(argv, out.parent, ".v.*.tmp.mp4", sigint=signal.SIG_IGN)
    try:
        process.send_signal(signal.SIGINT)
        time.sleep(3.0)  # a stop takes a frame, then the encoder's end; 50 episodes take far longer
        assert process.poll() is None, process.communicate()
        assert list(out.parent.glob(".v.*.tmp.mp4"))
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=120)
    finally:
        _end(process)
    _check_stopped((process.returncode, err), -signal.SIGTERM, "")
    orphans = _renders_to(out)
    for pid in orphans:
        os.kill(pid, signal.SIGKILL)
    assert orphans == [] and list(out.parent.iterdir()) == []


# A caller of record_video with a SIGTERM handler of its own that returns: it notes the signal and goes on.
OWN_HANDLER = """
import json, os, signal, sys, threading, time
from pathlib import Path
from canter.use import video

if sys.argv[3] == "in a subprocess":
    video.headless_in_this_process = lambda: False
out = Path(sys.argv[2])
noted = []
note = lambda signum, frame: noted.append(signum)
signal.signal(signal.SIGTERM, note)

def once_rendering():
    while not list(out.parent.glob(".v.*.tmp.mp4")):
        time.sleep(0.01)
    os.kill(os.getpid(), signal.SIGTERM)

threading.Thread(target=once_rendering, daemon=True).start()
returns = video.record_video(sys.argv[1], out, episodes=50, width=64, height=48)
print(json.dumps({"noted": noted, "episodes": len(returns), "back": signal.getsignal(signal.SIGTERM) is note}))
"""


@pytest.mark.slow
@pytest.mark.parametrize("where", WHERE)
def test_record_video_passes_sigterm_to_its_callers_handler(tiny_run, tmp_path, where):
    """The caller's own SIGTERM handler gets the signal once the unfinished file is gone, and as it returns, so does
    record_video, with fewer episodes than asked and no file; it raised KeyboardInterrupt, which no handler did."""
    out = tmp_path / "vid" / "v.mp4"
    argv = [sys.executable, "-c", OWN_HANDLER, str(tiny_run.run_dir), str(out), where]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    said = json.loads(done.stdout.strip().splitlines()[-1])
    assert said["noted"] == [signal.SIGTERM] and said["episodes"] < 50 and said["back"], said
    assert not out.exists() and list(out.parent.iterdir()) == []
