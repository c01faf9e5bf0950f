"""Tracker names for `--track NAME` (`canter train`, `tune`, `bench`)."""

from __future__ import annotations

from canter.errors import CanterError
from canter.training.trackers.base import Tracker
from canter.training.trackers.mlflow_tracker import MlflowTracker
from canter.training.trackers.wandb_tracker import WandbTracker

TRACKERS: dict[str, Tracker] = {"wandb": WandbTracker(), "mlflow": MlflowTracker()}


def tracker_names() -> list[str]:
    return sorted(TRACKERS)


def get_tracker(name: str) -> Tracker:
    if name not in TRACKERS:
        raise CanterError(f"unknown tracker {name!r}; choose from {', '.join(tracker_names())}")
    return TRACKERS[name]


_TRACKER_METHODS = tuple(name for name, value in vars(Tracker).items() if callable(value) and not name.startswith("_"))


def register_tracker(name: str, tracker: Tracker) -> None:
    """Add a tracker backend (a plugin, or a test's); one lacking a method of `Tracker` is refused here, not when a
    tune or bench first calls it."""
    missing = [method for method in _TRACKER_METHODS if not callable(getattr(tracker, method, None))]
    if missing:
        raise CanterError(
            f"tracker {name!r} lacks {', '.join(missing)}; a tracker implements every method of "
            f"canter.training.trackers.base.Tracker"
        )
    TRACKERS[name] = tracker
