"""MLflow: one MLflow run per seed, the child of a parent run per experiment (extra `canter[mlflow]`).

`--mlflow-uri` picks the tracking store (default: MLflow's own, MLFLOW_TRACKING_URI or ./mlruns); the MLflow
experiment is `canter` unless MLFLOW_EXPERIMENT_NAME says otherwise. The client talks to the store directly, so
the seeds of a group log side by side without MLflow's process-global active run."""

from __future__ import annotations

import logging
import math
import os
import time
from pathlib import Path
from typing import Any

from canter.errors import CanterError
from canter.training.trackers.base import RunContext, TrackSpec

GROUP_TAG = "canter.group"
PARENT_TAG = "canter.parent"
MAX_PARAMS_PER_BATCH = 100  # MLflow's limit for one log_batch


def _client(spec: TrackSpec) -> Any:
    try:
        from mlflow.tracking import MlflowClient
    except ImportError:
        raise CanterError("--track mlflow needs the MLflow client; install canter[mlflow]") from None
    logging.getLogger("mlflow").setLevel(logging.WARNING)  # not its notes on creating a store's tables
    try:
        client = MlflowClient(tracking_uri=spec.mlflow_uri)
        client.search_experiments(max_results=1)  # opens the store: a bad URI fails here, before training
    except Exception as exc:
        where = f"--mlflow-uri {spec.mlflow_uri}" if spec.mlflow_uri else "MLflow's default tracking store"
        raise CanterError(
            f"{where} cannot be opened ({_first_line(exc)}); pass e.g. --mlflow-uri sqlite:///mlflow.db"
        ) from None
    return client


class MlflowTracker:
    def check(self, spec: TrackSpec) -> None:
        _client(spec)

    def start(self, context: RunContext, run_id: str | None) -> _MlflowRun:
        from mlflow.entities import Param

        client = _client(context.spec)
        try:
            if run_id is not None:
                client.update_run(run_id, status="RUNNING")
                return _MlflowRun(client, run_id)
            experiment = _experiment_id(client)
            run = client.create_run(
                experiment,
                run_name=context.out.name,
                tags={
                    "mlflow.parentRunId": _parent_run_id(client, experiment, context.group),
                    GROUP_TAG: context.group,
                    "canter.run_dir": str(context.out.resolve()),
                },
            )
            params = [Param(k, str(v)) for k, v in context.config.items()]
            for i in range(0, len(params), MAX_PARAMS_PER_BATCH):
                client.log_batch(run.info.run_id, params=params[i : i + MAX_PARAMS_PER_BATCH])
        except Exception as exc:
            raise CanterError(f"--track mlflow could not start an MLflow run: {_first_line(exc)}") from None
        return _MlflowRun(client, run.info.run_id)


def _experiment_id(client: Any) -> str:
    name = os.environ.get("MLFLOW_EXPERIMENT_NAME", "canter")
    experiment = client.get_experiment_by_name(name)
    return str(experiment.experiment_id if experiment is not None else client.create_experiment(name))


def _parent_run_id(client: Any, experiment: str, group: str) -> str:
    """The experiment's parent run, made by its first seed. A parent only groups: it is FINISHED at once."""
    found = client.search_runs(
        [experiment], filter_string=f"tags.`{PARENT_TAG}` = 'true' and tags.`{GROUP_TAG}` = '{group}'", max_results=1
    )
    if found:
        return str(found[0].info.run_id)
    parent = client.create_run(experiment, run_name=group, tags={PARENT_TAG: "true", GROUP_TAG: group})
    client.set_terminated(parent.info.run_id, "FINISHED")
    return str(parent.info.run_id)


class _MlflowRun:
    def __init__(self, client: Any, run_id: str) -> None:
        self._client = client
        self.run_id = run_id

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
        for name in ("summary.json", "config.toml"):
            self._client.log_artifact(self.run_id, str(out / name))
        self._client.set_terminated(self.run_id, "FINISHED")

    def close(self) -> None:
        self._client.set_terminated(self.run_id, "FAILED")


def _first_line(exc: Exception) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
