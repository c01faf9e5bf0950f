"""Whole-process timed `canter train` runs for the report pages, each archived beside its page.

A run is one `canter train` process, timed from outside (interpreter start, imports, compile, training and the final
checkpoint), then evaluated by `canter eval` in a process of its own (deterministic, 10 episodes unless the page
asks for more, every episode's return and length). Its files are copied into `<page>/runs/<name>/`: config.toml,
metrics.csv, summary.json, versions.json, eval.json, train.log and timing.json (the command, its wall seconds, the
1-minute load average before it and the cores other processes took while it trained, which say whether other work
shared them). A run whose archive is complete is not trained again, so a page's script can be rerun to fill in what
is missing. Two page commands on one machine share the work: each run is claimed by the process training it
(the writer lock of `.claims/<name>` beside its work folder), and the other command skips it and goes on to the next.

A run longer than a working session is trained in several processes: a page's `--max-minutes M` stops its training
after M minutes, checkpointed, and the next call resumes it. Its timing.json then lists every process, and its wall
time is their sum, which counts each process's start and compile again. A stopped run's work folder (its newest
checkpoint, sessions.json and train.log) is also kept in `<page>/inflight/<name>.tar`, committed with the page, so
that a fresh clone carries it on too; it is deleted when the run is archived."""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from archive import (
    RUN_FILES,
    copy_run,
    inflight_pack,
    provenance_table,
    read_pack,
    read_text,
    replace_between,
    sync,
    write_pack,
)

from canter.errors import CanterError
from canter.training import run_lock

ROOT = Path(__file__).resolve().parents[2]
EVAL_EPISODES = 10


def canter_command() -> list[str]:
    beside = Path(sys.executable).parent / "canter"
    return [str(beside)] if beside.exists() else [sys.executable, "-m", "canter.cli.main"]


def archived(page: Path, name: str) -> dict[str, Any] | None:
    """The archived run's timing.json, eval.json and summary.json, or None if it is not complete."""
    folder = page / "runs" / name
    files = ("timing.json", "eval.json", "summary.json")
    if not all((folder / f).is_file() for f in files):
        return None
    return {f.removesuffix(".json"): json.loads((folder / f).read_text()) for f in files} | {"folder": folder}


@dataclass
class Deadline:
    """When a page command stops training (`--max-minutes`, as time.monotonic()), or None: each training process
    still running then gets SIGTERM and stops, checkpointed, and the same command carries it on later. That
    lets a page whose runs take longer than a working session be filled in over several."""

    at: float | None = None
    waiting: bool = False  # run_to_deadline is waiting for its process, which SIGTERM may then interrupt

    def seconds_left(self) -> float | None:
        return None if self.at is None else self.at - time.monotonic()


DEADLINE = Deadline()
# A stopped process finishes its iteration and writes its checkpoint; give up on it after this long.
STOP_GRACE_SECONDS = 600


class StopRequested(Exception):
    """SIGTERM reached the page command while it waited for a training process."""


def _deadline_now(signum: int, frame: object) -> None:
    DEADLINE.at = time.monotonic()
    if DEADLINE.waiting:
        raise StopRequested


def stop_on_sigterm() -> None:
    """Make SIGTERM to this process a deadline that has come: its training process stops, checkpointed, as at
    --max-minutes, what finished is archived, and nothing new starts. Without it, the process would die and leave
    its `canter train` or `canter bench` running on."""
    signal.signal(signal.SIGTERM, _deadline_now)


def run_to_deadline(command: list[str], **popen: Any) -> tuple[int, bool]:
    """Run `command` to its end or to DEADLINE, where it gets SIGTERM; its exit code, and whether the deadline stopped
    it. canter train then writes its checkpoint at the end of the iteration and returns; canter bench ends at once,
    and its jobs, which get SIGTERM as their parent dies, write theirs. SIGTERM rather than SIGINT, because a process
    started in the background by a shell script ignores SIGINT."""
    with subprocess.Popen(command, **popen) as proc:
        try:
            DEADLINE.waiting = True
            try:
                return proc.wait(timeout=DEADLINE.seconds_left()), False
            finally:
                DEADLINE.waiting = False
        except (subprocess.TimeoutExpired, StopRequested):
            proc.send_signal(signal.SIGTERM)
            try:
                return proc.wait(timeout=STOP_GRACE_SECONDS), True
            except subprocess.TimeoutExpired:
                proc.kill()
                return proc.wait(), True


