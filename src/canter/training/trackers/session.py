"""Trackers during training: checked before it starts, one tracker run per seed, never able to stop a run.

`canter train --track ...` enters `tracking(spec)`, which checks every tracker (`check_trackers`: a one-line
CanterError before any env exists) and makes them the trackers of the runs trained inside it; `canter tune` and
`canter bench` check them before their first job and each job trains inside `tracking`; `canter.training.seed_run` asks
`open_for_run` for each seed's `SeedTrackers` (none outside `tracking`). The run folder stays the source of truth:
a tracker that fails mid-run prints one warning line and is dropped, and the run goes on. Each seed's tracker run
ids are kept in RUN/trackers.json, so that a resume continues the same tracker runs."""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import json
import math
import sys
from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from canter.config.experiment import experiment_key, flat_config
from canter.config.schema import Config
from canter.errors import CanterError, first_line
from canter.files import atomic_write_bytes
from canter.parsing import json_value
from canter.run_layout import TRACKERS_FILE
from canter.training.trackers.base import RunContext, TrackerRun, TrackSpec
from canter.training.trackers.registry import get_tracker

_ACTIVE: contextvars.ContextVar[TrackSpec | None] = contextvars.ContextVar("canter_trackers", default=None)


@contextlib.contextmanager
def tracking(spec: TrackSpec) -> Iterator[None]:
    """Train with these trackers inside the block. Every tracker is checked first."""
    check_trackers(spec)
    token = _ACTIVE.set(spec if spec.names else None)
    try:
        yield
    finally:
        _ACTIVE.reset(token)


def check_trackers(spec: TrackSpec) -> None:
    """A one-line CanterError if a tracker is unknown or cannot start (its library missing, a store that does not
    open); nothing is created."""
    for name in spec.names:
        get_tracker(name).check(spec)


def open_groups(spec: TrackSpec, groups: Sequence[str]) -> TrackSpec:
    """The spec with each group's own tracker records (MLflow's parent runs) made or found now, once, so that the jobs
    of a tune or bench that start together share them instead of each making one."""
    opened = [
        (name, group, run_id)
        for name in spec.names
        for group in dict.fromkeys(groups)
        if (run_id := get_tracker(name).open_group(spec, group)) is not None
    ]
    return replace(spec, group_runs=(*spec.group_runs, *opened))


def resume_spec(names: Sequence[str], mlflow_uri: str | None, run_dirs: Sequence[Path]) -> TrackSpec:
    """The trackers of a resume: those given, and those the run folders were tracked with (and their MLflow
    store, unless another is given)."""
    recorded = [read_ids(Path(d)) for d in run_dirs]
    all_names = list(dict.fromkeys([*names, *(name for ids in recorded for name in ids)]))
    stored_uri = next((ids["mlflow"].get("uri") for ids in recorded if "mlflow" in ids), None)
    return TrackSpec(tuple(all_names), mlflow_uri or stored_uri)


def group_name(config: Config) -> str:
    """The name the seeds of one experiment share: its env and algorithm, and a digest of its learning keys."""
    digest = hashlib.sha1(repr(experiment_key(config)).encode()).hexdigest()[:10]
    return f"{config.env.id.split(':')[-1]}-{config.run.algo}-{digest}"


def read_ids(run_dir: Path) -> dict[str, dict[str, Any]]:
    path = run_dir / TRACKERS_FILE
    if not path.is_file():
        return {}
    try:
        ids = json_value(path.read_text())
    except ValueError:
        ids = None
    if not isinstance(ids, dict) or not all(isinstance(entry, dict) for entry in ids.values()):
        raise CanterError(f"{path} is not the JSON canter writes; delete it to resume with new tracker runs")
    return ids


def open_for_run(config: Config, out: Path, resumed: bool) -> SeedTrackers:
    """The seed's tracker runs (new ones, or on a resume those of RUN/trackers.json), started before training."""
    spec = _ACTIVE.get()
    if spec is None:
        return SeedTrackers({})
    recorded = read_ids(out) if resumed else {}
    name = f"{spec.run_prefix}-{out.name}" if spec.run_prefix else out.name
    fresh = RunContext(flat_config(config), out, spec.group or group_name(config), name, spec)
    contexts: dict[str, RunContext] = {}
    runs: dict[str, TrackerRun] = {}
    try:
        for tracker in spec.names:
            earlier = recorded.get(tracker, {})
            # A continued tracker run keeps the group and name it was started with, whoever resumes it.
            contexts[tracker] = replace(
                fresh, group=earlier.get("group", fresh.group), name=earlier.get("name", fresh.name), recorded=earlier
            )
            try:
                runs[tracker] = get_tracker(tracker).start(contexts[tracker], earlier.get("run_id"))
            except CanterError as exc:
                if "run_id" not in earlier:
                    raise
                raise CanterError(f"{exc}; to resume without it, delete {out / TRACKERS_FILE}") from None
    except BaseException:
        SeedTrackers(runs).close()
        raise
    ids = dict(recorded)
    for tracker, run in runs.items():
        ids[tracker] = {"run_id": run.run_id, "group": contexts[tracker].group, "name": contexts[tracker].name}
        ids[tracker].update(getattr(run, "place", {}))
    atomic_write_bytes(out / TRACKERS_FILE, lambda f: f.write(json.dumps(ids, indent=2).encode()))
    return SeedTrackers(runs)


class SeedTrackers:
    """One seed's tracker runs. Nothing a tracker raises reaches the training loop."""

    def __init__(self, runs: dict[str, TrackerRun]) -> None:
        self._runs = runs

    def log(self, row: dict[str, Any]) -> None:
        """A metrics.csv row, every column but global_step (the step) and its empty cells."""
        step = int(row["global_step"])
        values = {k: float(v) for k, v in row.items() if k != "global_step" and v is not None}
        values = {k: v for k, v in values.items() if not math.isnan(v)}
        self._each("logging", lambda run: run.log(values, step))

    def finish(self, out: Path, summary: dict[str, Any]) -> None:
        self._each("finishing", lambda run: run.finish(out, summary))
        self._runs = {}

    def close(self) -> None:
        self._each("closing", lambda run: run.close())
        self._runs = {}

    def _each(self, doing: str, call: Any) -> None:
        for name, run in list(self._runs.items()):
            try:
                call(run)
            except Exception as exc:
                del self._runs[name]
                print(
                    f"canter: warning: tracker {name} failed while {doing} ({first_line(exc)}); training goes on "
                    f"without it, the run folder has everything",
                    file=sys.stderr,
                )
