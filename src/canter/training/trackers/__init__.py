"""Experiment trackers (W&B, MLflow) for `canter train --track`: optional extras; the run folder stays the source
of truth. See `canter.training.trackers.session`."""

from canter.training.trackers.base import TrackSpec
from canter.training.trackers.registry import get_tracker, register_tracker, tracker_names
from canter.training.trackers.session import SeedTrackers, open_for_run, resume_spec, tracking

__all__ = [
    "SeedTrackers",
    "TrackSpec",
    "get_tracker",
    "open_for_run",
    "register_tracker",
    "resume_spec",
    "tracker_names",
    "tracking",
]
