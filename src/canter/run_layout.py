"""The names of a run folder's own files and folders, and which of them a folder holds.

They sit below every layer because the safe-write guards (canter.files) must know them too: a user-named output
never replaces a run's own file. Each caller asks its own question of `run_files_in`: a new run refuses a folder
with any sign of a run, while an output guard refuses only a folder that is surely one.
"""

import re
from enum import StrEnum
from pathlib import Path
from typing import Any

from canter.errors import CanterError
from canter.parsing import json_value

CONFIG_FILE = "config.toml"
METRICS_FILE = "metrics.csv"
ARCHIVED_METRICS_FILE = METRICS_FILE + ".gz"
SUMMARY_FILE = "summary.json"
VERSIONS_FILE = "versions.json"
TRACKERS_FILE = "trackers.json"  # the tracker runs a run logs to (canter.training.trackers.session)
EVAL_FILE = "eval.json"
CHECKPOINT_FOLDER = "checkpoints"
TENSORBOARD_FOLDER = "tb"
VIDEOS_FOLDER = "videos"  # videos rendered while a run trains (canter.training.videos)
STEP_VIDEO = "step_*.mp4"  # in videos/: the video of one step
# In videos/ too: the renderer's output, the states it renders from, and unfinished videos (atomic writes' temp files).
VIDEO_WORK_FILES = ("render.log", ".snapshot_*.npz", ".*.tmp*")
# The writer lock (canter.training.run_lock) of each folder canter trains into: a run's, a bench's or a tune's. Not
# one of RUN_OWN_FILES, which tell a run: a folder whose first run was refused keeps its lock and is no run.
LOCK_FILE = ".writer.lock"
CHECKPOINT_NAME = re.compile(r"^ckpt_(\d{12})\.npz$")
BEST_FILE = "best.npz"  # in checkpoints/: the state of the best evaluation during training
# In checkpoints/ too, while a best.npz newer than the newest checkpoint has replaced it: the best.npz that this
# checkpoint's training had, which a resume from the checkpoint puts back.
KEPT_BEST_FILE = ".best_at_checkpoint.npz"

RUN_OWN_FILES = frozenset(
    {CONFIG_FILE, METRICS_FILE, ARCHIVED_METRICS_FILE, SUMMARY_FILE, VERSIONS_FILE, TRACKERS_FILE, EVAL_FILE}
)
RUN_OWN_FOLDERS = frozenset({CHECKPOINT_FOLDER, TENSORBOARD_FOLDER})


class StopReason(StrEnum):
    """Why a run stopped, as summary.json's `stop_reason` records it."""

    BUDGET = "budget"  # it trained run.total_steps
    TARGET = "stop_at_return"  # its recent training return reached run.stop_at_return
    MAX_MINUTES = "max_minutes"
    SIGNAL = "signal"
    NON_FINITE = "non_finite"  # its losses or parameters diverged


FINISHED = frozenset({StopReason.BUDGET, StopReason.TARGET})  # the others stop a run that a resume goes on with


def checkpoints_in(folder: Path) -> list[Path]:
    """The `ckpt_<step>.npz` files in the run folder's checkpoints/, oldest first."""
    checkpoints = Path(folder) / CHECKPOINT_FOLDER
    if not checkpoints.is_dir():
        return []
    return sorted(p for p in checkpoints.iterdir() if CHECKPOINT_NAME.match(p.name))


def run_files_in(folder: Path) -> frozenset[str]:
    """The run's own files that `folder` holds, by name, with checkpoints/ counted only when it holds a checkpoint."""
    folder = Path(folder)
    held = {name for name in RUN_OWN_FILES if (folder / name).is_file()}
    if checkpoints_in(folder):
        held.add(CHECKPOINT_FOLDER)
    return frozenset(held)


