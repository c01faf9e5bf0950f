"""Jobs: child processes that train seeds of one config, for `canter tune` and `canter bench`; and the spawned worker
processes that run their Optuna trials.

A job runs in its own process (`python -m canter.orchestrate.jobs SPEC.json`), started with `subprocess`, never
forked: JAX and EnvPool are not fork-safe, a MuJoCo error kills the process that hit it (the caller records the
failure and goes on), and a trial that overruns its time limit can be killed without taking its worker down. The
child dies with its parent (PR_SET_PDEATHSIG), so a killed worker leaves no orphan training behind.

Every seed has a fixed run folder. Re-running a spec skips seeds whose run finished, resumes seeds that stopped
after a checkpoint, and trains the rest, all of them in one vmapped seed group (`canter.training.loop.train_seeds`);
with `eval_episodes` it then writes each run's final deterministic evaluation to `eval.json`.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from canter import run_layout
from canter.errors import CanterError, error_line
from canter.files import AppendFile, WriteError, atomic_write_bytes, is_write_error
from canter.orchestrate.job_resources import apply_cpu_pinning, job_layout
from canter.orchestrate.run_status import is_number, run_status
from canter.run_layout import CHECKPOINT_NAME, EVAL_FILE, SUMMARY_FILE
from canter.signals import (
    die_with_parent,
    end_quietly_without_stdout,
    exit_interrupted,
    handling_stop_signals,
    stdout_is_gone,
    stops_held,
)
from canter.training.trackers.base import TrackSpec

# --------------------------------------------------------------------------------------------------- child process


@dataclass(frozen=True)
class JobSpec:
    config_toml: str
    run_dirs: dict[int, str]  # seed -> run folder
    eval_episodes: int = 0  # 0: no final evaluation
    track: TrackSpec = field(default_factory=TrackSpec)  # `--track`: each seed's tracker runs

    def to_json(self) -> str:
        return json.dumps(
            {
                "config_toml": self.config_toml,
                "run_dirs": {str(k): v for k, v in self.run_dirs.items()},
                "eval_episodes": self.eval_episodes,
                "track": self.track.to_dict(),
            }
        )

    @staticmethod
    def from_json(text: str) -> JobSpec:
        data = json.loads(text)
        return JobSpec(
            data["config_toml"],
            {int(k): v for k, v in data["run_dirs"].items()},
            int(data["eval_episodes"]),
            TrackSpec.from_dict(data.get("track", {})),  # a job.json written before --track reached jobs has none
        )


# The line a job's start writes into its train.log, which its failure reason reads after.
JOB_START = "canter: job started"


def start_job(spec: JobSpec, folder: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
    """Start the child process of a job; its output goes to folder/train.log. A write error (a full disk) is a
    `WriteError` that leaves no half-written job.json behind."""
    spec_path = folder / "job.json"
    log_path = folder / "train.log"
    atomic_write_bytes(spec_path, lambda f: f.write(spec.to_json().encode()))
    log = AppendFile(log_path)
    try:
        log.append(f"{JOB_START} {time.strftime('%Y-%m-%d %H:%M:%S')}\n".encode())
    finally:
        log.close()
    try:
        with open(log_path, "ab") as output:
            return subprocess.Popen(
                [sys.executable, "-m", "canter.orchestrate.jobs", str(spec_path)],
                stdout=output,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env={**os.environ, **(env or {})},
            )
    except OSError as exc:
        if is_write_error(exc):
            raise WriteError(log_path, exc) from None
        raise


# The exit status of a child that refused its input with a one-line error (`main`): a retry meets the same refusal.
INPUT_ERROR = 2
# The exit status of a child whose run folder another process writes (sysexits' EX_TEMPFAIL): a later try can work.
BUSY = 75
_FAILED = "training process failed"

# What a signal's end most likely means, which the process's last line cannot say: the kernel's out-of-memory killer
# sends SIGKILL, which canter and schedulers send only after a SIGTERM went unheeded.
_SIGNAL_NOTES = {signal.SIGKILL: "probably out of memory"}

# Lines a crash's log ends with that say nothing of the error: JAX's note that it filtered the traceback above, and
# the rule it draws before the note.
_TRAILERS = (re.compile(r"-+"), re.compile(r"For simplicity, JAX has removed its internal frames.*"))


def exit_text(returncode: int) -> str:
    """'exit 2', or 'killed by signal 9 (SIGKILL, probably out of memory)' for a process a signal ended (a negative
    return code)."""
    if returncode >= 0:
        return f"exit {returncode}"
    try:
        sig = signal.Signals(-returncode)
    except ValueError:
        return f"killed by signal {-returncode}"
    note = _SIGNAL_NOTES.get(sig)
    return f"killed by signal {-returncode} ({sig.name}{f', {note}' if note else ''})"


def failure_reason(folder: Path, returncode: int) -> str:
    """The child's one-line error (`canter: error: ...`), whole, since its fix comes last; else the last line of its
    log that says something (cut short: a crash's last line can be any length), with the exit status. Only the
    output of the newest start counts: the log is appended to, and an earlier session's error is not this one's."""
    lines = []
    with contextlib.suppress(OSError):
        lines = [line for line in (folder / "train.log").read_text(errors="replace").splitlines() if line.strip()]
    starts = [i for i, line in enumerate(lines) if line.startswith(JOB_START)]
    lines = lines[starts[-1] + 1 :] if starts else lines
    errors = [line for line in lines if line.startswith("canter: error:")]
    said = [line for line in lines if not any(t.fullmatch(line.strip()) for t in _TRAILERS)]
    last = errors[-1] if errors else (said[-1][:300] if said else "no output")
    return f"{_FAILED} ({exit_text(returncode)}): {last.strip()}"


def needs_a_fix(reason: str) -> bool:
    """Whether a `failure_reason` is a job's refusal of its input, which a retry alone meets again."""
    return reason.startswith(f"{_FAILED} ({exit_text(INPUT_ERROR)})")


# A job told to stop finishes its iteration, or the evaluation under way, and writes its checkpoint; a long
# HumanoidStandup evaluation on two cores outlasts 20 s, and a job killed then loses everything since its last one.
STOP_GRACE_SECONDS = 180.0


def stop_jobs(procs: Iterable[subprocess.Popen], grace_seconds: float = STOP_GRACE_SECONDS) -> None:
    """SIGTERM to every job at once (the trainer saves a checkpoint and returns), then SIGKILL to those still running
    after the grace period, which all of them share."""
    running = [proc for proc in procs if proc.poll() is None]
    for proc in running:
        proc.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + grace_seconds
    for proc in running:
        try:
            proc.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextlib.contextmanager
def bench_advice_for_damaged_checkpoints() -> Iterator[None]:
    """A damaged periodic checkpoint of a seed the job resumes, with what fixes it for a re-run of the bench: moved
    away, the seed resumes from the checkpoint before it; a seed with no other is trained anew once its folder is
    moved away (its summary.json would otherwise mark it finished)."""
    from canter.training import checkpoint, run_folder

    try:
        yield
    except checkpoint.DamagedCheckpoint as exc:
        run_dir = exc.path.parent.parent
        if exc.path.parent != run_folder.checkpoint_dir(run_dir) or not CHECKPOINT_NAME.match(exc.path.name):
            raise  # best.npz, whose own advice fits
        if len(run_folder.list_checkpoints(run_dir)) > 1:
            fix = f"move it out of {exc.path.parent}, and the re-run resumes the seed from the checkpoint before it"
        else:
            fix = f"it is the seed's only one: move the folder {run_dir} away, and the re-run trains that seed anew"
        raise CanterError(f"checkpoint {exc.path} {exc.what}; {fix}") from None


def run_job(spec: JobSpec, quiet: bool = True) -> None:
    """Skip finished seeds, resume stopped ones (and their tracker runs), train the rest (as one seed group), each seed
    with its own tracker runs, then evaluate the final policies."""
    from canter.config.serialize import from_toml_text
    from canter.training.loop import resume_seeds, train_seeds
    from canter.training.resume import summarize_ended_run
    from canter.training.run_lock import LOCK_FILE, RunLocks
    from canter.training.trackers import resume_spec, tracking

    config = from_toml_text(spec.config_toml, "job spec")
    total = config.run.total_steps
    fresh: list[int] = []
    partial: list[Path] = []
    with RunLocks() as locks:  # another job on the same cell is refused before it changes anything
        for folder in spec.run_dirs.values():
            locks.take(Path(folder))
        for seed, folder in sorted(spec.run_dirs.items()):
            run_dir = Path(folder)
            status = run_status(run_dir, total, config.run.stop_at_return)
            if status == "partial":
                partial.append(run_dir)
            elif status == "ended":  # its tracker runs are closed as a finish closes them
                recorded = resume_spec(spec.track.names, spec.track.mlflow_uri, [run_dir])
                with tracking(replace(spec.track, names=recorded.names, mlflow_uri=recorded.mlflow_uri)):
                    summarize_ended_run(run_dir)
            elif status == "new":
                if (run_dir / SUMMARY_FILE).is_file():
                    raise CanterError(
                        f"{run_dir} holds a finished run without its checkpoints (an archive?), which cannot be "
                        f"trained on to {total:,} steps; move it away, or give the bench another --out"
                    )
                for item in run_dir.iterdir():  # started but died before its first checkpoint: nothing to keep
                    if item.name != LOCK_FILE:
                        shutil.rmtree(item) if item.is_dir() else item.unlink()
                fresh.append(seed)
        stops_before = stops_held()
        with tracking(spec.track):
            if partial:  # each resumes from its own newest checkpoint, together in one program
                # ... and continues the tracker runs its trackers.json records, whether or not this re-run tracks
                recorded = resume_spec(spec.track.names, spec.track.mlflow_uri, partial)
                with (
                    tracking(replace(spec.track, names=recorded.names, mlflow_uri=recorded.mlflow_uri)),
                    bench_advice_for_damaged_checkpoints(),
                ):
                    resume_seeds(
                        partial,
                        total,
                        max_minutes=config.run.max_minutes,
                        stop_at_return=config.run.stop_at_return,  # the target given now, or none
                        quiet=quiet,
                    )
            # A signal stops the job: the group it stopped kept a checkpoint, and the rest wait for the re-run.
            if fresh and stops_held() == stops_before:
                train_seeds(config, fresh, quiet=quiet, run_dirs=[Path(spec.run_dirs[s]) for s in fresh])
        if spec.eval_episodes and stops_held() == stops_before:
            for folder in spec.run_dirs.values():
                write_final_eval(Path(folder), spec.eval_episodes)


FINAL_EVAL_SEED = 0  # the eval seed, from which `canter.core.seeding` derives the envs' seeds


def write_final_eval(run_dir: Path, episodes: int) -> dict[str, Any]:
    """Deterministic evaluation of the newest checkpoint (eval seed 0), cached in eval.json with every episode's
    return and length. A cached evaluation without lengths (written before they were kept), or without a mean
    return (a damaged file), is done again."""
    from canter.training import checkpoint
    from canter.use.evaluate import evaluate
    from canter.use.policy import load

    path = run_dir / EVAL_FILE
    cached = run_layout.read_object(path) or {}
    step = checkpoint.latest(run_dir).name
    if (
        cached.get("checkpoint") == step
        and cached.get("episodes") == episodes
        and "lengths" in cached
        and is_number(cached.get("mean"))
    ):
        return cached
    result = evaluate(load(run_dir), episodes=episodes, deterministic=True, seed=FINAL_EVAL_SEED)
    summary = result.summary()
    data = {
        "checkpoint": step,
        "episodes": episodes,
        "deterministic": True,  # the protocol, with the seed, in the file that a table's scores are read from
        "seed": FINAL_EVAL_SEED,
        "mean": result.mean,
        "std": result.std,
        "returns": summary["returns"],
        "lengths": summary["lengths"],
        "backend": summary["backend"],
        "physics": summary["physics"],
    }
    atomic_write_bytes(path, lambda f: f.write(json.dumps(data, indent=2).encode()))
    return data


# ------------------------------------------------------------------------------------------------ worker processes


def run_workers(work: Callable[..., None], worker_args: list[tuple[Any, ...]], name: str) -> list[int]:
    """Call `work(*args)` once per entry of `worker_args`, each in a process of its own pinned to its share of the
    cores (`job_layout`), and wait for them all; returns the non-zero exit statuses. The processes are spawned,
    never forked (JAX and EnvPool are not fork-safe); `work` must be a module-level function so that it pickles."""
    import multiprocessing

    context = multiprocessing.get_context("spawn")
    processes = [
        context.Process(target=_worker_main, args=(work, args, caps), name=f"{name}-{i}")
        for i, (args, caps) in enumerate(zip(worker_args, job_layout(len(worker_args))))
    ]
    for p in processes:
        p.start()
    try:
        for p in processes:
            p.join()
    except KeyboardInterrupt:
        # A terminal's Ctrl-C reaches the workers too; a SIGTERM to this process alone does not, nor does a SIGINT
        # that a background shell made them ignore. Tell them (a worker that stopped already ignores it), then give
        # each the time its running job takes to checkpoint.
        for p in processes:
            if p.is_alive() and p.pid is not None:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(p.pid, signal.SIGTERM)
        deadline = time.monotonic() + STOP_GRACE_SECONDS + 30
        for p in processes:
            p.join(max(0.0, deadline - time.monotonic()))
        raise
    return [p.exitcode for p in processes if p.exitcode]


def _ignore(signum: int, frame: Any) -> None:
    """A stop signal after the first, while the cleanup it started runs."""


@contextlib.contextmanager
def sigterm_interrupts() -> Iterator[None]:
    """Within it, SIGTERM (a scheduler, `kill`, a dying parent) stops the process as Ctrl-C does, so that a bench or
    tune worker stops its job and records its trial as interrupted rather than leave it running in the study. The
    first stop signal interrupts, and later ones are ignored: a second one (Ctrl-C to the process group, then the
    parent passing it on) would cut short the cleanup that waits for the job's checkpoint, which is bounded anyway
    (`stop_jobs`: its grace, then SIGKILL). A signal the process ignores stays ignored (`handling_stop_signals`)."""

    def interrupt(signum: int, frame: Any) -> None:
        # A handler that does nothing, not SIG_IGN: a second signal that landed with the first (Ctrl-C to the group,
        # and the parent's SIGTERM) is still pending in Python, which raises "Signal N ignored due to race condition"
        # for a pending signal whose handler became SIG_IGN.
        for sig in handled:
            signal.signal(sig, _ignore)
        raise KeyboardInterrupt

    with handling_stop_signals(interrupt) as handled:
        yield


def _worker_main(work: Callable[..., None], args: tuple[Any, ...], thread_caps: dict[str, str]) -> None:
    die_with_parent(signal.SIGTERM)  # a killed parent takes its workers along; their trials are retried by heartbeat
    os.environ.update(thread_caps)
    apply_cpu_pinning()
    try:
        with sigterm_interrupts():
            work(*args)
    except CanterError as exc:
        print(error_line(exc), file=sys.stderr, flush=True)
        sys.exit(2)
    except KeyboardInterrupt:
        exit_interrupted()
    except OSError:  # a print to a stdout nobody reads any more (`| head -1`), as the command's own process ends
        if not stdout_is_gone():
            raise
        sys.exit(end_quietly_without_stdout())


def main(argv: list[str]) -> int:
    from canter.training.run_lock import RunFolderBusy

    die_with_parent(signal.SIGTERM)
    apply_cpu_pinning()
    try:
        run_job(JobSpec.from_json(Path(argv[0]).read_text()))
    except RunFolderBusy as exc:  # a job of a killed bench still stopping, say: a later try finds the folder free
        print(error_line(exc), file=sys.stderr, flush=True)
        return BUSY
    except CanterError as exc:
        print(error_line(exc), file=sys.stderr, flush=True)
        return INPUT_ERROR
    except KeyboardInterrupt:  # a second Ctrl-C, which means now
        exit_interrupted()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
