"""What a tracker backend is: a check before training, then one tracker run per seed."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol


@dataclass(frozen=True)
class TrackSpec:
    """The trackers of a `canter train`, `tune` or `bench` (`--track`, repeatable), where MLflow writes
    (`--mlflow-uri`), and, for a tune trial, what its runs are grouped and named by."""

    names: tuple[str, ...] = ()
    mlflow_uri: str | None = None
    group: str | None = None  # the group of every run tracked with this spec; None: one group per experiment
    run_prefix: str | None = None  # tracker runs are named PREFIX-FOLDER (trial_00003-s0); None: the folder name
    tags: tuple[tuple[str, str], ...] = ()  # recorded with each run: MLflow tags, W&B config entries

    def to_dict(self) -> dict[str, Any]:
        """As JSON takes it (a job's job.json)."""
        return {
            "names": list(self.names),
            "mlflow_uri": self.mlflow_uri,
            "group": self.group,
            "run_prefix": self.run_prefix,
            "tags": [list(tag) for tag in self.tags],
        }

    @staticmethod
    def from_dict(data: dict[str, Any]) -> TrackSpec:
        return TrackSpec(
            tuple(data.get("names", ())),
            data.get("mlflow_uri"),
            data.get("group"),
            data.get("run_prefix"),
            tuple((str(k), str(v)) for k, v in data.get("tags", ())),
        )


@dataclass(frozen=True)
class RunContext:
    """What a tracker run is started with: the seed's config (flat `section.key` settings), its run folder, the
    group its seeds share (one experiment, or a tune study) and the run's name."""

    config: dict[str, Any]
    out: Path
    group: str
    name: str
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
