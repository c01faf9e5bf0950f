"""MLflow: one MLflow run per seed, the child of a parent run per experiment (extra `canter[mlflow]`).

`--mlflow-uri` picks the tracking store (default: MLflow's own, MLFLOW_TRACKING_URI or sqlite:///mlflow.db in the
working folder); the MLflow
experiment is `canter` unless MLFLOW_EXPERIMENT_NAME says otherwise. The client talks to the store directly, so
the seeds of a group log side by side without MLflow's process-global active run."""

from __future__ import annotations

import logging
import math
import os
import time
from pathlib import Path
from typing import Any

from canter.errors import CanterError, first_line, first_sentence
from canter.run_layout import CONFIG_FILE, SUMMARY_FILE
from canter.training.trackers.base import RunContext, TrackSpec

GROUP_TAG = "canter.group"
PARENT_TAG = "canter.parent"
MAX_PARAMS_PER_BATCH = 100  # MLflow's limit for one log_batch
# A run's start time is stamped by the job that makes it, before the store has it: a parent stamped earlier than
# another may become visible later. Waiting this long before the second look lets it show up.
PARENT_SETTLE_S = 1.0


_CLIENTS: dict[tuple[str | None, str | None, str], Any] = {}


def _client(spec: TrackSpec) -> Any:
    """The client of the store, opened once per process: opening checks the store's schema, a second or more."""
    key = (spec.mlflow_uri, os.environ.get("MLFLOW_TRACKING_URI"), os.getcwd())  # what picks the store
    if key not in _CLIENTS:
        _CLIENTS[key] = _open_client(spec)
    return _CLIENTS[key]


# MLflow retries a request to an unreachable server 7 times with backoff (about 4 minutes), and the training loop
# logs synchronously: a store that went away would stall training that long before the tracker is dropped. These
# bound it to a few seconds, unless the user set them.
_RETRY_BOUNDS = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "2", "MLFLOW_HTTP_REQUEST_TIMEOUT": "20"}
# A database store it cannot open (an unwritable SQLite path, a database server that is down) MLflow tries 10 times
# with backoff, about 100 s of warnings, and no setting bounds it: 3 tries take half a second.
DATABASE_TRIES = 3


def _open_client(spec: TrackSpec) -> Any:
    for name, value in _RETRY_BOUNDS.items():
        os.environ.setdefault(name, value)
    try:
        import mlflow.store.db.utils as database
        from mlflow.tracking import MlflowClient
    except ImportError:
        raise CanterError("--track mlflow needs the MLflow client; install canter[mlflow]") from None
    database.MAX_RETRY_COUNT = min(database.MAX_RETRY_COUNT, DATABASE_TRIES)
    logging.getLogger("mlflow").setLevel(logging.WARNING)  # not its notes on creating a store's tables
    logging.getLogger("mlflow.store.db.utils").setLevel(logging.ERROR)  # not a warning per retry: the error says it
    try:
        client = MlflowClient(tracking_uri=spec.mlflow_uri)
        client.search_experiments(max_results=1)  # opens the store: a bad URI fails here, before training
    except Exception as exc:
        where = f"--mlflow-uri {spec.mlflow_uri}" if spec.mlflow_uri else "MLflow's default tracking store"
        raise CanterError(
            f"{where} cannot be opened ({store_refusal(exc)}); pass e.g. --mlflow-uri sqlite:///mlflow.db"
        ) from None
    return client


# The setting that lets MLflow (3.x) open a plain folder as its store, which its refusal of one names.
FILE_STORE_OPT_IN = "MLFLOW_ALLOW_FILE_STORE"
REASON_CHARS = 300  # a reason longer than this (a server's page) is cut


def store_refusal(exc: BaseException) -> str:
    """Why MLflow would not open a store, in one line. Its refusal of a plain folder (a file store: a path, file:
    URI or bare word) is a paragraph whose first sentence only says that backend is "in maintenance mode"; the
    refusal is told by the opt-out it names. Other errors give their first sentence, cut to REASON_CHARS."""
    if FILE_STORE_OPT_IN in str(exc):
        return f"MLflow no longer writes to a plain folder, a file store, unless {FILE_STORE_OPT_IN}=true is set"
    reason = " ".join(first_sentence(exc).split())
    return reason if len(reason) <= REASON_CHARS else reason[: REASON_CHARS - 3].rstrip() + "..."


class MlflowTracker:
    def check(self, spec: TrackSpec) -> None:
        _client(spec)

    def open_group(self, spec: TrackSpec, group: str) -> str:
        client = _client(spec)
        try:
            return _parent_run_id(client, _experiment_id(client), group)
        except Exception as exc:
            raise CanterError(f"--track mlflow could not make the parent run of {group}: {first_line(exc)}") from None

    def start(self, context: RunContext, run_id: str | None) -> _MlflowRun:
        from mlflow.entities import Param

        client = _client(context.spec)
        try:
            if run_id is not None:
                client.update_run(run_id, status="RUNNING")
                _tag_changed_settings(client, run_id, context.config)
                return _MlflowRun(client, run_id)
            experiment = _experiment_id(client)
            opened = context.spec.group_run("mlflow", context.group)
            parent = opened or _parent_run_id(client, experiment, context.group)
            run = client.create_run(
                experiment,
                run_name=context.name,
                tags={
                    "mlflow.parentRunId": parent,
                    GROUP_TAG: context.group,
                    "canter.run_dir": str(context.out.resolve()),
                    **dict(context.spec.tags),
                },
            )
            params = [Param(k, str(v)) for k, v in context.config.items()]
            for i in range(0, len(params), MAX_PARAMS_PER_BATCH):
                client.log_batch(run.info.run_id, params=params[i : i + MAX_PARAMS_PER_BATCH])
        except Exception as exc:
            raise CanterError(f"--track mlflow could not start an MLflow run: {first_line(exc)}") from None
        return _MlflowRun(client, run.info.run_id)


