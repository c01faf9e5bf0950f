"""A process killed (SIGKILL: no handler runs) at the moments between a run's writes leaves a folder that resumes
and that every reader takes. Each test stops a real `canter train` where its fault was, by a hook that kills the
process from inside, so the moment is exact rather than a matter of timing."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from canter.run_layout import CONFIG_FILE, LOCK_FILE
from canter.training import checkpoint, run_folder
from canter.training.logger import read_rows

CANTER = [sys.executable, "-m", "canter.cli"]
SETS = ["net.hidden=16,16", "env.num_envs=4", "ppo.n_steps=64", "ppo.minibatch_size=128", "ppo.epochs=1"]
SET_ARGS = [arg for s in SETS for arg in ("--set", s)]
# Two iterations, each with a video; a periodic checkpoint after the first.
VIDEO_RUN = ["train", "InvertedPendulum-v4", "--total-steps", "512", "--out-dir", "runs", *SET_ARGS]
VIDEO_RUN += ["--set", "run.checkpoint_every=256", "--set", "run.video_every=256"]


def _killed_at(hook: str, argv: list[str] | str, cwd: Path) -> None:
    """Run `canter argv` (or Python code) with `hook` (Python that wraps a canter function so that it kills the
    process) installed first, and check that the kill came."""
    call = argv if isinstance(argv, str) else f"from canter.cli.main import main\nsys.exit(main({argv!r}))"
    script = "\n".join(["import os, signal, sys", textwrap.dedent(hook), call])
    result = subprocess.run([sys.executable, "-c", script], cwd=cwd, capture_output=True, text=True, timeout=300)
    assert result.returncode == -signal.SIGKILL, result.stderr[-2000:]


def _after_seed_run(method: str) -> str:
    """A hook that kills the process as soon as a SeedRun's `method` returns."""
    return f"""
        from canter.training.seed_run import SeedRun
        original = SeedRun.{method}
        def killed_after(self, *args, **kwargs):
            original(self, *args, **kwargs)
            os.kill(os.getpid(), signal.SIGKILL)
        SeedRun.{method} = killed_after
    """