def out_of_time(name: str) -> bool:
    left = DEADLINE.seconds_left()
    if left is not None and left <= 0:
        print(f"{name}: past this command's --max-minutes; not started", flush=True)
        return True
    return False


SESSIONS_FILE = "sessions.json"  # beside the work folder's run: one entry per training process
FINISHED = ("budget", "stop_at_return")  # summary.json stop reasons that end a run; others resume


def _sessions(out: Path) -> list[dict[str, Any]]:
    """The work folder's finished training processes, or [] where it holds none that can be carried on: no folder,
    no run with a checkpoint yet, or a process that ended without its time recorded (killed), whose time is lost."""
    path, run_dir = out / SESSIONS_FILE, _run_dir(out)
    if not path.is_file() or run_dir is None or not any((run_dir / "checkpoints").glob("*")):
        return []
    sessions = json.loads(path.read_text())
    return sessions if all(entry["wall_seconds"] is not None for entry in sessions) else []


def _run_dir(out: Path) -> Path | None:
    dirs = [d for d in out.iterdir() if d.is_dir()] if out.is_dir() else []
    return dirs[0] if len(dirs) == 1 else None


def _write_sessions(out: Path, sessions: list[dict[str, Any]]) -> None:
    (out / SESSIONS_FILE).write_text(json.dumps(sessions, indent=2) + "\n")


def claim_dir(work: Path, name: str) -> Path:
    """The folder whose writer lock the process training `name` holds."""
    return work / ".claims" / name


def claim(folder: Path) -> bool:
    """Hold `folder`'s writer lock for this process, or False where another process holds it. The OS releases a
    flock however its holder dies, so a claim whose process is gone is simply taken over."""
    try:
        run_lock.acquire(folder)
    except CanterError:
        return False
    return True


def _busy_cpu_seconds() -> float | None:
    """CPU seconds the whole machine has spent busy since boot (all cores), or None without /proc/stat."""
    try:
        ticks = [int(t) for t in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:9]]
    except (OSError, ValueError):
        return None
    idle = ticks[3] + ticks[4]  # idle and iowait
    return (sum(ticks) - idle) / os.sysconf("SC_CLK_TCK")


def _children_cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


class OtherWork:
    """The CPU seconds that processes other than this one's children used while the `with` block ran: the
    machine's busy time (/proc/stat) less the children's (getrusage, once they have been waited for). Divided by
    the wall time, the number of cores other work took from a timed run."""

    def __init__(self) -> None:
        self.cpu_seconds: float | None = None

    def __enter__(self) -> OtherWork:
        self._machine, self._children = _busy_cpu_seconds(), _children_cpu_seconds()
        return self

    def __exit__(self, *exc: object) -> None:
        machine = _busy_cpu_seconds()
        if machine is not None and self._machine is not None:
            children = _children_cpu_seconds() - self._children
            self.cpu_seconds = max(0.0, machine - self._machine - children)


def timed_train(
    page: Path, name: str, train_args: list[str], work: Path, episodes: int = EVAL_EPISODES
) -> dict[str, Any] | None:
    """Train (unless archived already), evaluate (`episodes` episodes) and archive one run; returns
    `archived(page, name)`, or None when DEADLINE stopped the process before the run's end (the same call carries
    it on from its checkpoint, and the archived wall time is the sum of its processes), or when another page command
    is training it."""
    found = archived(page, name)
    if found:
        print(f"{name}: archived already", flush=True)
        inflight_pack(page, name).unlink(missing_ok=True)  # a pack committed beside its archived run is stale
        return found
    if out_of_time(name):
        return None
    lock = claim_dir(work, name)
    if not claim(lock):
        print(f"{name}: another process is training it ({run_lock.read_holder(lock).get('pid')}); skipped", flush=True)
        return None
    try:
        return _train_claimed(page, name, train_args, work, episodes)
    finally:
        run_lock.release(lock)


