"""What a tracker backend is: a check before training, then one tracker run per seed."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol


@dataclass(frozen=True)
class TrackSpec:
    """The trackers of a `canter train` (`--track`, repeatable) and where MLflow writes (`--mlflow-uri`)."""

    names: tuple[str, ...] = ()
    mlflow_uri: str | None = None


@dataclass(frozen=True)
class RunContext:
    """What a tracker run is started with: the seed's config (flat `section.key` settings), its run folder, and
    the group its seeds share (one experiment)."""

    config: dict[str, Any]
    out: Path
    group: str
    spec: TrackSpec


class TrackerRun(Protocol):
    """One seed's run in a tracker. Any method may raise: the caller warns once and stops using it."""

    run_id: str

    def log(self, values: dict[str, float], step: int) -> None: ...

    def finish(self, out: Path, summary: dict[str, Any]) -> None:
        """Upload the final summary and artifacts (summary.json, config.toml) and end the run."""

    def close(self) -> None:
        """End a run that did not finish (a failed or interrupted seed)."""


class Tracker(Protocol):
    """A tracker backend, registered by name in `canter.training.trackers.registry`."""

    def check(self, spec: TrackSpec) -> None:
        """Raise a one-line CanterError if it cannot start (library missing, bad store); nothing is created."""

    def start(self, context: RunContext, run_id: str | None) -> TrackerRun:
        """Start the seed's tracker run, or continue `run_id` (a resume). Raises CanterError if it cannot."""
        ...