def _canter(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([*CANTER, *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_a_new_run_killed_while_its_envs_are_made_resumes_from_step_0(tmp_path):
    """Between taking a new folder's writer lock and its first iteration lie the envs and the compile, seconds
    long. A kill there left a folder that held the lock alone: no resume took it, and `canter plot runs/*` failed."""
    hook = """
        import canter.training.loop as loop
        loop._make_env = lambda *args, **kwargs: os.kill(os.getpid(), signal.SIGKILL)
    """
    _killed_at(hook, ["train", "InvertedPendulum-v4", "--total-steps", "512", "--out-dir", "runs", *SET_ARGS], tmp_path)
    (run,) = (tmp_path / "runs").iterdir()
    assert {CONFIG_FILE, LOCK_FILE} <= {p.name for p in run.iterdir()}
    resumed = _canter("train", "--resume", str(run), "--quiet", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert "trains again from step 0" in resumed.stderr
    assert (run / "summary.json").is_file()
    plotted = _canter("plot", str(run), "--out", "curve.png", cwd=tmp_path)
    assert plotted.returncode == 0 and (tmp_path / "curve.png").is_file(), plotted.stderr


def test_a_new_run_refused_after_its_folder_was_made_leaves_no_folder(tmp_path):
    """Made at once, a new folder is also taken away again when the run is refused before it trains (here by its
    envs: a discrete-action env under a continuous-only algorithm)."""
    result = _canter("train", "CartPole-v1", "--algo", "td3", "--out-dir", "runs", cwd=tmp_path)
    assert result.returncode != 0 and "continuous-only" in result.stderr, result.stderr
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def _video_steps(run: Path) -> list[int]:
    return sorted(int(video.stem.removeprefix("step_")) for video in (run / "videos").glob("step_*.mp4"))


def test_a_run_killed_after_a_periodic_checkpoint_keeps_the_video_of_its_step(tmp_path):
    """The checkpoint came before the video's snapshot: killed between the two, a resume from that checkpoint never
    recorded the video of its step."""
    _killed_at(_after_seed_run("save_periodic"), VIDEO_RUN, tmp_path)
    (run,) = (tmp_path / "runs").iterdir()
    (checkpointed,) = run_folder.list_checkpoints(run)
    resumed = _canter("train", "--resume", str(run), "--quiet", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    final = json.loads((run / "summary.json").read_text())["global_step"]
    steps = [run_folder.step_of(checkpointed), final]
    assert _video_steps(run) == steps, (run / "videos" / "render.log").read_text()
    assert not list((run / "videos").glob(".snapshot_*"))


def test_a_run_killed_before_its_summary_renders_its_last_video_and_records_its_seeds(tmp_path):
    """Killed after its final checkpoint, the run's summary is written by the next resume from that checkpoint; the
    final video, whose renderer died with the process, was lost, and the summary said nothing of the seeds that
    trained together."""
    hook = """
        from canter.training.seed_run import SeedRun
        SeedRun._end = lambda self, result: os.kill(os.getpid(), signal.SIGKILL)
    """
    _killed_at(hook, VIDEO_RUN, tmp_path)
    (run,) = (tmp_path / "runs").iterdir()
    final = run_folder.step_of(run_folder.list_checkpoints(run)[-1])
    assert not (run / "summary.json").exists() and (run / "videos" / f".snapshot_{final:012d}.npz").is_file()
    resumed = _canter("train", "--resume", str(run), "--quiet", cwd=tmp_path)
    assert resumed.returncode == 0 and "stopped before writing its summary.json" in resumed.stderr, resumed.stderr
    assert len(_video_steps(run)) == 2 and _video_steps(run)[-1] == final, (run / "videos" / "render.log").read_text()
    assert not list((run / "videos").glob(".snapshot_*"))
    assert json.loads((run / "summary.json").read_text())["trained_with"] == [0]


def _best_step(run: Path) -> int:
    return int(checkpoint.read_header(checkpoint.best_path(run))["global_step"])


@pytest.mark.parametrize("resume_evaluates", [True, False])
def test_a_run_killed_after_a_new_best_keeps_the_best_of_the_checkpoint_it_resumes_from(tmp_path, resume_evaluates):
    """A best.npz saved after the newest checkpoint is of training that the resume does again, so the resume removes
    it; the best.npz it had replaced, of the checkpoint's training, was lost with it. Each evaluation here counts as
    a new best, so the second replaces the first; the kill comes before the second iteration's checkpoint. A resume
    that does not evaluate (run.eval_every is an output key, which a resume may change) sets best.npz right too."""
    hook = """
        from canter.training.evaluation import TrainingEvaluation
        from canter.training.seed_run import SeedRun
        TrainingEvaluation.improves = lambda self, result: True
        save_periodic, saved = SeedRun.save_periodic, []
        def killed_at_the_second(self, *args, **kwargs):
            if saved:
                os.kill(os.getpid(), signal.SIGKILL)
            save_periodic(self, *args, **kwargs)
            saved.append(self.global_step)
        SeedRun.save_periodic = killed_at_the_second
    """
    run_args = ["train", "InvertedPendulum-v4", "--total-steps", "2048", "--out-dir", "runs", *SET_ARGS]
    run_args += ["--set", "run.checkpoint_every=1", "--set", "run.eval_every=1", "--set", "run.eval_episodes=1"]
    _killed_at(hook, run_args, tmp_path)
    (run,) = (tmp_path / "runs").iterdir()
    (checkpointed,) = run_folder.list_checkpoints(run)
    first = run_folder.step_of(checkpointed)
    assert _best_step(run) > first and checkpoint.kept_best_path(run).is_file()
    # The resume is stopped as soon as it has set up its seed: what it did to best.npz is what the run goes on with.
    resume: list[str] | str = ["train", "--resume", str(run)]
    if not resume_evaluates:
        resume = (
            "import canter\nfrom canter.training.resume import resume_config\n"
            f"canter.train(resume_config({str(run)!r}, None).with_values('run', eval_every=0), resume={str(run)!r})"
        )
    _killed_at(_after_seed_run("__init__"), resume, tmp_path)
    assert _best_step(run) == first and not checkpoint.kept_best_path(run).exists()
    header = checkpoint.read_header(checkpoint.best_path(run))
    (row,) = [row for row in read_rows(run / "metrics.csv")[1] if int(row["global_step"]) == first]
    assert float(row["eval/return_mean"]) == header["evaluation"]["return_mean"]


def test_the_kept_best_comes_back_whichever_write_a_kill_interrupted(tmp_path):
    """The cases of `resumed_best`, by the files a kill left: (best.npz, the kept one) and the resume's step."""
    from canter.training.seed_run import Best, resumed_best

    (tmp_path / "checkpoints").mkdir()
    best_file, kept_file = checkpoint.best_path(tmp_path), checkpoint.kept_best_path(tmp_path)

    def files(best: int | None, kept: int | None) -> tuple[Best | None, Best | None]:
        for path, step in ((best_file, best), (kept_file, kept)):
            path.unlink(missing_ok=True)
            if step is not None:
                path.write_text(str(step))
        return (
            Best(best_file, float(best), best) if best is not None else None,
            Best(kept_file, float(kept), kept) if kept is not None else None,
        )

    # Killed after the checkpoint that covers best.npz, before the kept one was removed: best.npz stands.
    assert resumed_best(*files(300, 100), 300, tmp_path) == Best(best_file, 300.0, 300)
    assert best_file.read_text() == "300" and not kept_file.exists()
    # Killed before that checkpoint: the kept one is back.
    assert resumed_best(*files(300, 100), 200, tmp_path) == Best(best_file, 100.0, 100)
    assert best_file.read_text() == "100" and not kept_file.exists()
    # Killed between keeping best.npz and writing the new one.
    assert resumed_best(*files(None, 100), 200, tmp_path) == Best(best_file, 100.0, 100)
    assert best_file.read_text() == "100" and not kept_file.exists()
    # No best before the checkpoint: none is left.
    assert resumed_best(*files(300, None), 200, tmp_path) is None
    assert not best_file.exists() and not kept_file.exists()
    # A resume from an older checkpoint than the kept best's (the newest was damaged): neither stands.
    assert resumed_best(*files(300, 100), 50, tmp_path) is None
    assert not best_file.exists() and not kept_file.exists()


def test_an_output_s_temp_file_left_by_a_killed_writer_goes_with_the_next_write(archived_run, tmp_path):
    """A write goes to a hidden temp file that is renamed into place; a kill before the rename left that file beside
    the output for good. The next writer of the output removes it, knowing from its name that its process is gone."""
    hook = "os.fsync = lambda fd: os.kill(os.getpid(), signal.SIGKILL)"
    _killed_at(hook, ["plot", str(archived_run), "--out", "curve.png"], tmp_path)
    (left,) = tmp_path.glob(".curve.png.*.tmp")
    assert not (tmp_path / "curve.png").exists()
    plotted = _canter("plot", str(archived_run), "--out", "curve.png", cwd=tmp_path)
    assert plotted.returncode == 0, plotted.stderr
    assert (tmp_path / "curve.png").is_file() and not left.exists()
    assert not list(tmp_path.glob(".curve.png.*"))


def test_only_the_temp_files_of_gone_processes_of_this_machine_are_removed(tmp_path):
    """A temp file being written (its process alive) stays, and so does one of another machine sharing the folder,
    whose processes this one cannot see."""
    from canter.files import remove_orphaned_temps, temp_prefix

    finished = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    gone_pid = int(finished.stdout)
    mine = temp_prefix("out.json")
    alive = tmp_path / f"{mine}abc.tmp"
    gone = tmp_path / f"{mine.replace(f'-{os.getpid()}-', f'-{gone_pid}-')}abc.tmp"
    elsewhere = tmp_path / f".out.json.000000-{gone_pid}-abc.tmp"
    other_output = tmp_path / f"{temp_prefix('other.json').replace(f'-{os.getpid()}-', f'-{gone_pid}-')}abc.tmp"
    # Names that no writer of canter's gives, with no process ID in them: left alone, and no error.
    odd = [tmp_path / f"{mine.replace(f'-{os.getpid()}-', f'-{pid}-')}abc.tmp" for pid in ("²", "9" * 40, "")]
    for path in (alive, gone, elsewhere, other_output, *odd):
        path.write_text("")
    remove_orphaned_temps(tmp_path, "out.json")
    kept = (alive, elsewhere, other_output, *odd)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in kept)


def test_keeping_best_npz_leaves_it_in_place_and_takes_one_moved_away(tmp_path):
    """best.npz is kept by a link, so that readers find it throughout; one that the user moved away while the run
    trained leaves nothing to keep, and training goes on."""
    from canter.training.seed_run import keep_best

    (tmp_path / "checkpoints").mkdir()
    best, kept = checkpoint.best_path(tmp_path), checkpoint.kept_best_path(tmp_path)
    best.write_bytes(b"best of step 100")
    kept.write_bytes(b"stale")
    keep_best(tmp_path)
    assert best.read_bytes() == kept.read_bytes() == b"best of step 100"
    best.unlink()
    kept.unlink()
    keep_best(tmp_path)
    assert not kept.exists()