def _experiment_id(client: Any) -> str:
    name = os.environ.get("MLFLOW_EXPERIMENT_NAME", "canter")
    experiment = client.get_experiment_by_name(name)
    if experiment is not None:
        return str(experiment.experiment_id)
    try:
        return str(client.create_experiment(name))
    except Exception:  # a job that started at the same time made it first
        experiment = client.get_experiment_by_name(name)
        if experiment is None:
            raise
        return str(experiment.experiment_id)


def _parent_run_id(client: Any, experiment: str, group: str) -> str:
    """The group's parent run, made by the tune or bench process before its jobs (`open_group`), or else by the
    group's first run. A parent only groups: it is FINISHED at once.

    Processes that start together (tune workers sharing a study, `canter train` runs of one experiment) may each
    make one. The oldest is the parent: each looks again
    `PARENT_SETTLE_S` after making its own, when every parent stamped before its own is visible, so all pick the
    same one, and a job whose parent is not that one deletes it."""
    found = _oldest_parent(client, experiment, group)
    if found is not None:
        return found
    made = client.create_run(experiment, run_name=group, tags={PARENT_TAG: "true", GROUP_TAG: group}).info.run_id
    client.set_terminated(made, "FINISHED")
    time.sleep(PARENT_SETTLE_S)
    oldest = _oldest_parent(client, experiment, group) or made
    if oldest != made:
        client.delete_run(made)
    return str(oldest)


def _oldest_parent(client: Any, experiment: str, group: str) -> str | None:
    found = client.search_runs(
        [experiment],
        filter_string=f"tags.`{PARENT_TAG}` = 'true' and tags.`{GROUP_TAG}` = {_quoted(group)}",
        order_by=["attributes.start_time ASC"],
        max_results=50,
    )
    return str(min(found, key=lambda r: (r.info.start_time, r.info.run_id)).info.run_id) if found else None


def _quoted(value: str) -> str:
    """A string literal of MLflow's filter syntax, which has no escapes: a name with a single quote takes double ones
    (a tune --study such as bob's)."""
    if "'" in value and '"' in value:
        raise CanterError(f"MLflow cannot search for the group {value!r}, which holds both kinds of quote; rename it")
    return f'"{value}"' if "'" in value else f"'{value}'"


def absolute_store(uri: str) -> str:
    """A tracking URI with a path relative to the working folder made absolute: a SQLite file or a plain folder."""
    sqlite = "sqlite:///"
    if uri.startswith(sqlite) and not uri.startswith(sqlite + "/"):
        path, mark, query = uri[len(sqlite) :].partition("?")
        if path in ("", ":memory:"):
            return uri
        return sqlite + os.path.abspath(path) + mark + query
    if uri.startswith("file:") and not uri.startswith("file:/"):  # file:./mlruns
        return "file://" + os.path.abspath(uri[len("file:") :])
    if ":" not in uri and (uri.startswith(".") or os.path.isdir(uri)):  # not a scheme such as databricks
        return os.path.abspath(uri)
    return uri


def _tag_changed_settings(client: Any, run_id: str, config: dict[str, Any]) -> None:
    """MLflow cannot change a logged parameter, so a setting that a resume changed (its budget, say) is a tag of
    the same name holding the value the run now trains with."""
    logged = client.get_run(run_id).data.params
    for key, value in config.items():
        if key in logged and logged[key] != str(value):
            client.set_tag(run_id, key, str(value))


class _MlflowRun:
    def __init__(self, client: Any, run_id: str) -> None:
        self._client = client
        self.run_id = run_id
        # Absolute: a store named relative to the working folder (sqlite:///mlflow.db, the default's too) must be found
        # again by a resume started elsewhere.
        self.place = {"uri": absolute_store(str(client.tracking_uri))}

    def log(self, values: dict[str, float], step: int) -> None:
        from mlflow.entities import Metric

        stamp = int(time.time() * 1000)
        metrics = [Metric(k, v, stamp, step) for k, v in values.items()]
        self._client.log_batch(self.run_id, metrics=metrics)

    def finish(self, out: Path, summary: dict[str, Any]) -> None:
        numbers = {k: float(v) for k, v in summary.items() if isinstance(v, int | float) and math.isfinite(v)}
        step = int(summary.get("global_step", 0))
        self.log({f"summary/{k}": v for k, v in numbers.items()}, step)
        self._client.set_tag(self.run_id, "canter.stop_reason", str(summary.get("stop_reason")))
        for name in (SUMMARY_FILE, CONFIG_FILE):
            self._client.log_artifact(self.run_id, str(out / name))
        self._client.set_terminated(self.run_id, "FINISHED")

    def close(self) -> None:
        self._client.set_terminated(self.run_id, "FAILED")