def _train_claimed(page: Path, name: str, train_args: list[str], work: Path, episodes: int) -> dict[str, Any] | None:
    out = work / name
    if read_pack(inflight_pack(page, name), out):
        print(f"{name}: carrying on from {inflight_pack(page, name)}", flush=True)
    sessions = _sessions(out)
    if sessions:
        command = [*canter_command(), "train", "--resume", str(_run_dir(out)), "--quiet"]
    else:
        if out.exists():
            shutil.rmtree(out)  # a run stopped without its time recorded has an unusable time: start it again
        out.mkdir(parents=True)
        command = [*canter_command(), "train", *train_args, "--quiet", "--out-dir", str(out)]
    load = os.getloadavg()[0]
    entry = {
        "command": ["canter", *command[len(canter_command()) :]],
        "wall_seconds": None,  # filled in when the process ends; None on the next call means it was killed
        "load_average_before": round(load, 2),
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    _write_sessions(out, [*sessions, entry])
    print(f"{name}: $ {' '.join(entry['command'][1:])}", flush=True)
    start = time.perf_counter()
    with open(out / "train.log", "ab") as log, OtherWork() as other:
        code, stopped = run_to_deadline(command, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    if code != 0 and stopped:
        print(f"{name}: stopped at --max-minutes before its first checkpoint; the next call starts again", flush=True)
        return None
    if code != 0:
        raise SystemExit(f"{name}: canter train exited {code}; see {out / 'train.log'}")
    entry |= {"wall_seconds": round(wall, 1)}
    if other.cpu_seconds is not None:
        entry["other_cpu_seconds"] = round(other.cpu_seconds, 1)
    sessions = [*sessions, entry]
    _write_sessions(out, sessions)
    run_dir = _run_dir(out)
    assert run_dir is not None
    summary = json.loads((run_dir / "summary.json").read_text())
    total = sum(e["wall_seconds"] for e in sessions)
    if summary["stop_reason"] not in FINISHED:
        print(
            f"{name}: stopped ({summary['stop_reason']}) at step {summary['global_step']:,} after "
            f"{len(sessions)} process(es), {total / 60:.0f} min in all; the same command carries it on",
            flush=True,
        )
        if not write_pack(inflight_pack(page, name), out, [out / SESSIONS_FILE, out / "train.log", run_dir]):
            print(
                f"{name}: too large to keep in {inflight_pack(page, name)}; a fresh machine starts it again", flush=True
            )
        return None
    evaluation = out / "eval.json"
    subprocess.run(
        [*canter_command(), "eval", str(run_dir), "--episodes", str(episodes), "--json", str(evaluation)],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    [row] = json.loads(evaluation.read_text())["runs"]
    folder = page / "runs" / name
    folder.mkdir(parents=True, exist_ok=True)
    copy_run(run_dir, folder, tuple(f for f in RUN_FILES if f != "eval.json"))  # eval.json: canter eval's, below
    shutil.copyfile(out / "train.log", folder / "train.log")
    keep = ("episodes", "return_mean", "return_std", "returns", "lengths", "checkpoint", "global_step", "deterministic")
    (folder / "eval.json").write_text(json.dumps({k: row[k] for k in keep if k in row}, indent=2) + "\n")
    timing = {
        "command": sessions[0]["command"],
        "wall_seconds": round(total, 1),
        # The busiest start of its processes: wall_text marks the time as shared when this is high (runs timed
        # before other_cores was measured).
        "load_average_before": max(e["load_average_before"] for e in sessions),
        "date": sessions[-1]["date"],
    }
    if all("other_cpu_seconds" in e for e in sessions):
        timing["other_cores"] = round(sum(e["other_cpu_seconds"] for e in sessions) / total, 2)
    if len(sessions) > 1:
        timing["sessions"] = sessions
    (folder / "timing.json").write_text(json.dumps(timing, indent=2) + "\n")
    print(f"{name}: {total:.0f} s, eval {row['return_mean']:.0f}", flush=True)
    inflight_pack(page, name).unlink(missing_ok=True)
    found = archived(page, name)
    assert found is not None
    return found


def plot_and_film(page: Path, name: str, work: Path) -> None:
    """The archived run's training curve (`canter plot`, from the archive) and one episode's video (`canter video`,
    from the trained run's checkpoint), as <page>/<name>.png and .mp4, unless they exist."""
    run_dir = _run_dir(work / name)
    for suffix, command in (
        (".png", ["plot", str(page / "runs" / name), "--out"]),
        (".mp4", ["video", str(run_dir), "--episodes", "1", "--out"]),
    ):
        out = page / f"{name}{suffix}"
        if not out.is_file():
            if run_dir is None:
                raise SystemExit(f"{name}: its run folder under {work} is gone; train it again to film it")
            subprocess.run([*canter_command(), *command, str(out)], check=True, stdout=subprocess.DEVNULL)


# Where other work shared the cores: other processes' mean use of the machine's cores while the run trained, or,
# for runs timed before that was measured, the 1-minute load average as it started, which also counts a run that
# had just ended (a page's previous seed, say).
BUSY_OTHER_CORES, BUSY_LOAD_BEFORE = 0.2, 0.5


def load_text(timing: dict[str, Any]) -> str:
    """' (other work took X cores)' or ' (load X before)' where other work shared the cores, else ''."""
    if "other_cores" in timing:
        other = timing["other_cores"]
        return f" (other work took {other:.1f} cores)" if other > BUSY_OTHER_CORES else ""
    before = timing["load_average_before"]
    return f" (load {before:.1f} before)" if before > BUSY_LOAD_BEFORE else ""


def wall_text(run: dict[str, Any]) -> str:
    """An archived run's whole-process time in minutes, marked when other work shared the cores."""
    return f"{run['timing']['wall_seconds'] / 60:.1f} min{load_text(run['timing'])}"


Block = tuple[tuple[str, str], Callable[[], str]]  # a page's marker pair and what writes between them
PROVENANCE_MARKERS = ("<!-- provenance -->\n", "<!-- /provenance -->")


def provenance_text(folders: Sequence[Path]) -> str:
    return (
        "The code, machine and versions behind the archived runs (each run's `versions.json`; a resumed run counts "
        "under the commit it started at):\n\n" + provenance_table(folders)
    )


def page_main(
    doc: str,
    page: Path,
    blocks: Sequence[Block],
    steps: Mapping[str, Callable[[], None]],
    archives: Sequence[Path] = (),
) -> int:
    """A report page's command line. Without options it runs its steps (a step skips what is archived already),
    all of them or those named by --only, then writes the page's blocks from the archive; --write only writes them,
    and --check exits 1 where the page differs from what its archive gives. Every page ends with the provenance of
    the runs archived under its runs/ and in `archives`."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only check that the page's tables are the archive's")
    parser.add_argument("--write", action="store_true", help="only rewrite the page's tables")
    if len(steps) > 1:
        parser.add_argument("--only", choices=list(steps), action="append", help="run only this step (repeatable)")
    parser.add_argument(
        "--max-minutes",
        type=float,
        help="stop training after this long, checkpointed; the same command carries the runs on",
    )
    args = parser.parse_args()
    stop_on_sigterm()
    if args.max_minutes is not None:
        DEADLINE.at = time.monotonic() + args.max_minutes * 60
    if not (args.check or args.write):
        for name in getattr(args, "only", None) or steps:
            steps[name]()
    path = page / "README.md"
    text = read_text(path)
    provenance = (PROVENANCE_MARKERS, lambda: provenance_text([page / "runs", *archives]))
    for markers, render in [*blocks, provenance]:
        text = replace_between(text, markers, render())
    return sync({path: text}, args.check, f"{page.relative_to(ROOT)}/run.py --write")
