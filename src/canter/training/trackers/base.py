"""What a tracker backend is: a check before training, then one tracker run per seed."""

from __future__ import annotations

from dataclasses import dataclass, field
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
    # (tracker, group, id): each group's own record (MLflow's parent run), opened once by the tune or bench process
    # before its jobs start, so that jobs starting together never each make one (`open_groups`)
    group_runs: tuple[tuple[str, str, str], ...] = ()

    def group_run(self, tracker: str, group: str) -> str | None:
        """The id of the group's own record in this tracker, when the tune or bench process opened it."""
        return next((run_id for name, g, run_id in self.group_runs if (name, g) == (tracker, group)), None)

    def to_dict(self) -> dict[str, Any]:
        """As JSON takes it (a job's job.json)."""
        return {
            "names": list(self.names),
            "mlflow_uri": self.mlflow_uri,
            "group": self.group,
            "run_prefix": self.run_prefix,
            "tags": [list(tag) for tag in self.tags],
            "group_runs": [list(run) for run in self.group_runs],
        }

    @staticmethod
    def from_dict(data: dict[str, Any]) -> TrackSpec:
        return TrackSpec(
            tuple(data.get("names", ())),
            data.get("mlflow_uri"),
            data.get("group"),
            data.get("run_prefix"),
            tuple((str(k), str(v)) for k, v in data.get("tags", ())),
            tuple((str(t), str(g), str(i)) for t, g, i in data.get("group_runs", ())),
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
    # On a resume, what RUN/trackers.json recorded for this tracker (its run id, and where the run lives: a
    # TrackerRun's `place`), so that the run is found whatever folder or environment the resume starts from.
    recorded: dict[str, Any] = field(default_factory=dict)


class TrackerRun(Protocol):
    """One seed's run in a tracker. Any method may raise: the caller warns once and stops using it."""

    run_id: str
    # Where the run lives, recorded in RUN/trackers.json beside its id (MLflow's resolved store URI, W&B's project
    # and entity); a run without the attribute records none.
    place: dict[str, str]

    def log(self, values: dict[str, float], step: int) -> None: ...

    def finish(self, out: Path, summary: dict[str, Any]) -> None:
        """Upload the final summary and artifacts (summary.json, config.toml) and end the run."""

    def close(self) -> None:
        """End a run that did not finish (a failed or interrupted seed)."""


class Tracker(Protocol):
    """A tracker backend, registered by name in `canter.training.trackers.registry`."""

    def check(self, spec: TrackSpec) -> None:
        """Raise a one-line CanterError if it cannot start (library missing, bad store); nothing is created."""

    def open_group(self, spec: TrackSpec, group: str) -> str | None:
        """Make or find the group's own record (MLflow's parent run) and return its id, or None for a tracker whose
        groups are only names. Called once per group by a tune or bench process before its jobs start."""

    def start(self, context: RunContext, run_id: str | None) -> TrackerRun:
        """Start the seed's tracker run, or continue `run_id` (a resume). Raises CanterError if it cannot."""
        ...
