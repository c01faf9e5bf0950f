"""Where a bench or tune job's run folder stands (`run_status`: new, partial, ended or done at a budget), read
from its checkpoints, config.toml and summary.json, each of which may be damaged or missing."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from canter import run_layout
from canter.errors import CanterError
from canter.parsing import json_value
from canter.run_layout import SUMMARY_FILE, StopReason


def run_status(run_dir: Path, total_steps: int, stop_at_return: float | None = None) -> str:
    """`done` (trained to total_steps, or stopped on reaching `stop_at_return`, the target it is run with now),
    `ended` (its final checkpoint at this budget is saved, its summary.json is not), `partial` (stopped after a
    checkpoint) or `new` (nothing usable). A run trained on past this budget since is refused: its checkpoint at
    the budget may be gone, and evaluating a later one would report another budget's policy."""
    from canter.training import run_folder

    summary = read_usable_summary(run_dir) or {}
    found = run_folder.list_checkpoints(run_dir)
    newest = run_folder.step_of(found[-1]) if found else None
    summarized = summary.get("global_step")
    stale = newest is not None and (not isinstance(summarized, int) or newest > summarized)  # a resume since
    if newest is not None and newest >= total_steps:
        budget = _budget(found[-1])
        if budget is UNREADABLE:  # a resume reads it next, and says what is wrong with it
            return "partial"
        if budget is not None and budget != total_steps:
            raise CanterError(
                f"{run_dir} was trained on toward a budget of {budget:,} steps (to step {newest:,}) after this "
                f"one's {total_steps:,}; give --total-steps {budget}, or move the folder away to train it again"
            )
        if stale and budget == total_steps:
            return "ended"
    if stale:
        return "partial"
    if isinstance(summarized, int) and summarized >= total_steps:
        return "done"
    reached = summary.get("recent_return")
    if (
        summary.get("stop_reason") == StopReason.TARGET
        and stop_at_return is not None
        and reached is not None
        and reached >= stop_at_return
    ):
        # Its schedules (an annealed learning rate) stretched over the budget it trained toward, so it is a run of
        # that budget, whatever step it stopped at.
        budget = _config_budget(run_dir)
        if budget is not None and budget != total_steps:
            raise CanterError(
                f"{run_dir} reached its target return while training toward a budget of {budget:,} steps, not this "
                f"one's {total_steps:,}; give --total-steps {budget}, or move the folder away to train it again"
            )
        return "done"
    if found:
        return "partial"
    problem = summary_problem(read_json(run_dir / SUMMARY_FILE))
    if problem and (run_dir / SUMMARY_FILE).is_file():  # and no checkpoint to write it again from
        raise CanterError(
            f"{run_dir / SUMMARY_FILE} is damaged ({problem}); restore it from a copy, or move {run_dir} away to "
            f"train it again"
        )
    return "new"


def _config_budget(run_dir: Path) -> int | None:
    """run.total_steps of the run folder's config.toml; None where it has none that canter reads."""
    from canter.training.run_folder import read_config

    try:
        return read_config(run_dir).run.total_steps
    except (CanterError, OSError):
        return None


UNREADABLE = -1  # `_budget` of a checkpoint whose header cannot be read


def _budget(path: Path) -> int | None:
    """run.total_steps of the config a checkpoint was written with: None where its header holds no config,
    UNREADABLE where the file is damaged."""
    from canter.config.serialize import from_toml_text
    from canter.training import checkpoint

    try:
        header = checkpoint.read_header(path)
    except CanterError:
        return UNREADABLE
    try:
        return from_toml_text(header["config"], str(path)).run.total_steps
    except (CanterError, KeyError):
        return None


def read_json(path: Path) -> Any:
    """The file's JSON value; None where it is missing or not JSON."""
    try:
        return json_value(path.read_text())
    except (OSError, ValueError):
        return None


def is_number(value: Any) -> bool:
    """A JSON number: NaN counts (a diverged evaluation is one), true and false do not."""
    return isinstance(value, int | float) and not isinstance(value, bool)


# summary.json values that the bench reads, each with a test of its type; a file that gives another type is damaged.
_SUMMARY_CHECKS: dict[str, tuple[str, Callable[[Any], bool]]] = {
    "global_step": ("a whole number", lambda v: isinstance(v, int) and not isinstance(v, bool)),
    "wall_seconds": ("a number", is_number),
    "sps": ("a number", is_number),
    "recent_return": ("a number", lambda v: v is None or is_number(v)),
    "stop_reason": ("a string", lambda v: isinstance(v, str)),
    "trained_with": (
        "a list of seeds",
        lambda v: v is None or (isinstance(v, list) and all(isinstance(s, int) for s in v)),
    ),
}


def summary_problem(summary: Any) -> str | None:
    """What makes a summary.json's content unusable ('not a JSON object', 'sps is not a number'); None when the
    bench can read it. A value it lacks is no problem: summaries written by older versions lack some."""
    if not isinstance(summary, dict):
        return "not a JSON object"
    for key, (kind, valid) in _SUMMARY_CHECKS.items():
        if key in summary and not valid(summary[key]):
            return f"{key} is not {kind}"
    return None


def read_usable_summary(run_dir: Path) -> dict[str, Any] | None:
    """A run's summary.json; None where it is missing, or damaged (`summary_problem`): a run with its final
    checkpoint has it written again from that checkpoint, as after a kill between the two writes."""
    summary = run_layout.read_summary(run_dir)
    return None if summary is None or summary_problem(summary) else summary
