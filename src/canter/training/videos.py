"""`run.video_every`: videos of the policy rendered while it trains, each in a child process.

The child runs `python -m canter.use.video` on a snapshot of the train state, so that rendering (and everything it
loads: MuJoCo's OpenGL contexts, Gymnasium's renderers, dm_control's cameras) stays out of the training process,
which imports dm_control at most to read a DM Control task's observation keys.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

from canter.run_layout import VIDEOS_FOLDER
from canter.training.cadence import Cadence

_FORK_WARNING = r"os\.fork\(\) was called"  # JAX warns about any fork; ours (GL probe, ffmpeg, renderer) exec


@contextlib.contextmanager
def quiet_fork() -> Iterator[None]:
    """Silence JAX's warning about forking for a subprocess that execs at once."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=_FORK_WARNING, category=RuntimeWarning)
        yield


def child_env() -> dict[str, str]:
    """This process's environment, with the folder that holds the canter package first on PYTHONPATH."""
    source = str(Path(__file__).resolve().parents[2])
    path = os.environ.get("PYTHONPATH")
    return dict(os.environ, PYTHONPATH=source + (os.pathsep + path if path else ""))


class TrainingVideos:
    """At every multiple of `every` env steps, snapshot the train state and render one episode to
    RUN/videos/step_<step>.mp4 in a separate, lower-priority process. A failed render (MuJoCo aborts the process on
    some errors; a full disk) costs training nothing but a warning, and keeps its snapshot: the run's next resume
    renders it once more, as the failure may have passed, and gives it up if it fails again. Training never waits
    except for the previous video (one at a time) and, at the end, for the last one."""

    WAIT_SECONDS = 900

    def __init__(self, run_dir: Path, every: int, start_step: int, resumed: bool = False) -> None:
        """every == 0 switches videos off. A resumed run drops the videos of steps after its checkpoint, as the
        logger drops their metrics: they showed training that was lost with the process, and are redone. A video of
        a step up to the checkpoint whose render the process took with it is rendered now from its snapshot, which
        is whole (it is written atomically before its render starts), and so is one whose render failed."""
        self.folder = Path(run_dir) / VIDEOS_FOLDER
        self.cadence = Cadence(every, start_step)
        self._job: tuple[subprocess.Popen, Path, int, bool] | None = None
        self._saved: tuple[Path, int] | None = None  # a snapshot whose render has not started
        if resumed and self.folder.is_dir():
            for video in self.folder.glob("step_*.mp4"):
                step = video.stem.removeprefix("step_")
                if step.isdigit() and int(step) > start_step:
                    video.unlink()
            for snapshot in sorted(self.folder.glob(".snapshot_*.npz")):
                step = snapshot.stem.removeprefix(".snapshot_")
                if every and step.isdigit() and int(step) <= start_step and not self._video(int(step)).exists():
                    self._finish()
                    self._render(snapshot, int(step), again=True)
                else:
                    snapshot.unlink()

    def _video(self, step: int) -> Path:
        return self.folder / f"step_{step:012d}.mp4"

    def snapshot_if_due(self, step: int, save_snapshot: Callable[[Path], None]) -> None:
        """Save the snapshot of `step` where a video is due; `render_snapshot` starts its render. Apart, so that the
        snapshot comes before the step's checkpoint (a resume from it renders a snapshot its process left) and the
        wait for the video before comes after it."""
        if not self.cadence.due(step):
            return
        self.cadence = self.cadence.advance(step)
        self.folder.mkdir(parents=True, exist_ok=True)
        snapshot = self.folder / f".snapshot_{step:012d}.npz"
        save_snapshot(snapshot)
        self._saved = (snapshot, step)

    def render_snapshot(self) -> None:
        """Render the snapshot just saved, once the video before it is done."""
        if self._saved is None:
            return
        snapshot, step = self._saved
        self._saved = None
        self._finish()
        self._render(snapshot, step)

    def _render(self, snapshot: Path, step: int, again: bool = False) -> None:
        """Start the child that renders the video of `step` from its snapshot; `again` for a snapshot that a run
        before this process left."""
        request = dict(
            run_dir=str(self.folder.parent),
            out_path=str(self._video(step)),
            checkpoint=str(snapshot),
            episodes=1,
            nice=10,
            parent=os.getpid(),
        )
        with open(self.folder / "render.log", "a") as log, quiet_fork():
            process = subprocess.Popen(
                [sys.executable, "-m", "canter.use.video", json.dumps(request)],
                stdout=log,
                stderr=log,
                stdin=subprocess.DEVNULL,
                env=child_env(),
                start_new_session=True,
            )
        self._job = (process, snapshot, step, again)

    def _finish(self) -> None:
        if self._job is None:
            return
        process, snapshot, step, again = self._job
        self._job = None
        try:
            code = process.wait(timeout=self.WAIT_SECONDS)
        except subprocess.TimeoutExpired:
            process.kill()
            code = process.wait()
        if code == 0 or again:
            snapshot.unlink(missing_ok=True)
        if code != 0:
            fate = "so it is given up" if again else "its snapshot is kept, and the run's next resume renders it again"
            print(
                f"canter: warning: the video at step {step} failed (exit {code}; see {self.folder / 'render.log'}); "
                f"{fate}",
                file=sys.stderr,
            )

    def close(self) -> None:
        self._finish()
