"""Experiment trackers (W&B, MLflow) for `--track` of `canter train`, `tune` and `bench`: optional extras; the run
folder stays the source of truth. See `canter.training.trackers.session`."""

from canter.training.trackers.base import TrackSpec
from canter.training.trackers.registry import register_tracker, tracker_names
from canter.training.trackers.session import (
    check_trackers,
    group_name,
    open_for_run,
    open_groups,
    resume_spec,
    tracking,
)

__all__ = [
    "TrackSpec",
    "check_trackers",
    "group_name",
    "open_for_run",
    "open_groups",
    "register_tracker",
    "resume_spec",
    "tracker_names",
    "tracking",
]