def read_object(path: Path) -> dict[str, Any] | None:
    """A JSON file's object; None where the file is missing, not JSON, or holds anything else (a damaged or
    hand-edited file)."""
    try:
        data = json_value(Path(path).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def read_summary(folder: Path) -> dict[str, Any] | None:
    """The run's summary.json; None where it is missing (a run writes it when it stops), damaged or hand-edited."""
    return read_object(Path(folder) / SUMMARY_FILE)


def evaluates_newest_checkpoint(folder: Path, evaluation: dict[str, Any]) -> bool:
    """Whether an eval.json's content is of the run's newest checkpoint (one from before a resume is stale); a
    finished run kept without its checkpoints (an archive) has only its eval.json to go by."""
    found = checkpoints_in(folder)
    return not found or evaluation.get("checkpoint") == found[-1].name


def has_finished(folder: Path) -> bool:
    """A bench's evaluation, archived metrics, or a summary that says the run trained its budget or met its target:
    a finished run's files. A summary of a stop (a signal, even during the compile, or --max-minutes) is not."""
    held = run_files_in(folder)
    if held & {EVAL_FILE, ARCHIVED_METRICS_FILE}:
        return True
    reason = (read_summary(folder) or {}).get("stop_reason")
    return isinstance(reason, str) and reason in FINISHED  # a hand-edited value may be a list, which no set holds


def finished_without_checkpoints(folder: Path) -> bool:
    """A finished run kept without its checkpoints (an archive): not one stopped before its first checkpoint."""
    return not checkpoints_in(folder) and has_finished(folder)


def surely_a_run(folder: Path) -> bool:
    """A config.toml with the run's metrics, versions or a checkpoint: a config.toml beside a checkpoints/ folder of
    other files may be a user's project with its own outputs, so a name alone proves nothing."""
    held = run_files_in(folder)
    return CONFIG_FILE in held and bool(held & {METRICS_FILE, ARCHIVED_METRICS_FILE, VERSIONS_FILE, CHECKPOINT_FOLDER})


# The run folder's layout version, recorded in versions.json: a reader refuses a folder of a newer format.
RUN_FORMAT = 2


def versions_record(run_dir: Path) -> tuple[dict[str, Any], str | None]:
    """What versions.json holds, and what is wrong with it (None for a whole file): missing, empty, not JSON or not
    an object. Errors other than a missing file (no permission) are raised."""
    path = Path(run_dir) / VERSIONS_FILE
    try:
        text = path.read_text(errors="replace")
    except FileNotFoundError:
        return {}, "missing"
    if not text.strip():
        return {}, "empty"
    try:
        data = json_value(text)
    except ValueError:
        # The format of a damaged file still counts where it survives: one of a newer canter must stay refused.
        found = re.search(r'"run_format"\s*:\s*(\d+)', text)
        return ({"run_format": int(found.group(1))} if found else {}), "cut short or not JSON"
    if isinstance(data, dict):
        return data, None
    return {}, f"a JSON {_JSON_TYPES.get(type(data), type(data).__name__)}, not an object"


_JSON_TYPES = {list: "array", str: "string", int: "number", float: "number", bool: "boolean", type(None): "null"}


def read_versions(run_dir: Path) -> dict[str, Any]:
    try:
        return versions_record(run_dir)[0]
    except OSError:  # reading never stops at the version record: a folder without one reads as format 1
        return {}


def run_format(run_dir: Path) -> int:
    """The folder's format version (1 when versions.json does not name one)."""
    value = read_versions(run_dir).get("run_format", 1)
    # JSON's true, 2.5 and "2" would pass int(): only a JSON whole number is a format that canter wrote.
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise CanterError(
            f"{Path(run_dir) / VERSIONS_FILE} has run_format {value!r}, not a whole number from 1; restore it (1 "
            f"for a folder without one)"
        )
    if value > RUN_FORMAT:
        raise CanterError(
            f"{run_dir} has run-folder format {value}, this canter reads up to {RUN_FORMAT}; use a newer canter"
        )
    return value


def holds_every_section(config_file: str | Path) -> bool:
    """Whether `config_file` is the config.toml of a format-1 run folder, which holds every algorithm's section,
    read or not (`canter.config.build.build_config` leaves out those the run's algorithm does not read)."""
    folder = Path(config_file).parent
    return Path(config_file).name == CONFIG_FILE and surely_a_run(folder) and run_format(folder) == 1
