"""canter report: a self-contained page, checked in headless Chromium (loads, images and video present and
decoded, no console errors), with evaluation numbers that match canter.evaluate."""

import json
import re
import shutil
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from canter.cli.main import main
from chromium_page import CHROMIUM, inspect_page
from under_ci import program_missing


@pytest.fixture
def chromium_installed():
    if not Path(CHROMIUM).exists():
        program_missing(f"chromium is not installed ({CHROMIUM} not found)", "chromium")


needs_chromium = pytest.mark.usefixtures("chromium_installed")
# Starting Chromium forks; JAX warns about forks in general, but the child only execs bash and Chromium.
pytestmark = [pytest.mark.slow, pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")]


class _Tags(HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags: list[tuple[str, dict]] = []
        self.cells: list[str] = []
        self._in_cell = False

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        self._in_cell = tag == "td"
        if self._in_cell:
            self.cells.append("")

    def handle_endtag(self, tag):
        if tag == "td":
            self._in_cell = False

    def handle_data(self, data):
        if self._in_cell:
            self.cells[-1] += data


def parse(html_text: str) -> _Tags:
    tags = _Tags()
    tags.feed(html_text)
    return tags


@pytest.fixture
def run_with_media(tiny_run, tmp_path):
    """A copy of tiny_run with a small MP4 in videos/ and a robustness plot, as eval --vary and video write them."""
    import imageio.v3 as iio
    import matplotlib.image

    run = tmp_path / tiny_run.run_dir.name
    shutil.copytree(tiny_run.run_dir, run)
    (run / "videos").mkdir()
    frames = np.zeros((12, 48, 64, 3), np.uint8)
    frames[:, :, :32, 0] = 220
    frames[:, 16:, :, 2] = np.linspace(0, 255, 12, dtype=np.uint8)[:, None, None]
    iio.imwrite(run / "videos" / "step_000004096.mp4", frames, fps=12, codec="libx264", macro_block_size=16)
    (run / "robustness").mkdir()
    matplotlib.image.imsave(run / "robustness" / "body_mass-torso.png", np.random.default_rng(0).random((40, 60)))
    return run


@needs_chromium
def test_the_browser_check_catches_console_errors(tmp_path):
    page = tmp_path / "bad.html"
    page.write_text(
        "<!DOCTYPE html><html><head><title>t</title></head><body><p>hi</p>"
        "<script>console.error('deliberate error'); console.log('harmless log line');</script>"
        "<script>undefinedFunction();</script></body></html>"
    )
    report = inspect_page(page)
    assert report.loaded
    assert any("deliberate error" in e for e in report.console_errors)
    assert any("undefinedFunction" in e for e in report.console_errors)
    assert not any("harmless" in e for e in report.console_errors)


@needs_chromium
def test_report_in_a_headless_browser(run_with_media, tiny_run_seed1, tmp_path, capsys):
    from canter.use.evaluate import evaluate
    from canter.use.policy import load

    out = tmp_path / "report.html"
    code = main(["report", str(run_with_media), str(tiny_run_seed1.run_dir), "--episodes", "2", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    text = out.read_text()

    tags = parse(text)
    # Self-contained: every embedded resource is a data URI, and there are no scripts or links to fetch.
    sources = [attrs.get("src", "") for tag, attrs in tags.tags if tag in ("img", "video", "source", "script")]
    assert sources and all(s.startswith("data:") for s in sources)
    assert not [t for t, a in tags.tags if t in ("script", "link")]

    page = inspect_page(out)
    assert page.loaded and page.console_errors == []
    assert page.media["title"].startswith("canter report: Pendulum-v1 (2 runs)")
    images = page.media["images"]
    assert len(images) == 2 and all(i["complete"] and i["width"] > 0 for i in images)  # curves + robustness
    assert len(page.media["videos"]) == 1
    video = page.media["videos"][0]
    assert video["error"] is None and video["ready"] >= 2 and (video["width"], video["height"]) == (64, 48)
    dom = parse(page.dom)
    for heading in ("Runs", "Evaluation", "Statistics", "Learning curves", "Robustness", "Video", "Config"):
        assert f"<h2>{heading}</h2>" in page.dom
    assert "step_000004096.mp4" in page.dom and "robustness/body_mass-torso.png" in page.dom

    # The evaluation table reports what canter.evaluate computes for the same seed.
    expected = evaluate(load(run_with_media), episodes=2, seed=0)
    starts = [i for i, c in enumerate(dom.cells) if c == f"1. {run_with_media.name}"]
    assert len(starts) == 2  # the runs table, then the evaluation table (run, steps, episodes, return, ...)
    row = dom.cells[starts[1] : starts[1] + 6]
    assert row[2] == "2" and row[3] == f"{expected.mean:.1f} ± {expected.std:.1f}"
    assert "env=Pendulum-v1 algo=ppo preset=fast: mean of 2 runs" in dom.cells  # seeds summarised together
    # The statistics aggregate this evaluation: the two seeds are one cell, whose mean is the mean of the runs'.
    group_mean = dom.cells[dom.cells.index("env=Pendulum-v1 algo=ppo preset=fast: mean of 2 runs") + 3]
    start = dom.cells.index("Pendulum-v1")
    cell = dom.cells[start : start + 8]
    assert cell[1:3] == ["algo=ppo, preset=fast", "2"] and cell[7] == "none published"
    assert float(cell[4].split(" [")[0].replace(",", "")) == pytest.approx(float(group_mean.split(" ± ")[0]), abs=0.051)
    assert "this report's evaluation" in page.dom
    assert "run.seed" in dom.cells  # the config section lists the differing key


def test_report_without_evaluation_or_media(tiny_run, tmp_path, capsys):
    out = tmp_path / "r.html"
    assert main(["report", str(tiny_run.run_dir), "--episodes", "0", "--out", str(out)]) == 0
    text = out.read_text()
    assert "Not evaluated" in text and "No video" in text and "No robustness plot" in text
    assert "No statistics: they need a group of two or more runs" in text  # one run has no interval
    assert len(re.findall(r"<img ", text)) == 1


def test_report_bad_input(tiny_run, tmp_path, capsys):
    no_checkpoint = tmp_path / "run_without_checkpoint"
    shutil.copytree(tiny_run.run_dir, no_checkpoint, ignore=shutil.ignore_patterns("checkpoints"))
    assert main(["report", str(no_checkpoint), "--out", str(tmp_path / "r.html")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "without its checkpoints" in err and "report does with --episodes 0" in err
    # Without an evaluation or a video the page plays nothing, so an archived run kept without checkpoints will do.
    assert main(["report", str(no_checkpoint), "--episodes", "0", "--out", str(tmp_path / "archived.html")]) == 0
    assert "Not evaluated" in (tmp_path / "archived.html").read_text()
    (tmp_path / "archived.html").unlink()
    capsys.readouterr()

    blocker = tmp_path / "a_file"
    blocker.write_text("")
    assert main(["report", str(tiny_run.run_dir), "--episodes", "0", "--out", str(blocker / "r.html")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot write" in err
    # The page is HTML whatever the name says: a report.pdf would be an HTML file no PDF reader opens.
    assert main(["report", str(tiny_run.run_dir), "--episodes", "0", "--out", str(tmp_path / "r.pdf")]) == 2
    assert (
        capsys.readouterr().err
        == f"canter: error: --out {tmp_path / 'r.pdf'}: the report is one HTML page; name it *.html\n"
    )
    # Refused before any folder of the output's is made.
    assert main(["report", str(tiny_run.run_dir), "--episodes", "0", "--out", str(tmp_path / "new" / "r.pdf")]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "run_without_checkpoint"]


def test_report_records_a_video_with_canter_video(tiny_run, tmp_path, capsys):
    import base64

    import imageio.v3 as iio

    out = tmp_path / "r.html"
    assert main(["report", str(tiny_run.run_dir), "--episodes", "0", "--video", "--out", str(out)]) == 0
    videos = [a["src"] for t, a in parse(out.read_text()).tags if t == "video"]
    assert len(videos) == 1 and videos[0].startswith("data:video/mp4;base64,")
    (tmp_path / "embedded.mp4").write_bytes(base64.b64decode(videos[0].split(",", 1)[1]))
    frames = iio.imread(tmp_path / "embedded.mp4")
    assert frames.shape[0] == 201 and frames.shape[1:3] == (360, 480)  # reset frame + 200 Pendulum steps
    assert frames.std() > 5  # not blank
    assert "recorded for this report" in out.read_text()
    assert not (tiny_run.run_dir / "videos").exists()  # nothing written into the run folder


def test_robustness_table_shows_an_unstable_point_as_such(tmp_path):
    from canter.use.report import robustness_table

    stable = {"scale": 1.0, "return_mean": 214.8, "return_std": 1.1, "unstable_warnings": 0}
    diverged = {"scale": 1e30, "return_mean": 1.5e37, "return_std": 0.0, "unstable_warnings": 14}
    path = tmp_path / "gravity.json"
    runs = [{"label": "ppo s0", "points": [diverged, stable]}]
    path.write_text(json.dumps({"env": "Hopper-v5", "vary": "gravity=1e+30,1", "episodes": 2, "runs": runs}))
    cells = parse(robustness_table(path)).cells
    assert cells[cells.index("1e+30") + 1] == "unstable (14 MuJoCo warnings)"
    assert cells[cells.index("1") + 1] == "214.8 ± 1.1"


def test_report_shows_a_robustness_sweep_with_its_numbers(tiny_hopper_run, tmp_path, capsys):
    import json

    run = tmp_path / "hopper"
    shutil.copytree(tiny_hopper_run, run)
    assert main(["eval", str(run), "--vary", "body_mass:torso=0.5,1.5", "--episodes", "1"]) == 0
    sweep = json.loads(next((run / "robustness").glob("*.json")).read_text())
    out = tmp_path / "r.html"
    assert main(["report", str(run), "--episodes", "0", "--out", str(out)]) == 0
    text = out.read_text()
    assert text.count("<img ") == 2  # curves + the sweep's plot
    cells = parse(text).cells
    points = sweep["runs"][0]["points"]
    for scale, point in zip(("0.5", "1.5"), points):
        row = cells[cells.index(scale) :][:2]
        assert row[1] == f"{point['return_mean']:.1f} ± {point['return_std']:.1f}"
