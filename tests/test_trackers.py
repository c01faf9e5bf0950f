"""`canter train --track wandb/mlflow` with the real libraries and no network: W&B offline (its run files read
back), MLflow against a SQLite store (read back with MlflowClient)."""

import contextlib
import json
import math
import os
import struct
import time
from pathlib import Path

import pytest

from canter.cli.main import main
from canter.config.build import build_config
from canter.errors import CanterError
from canter.training.logger import read_rows
from canter.training.loop import train
from canter.training.resume import resume_config
from canter.training.trackers import TrackSpec, register_tracker, tracking
from canter.training.trackers.registry import TRACKERS, tracker_names

TINY_PPO = [
    "--quiet",
    "--backend",
    "envpool",
    "--total-steps",
    "2048",
    "--eval-every",
    "1000",
    "--eval-episodes",
    "2",
] + [
    x
    for s in ("net.hidden=16,16", "run.tensorboard=false", "env.num_envs=4", "ppo.n_steps=128", "ppo.epochs=2")
    for x in ("--set", s)
]


def _offline_wandb(monkeypatch, folder: Path) -> None:
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_DIR", str(folder))
    monkeypatch.setenv("WANDB_SILENT", "true")
    monkeypatch.setenv("WANDB_PROJECT", "canter-test")


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    """Two seeds of one experiment, tracked by W&B (offline) and MLflow (SQLite)."""
    root = tmp_path_factory.mktemp("tracked")
    with pytest.MonkeyPatch.context() as monkeypatch:
        _offline_wandb(monkeypatch, root)
        monkeypatch.chdir(root)  # MLflow's artifacts go to ./mlruns
        uri = f"sqlite:///{root / 'mlflow.db'}"
        argv = ["train", "InvertedPendulum-v4", "--seeds", "0,1", "--out-dir", str(root / "runs")]
        assert main(argv + ["--track", "wandb", "--track", "mlflow", "--mlflow-uri", uri] + TINY_PPO) == 0
    runs = sorted((root / "runs").iterdir())
    assert len(runs) == 2
    return root, uri, runs


def _rows(run: Path) -> list[dict]:
    return read_rows(run / "metrics.csv")[1]


def _same(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-9)


# ------------------------------------------------------------------------------------------------------ MLflow


def _mlflow_run(uri: str, run: Path):
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=uri)
    ids = json.loads((run / "trackers.json").read_text())
    return client, client.get_run(ids["mlflow"]["run_id"])


@pytest.mark.slow
def test_mlflow_gets_every_column_by_step_and_one_parent_per_experiment(tracked):
    _, uri, runs = tracked
    parents = set()
    for run in runs:
        client, tracked_run = _mlflow_run(uri, run)
        assert tracked_run.info.status == "FINISHED"
        assert tracked_run.data.params["run.seed"] in ("0", "1")
        parents.add(tracked_run.data.tags["mlflow.parentRunId"])
        rows = _rows(run)
        assert any(not math.isnan(float(r.get("eval/return_mean") or "nan")) for r in rows)
        for column in rows[0]:
            if column == "global_step":
                continue
            expected = {int(r["global_step"]): float(r[column]) for r in rows if r[column] not in ("", None)}
            expected = {k: v for k, v in expected.items() if not math.isnan(v)}
            history = {m.step: m.value for m in client.get_metric_history(tracked_run.info.run_id, column)}
            assert history.keys() == expected.keys(), column
            assert all(_same(history[k], v) for k, v in expected.items()), column
        summary = json.loads((run / "summary.json").read_text())
        assert tracked_run.data.metrics["summary/global_step"] == summary["global_step"]
        assert {a.path for a in client.list_artifacts(tracked_run.info.run_id)} == {"summary.json", "config.toml"}
    assert len(parents) == 1
    parent = client.get_run(parents.pop())
    assert parent.data.tags["canter.group"] == parent.info.run_name


# ------------------------------------------------------------------------------------------------------ W&B


def _wandb_records(path: Path):
    """The records of an offline run's .wandb file: a 7-byte header, then LevelDB-log blocks of 32 KiB, whose
    chunks (7-byte header: CRC, length, type FULL=1/FIRST=2/MIDDLE=3/LAST=4) carry protobuf Records."""
    from wandb.proto import wandb_internal_pb2

    data, pos, pending = path.read_bytes(), 7, b""
    while pos + 7 <= len(data):
        if 32768 - pos % 32768 < 7:  # a block's tail too short for a header is padding
            pos += 32768 - pos % 32768
            continue
        _, length, kind = struct.unpack("<IHB", data[pos : pos + 7])
        pending += data[pos + 7 : pos + 7 + length]
        pos += 7 + length
        if kind in (1, 4):
            record = wandb_internal_pb2.Record()
            record.ParseFromString(pending)
            pending = b""
            yield record


def _wandb_run(root: Path, run_id: str) -> tuple[str, list[dict], set[str]]:
    """Group, history rows and saved files of the offline W&B runs with this id (a resume adds a folder)."""
    group, history, files = "", [], set()
    for folder in sorted((root / "wandb").glob(f"offline-run-*-{run_id}")):
        files |= {p.name for p in (folder / "files").iterdir()}
        for record in _wandb_records(folder / f"run-{run_id}.wandb"):
            kind = record.WhichOneof("record_type")
            if kind == "run":
                group = record.run.run_group
            elif kind == "history":
                history.append(
                    {item.key or "/".join(item.nested_key): json.loads(item.value_json) for item in record.history.item}
                )
    return group, history, files


@pytest.mark.slow
def test_wandb_offline_gets_every_column_by_step_and_one_group_per_experiment(tracked):
    root, _, runs = tracked
    groups = set()
    for run in runs:
        ids = json.loads((run / "trackers.json").read_text())
        group, history, files = _wandb_run(root, ids["wandb"]["run_id"])
        groups.add(group)
        assert {"summary.json", "config.toml"} <= files
        # Copies, not links: `run.save` linked the live files (a resume rewrites them), warning twice per seed.
        for saved in root.glob(f"wandb/offline-run-*-{ids['wandb']['run_id']}/files/*.*"):
            if saved.name in ("summary.json", "config.toml"):
                assert not saved.is_symlink() and saved.read_bytes() == (run / saved.name).read_bytes()
        rows = _rows(run)
        assert [h["_step"] for h in history] == [int(r["global_step"]) for r in rows]
        for logged, row in zip(history, rows):
            for column, value in row.items():
                if column != "global_step" and value not in ("", None) and not math.isnan(float(value)):
                    assert _same(logged[column], float(value)), column
    assert len(groups) == 1 and groups.pop().startswith("InvertedPendulum-v4-ppo-")


@pytest.mark.slow
def test_resume_continues_the_same_tracker_runs(tracked, monkeypatch):
    root, uri, runs = tracked
    _offline_wandb(monkeypatch, root)
    monkeypatch.chdir(root)
    run = runs[0]
    before = json.loads((run / "trackers.json").read_text())
    steps_before = int(_rows(run)[-1]["global_step"])
    # no --track: a resume continues the trackers recorded in the run folder
    assert main(["train", "--resume", str(run), "--total-steps", "4096", "--quiet"]) == 0
    assert json.loads((run / "trackers.json").read_text()) == before
    client, tracked_run = _mlflow_run(uri, run)
    steps = [m.step for m in client.get_metric_history(tracked_run.info.run_id, "sps")]
    assert steps == [int(r["global_step"]) for r in _rows(run)] and steps[-1] > steps_before
    assert tracked_run.info.status == "FINISHED"
    # A parameter cannot change in MLflow: the budget the resume gave is a tag of the same name.
    assert tracked_run.data.params["run.total_steps"] == "2048" and tracked_run.data.tags["run.total_steps"] == "4096"
    assert "run.seed" not in tracked_run.data.tags
    _, history, _ = _wandb_run(root, before["wandb"]["run_id"])
    assert [h["_step"] for h in history] == steps


@pytest.mark.slow
def test_a_killed_run_keeps_in_wandb_the_rows_logged_before_its_last_second(tmp_path):
    """By default W&B writes its run file every 15 s, and a SIGKILL loses the rows since, checkpointed ones too."""
    import signal
    import subprocess
    import sys

    from canter.training.trackers.wandb_tracker import WANDB_FLUSH_SECONDS

    env = dict(os.environ, WANDB_MODE="offline", WANDB_DIR=str(tmp_path), WANDB_SILENT="true")
    argv = [sys.executable, "-m", "canter.cli", "train", "InvertedPendulum-v4", "--out-dir", str(tmp_path / "runs")]
    # A budget it never reaches before the kill, and rows a second or so apart, too few to fill W&B's write buffer.
    slow = {"2048": "1e7", "ppo.n_steps=128": "ppo.n_steps=2048", "ppo.epochs=2": "ppo.epochs=10"}
    tiny = [slow.get(a, a) for a in TINY_PPO]
    trainer = subprocess.Popen([*argv, "--track", "wandb", *tiny], env=env, cwd=tmp_path)
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and trainer.poll() is None:
            metrics = list(tmp_path.glob("runs/*/metrics.csv"))
            if metrics and len(logged := _rows(metrics[0].parent)) >= 3:
                break
            time.sleep(0.2)
        assert trainer.poll() is None, "the run ended before three rows"
        time.sleep(WANDB_FLUSH_SECONDS + 1.5)
        trainer.send_signal(signal.SIGKILL)
        trainer.wait(timeout=60)
    finally:
        trainer.kill()
    run = metrics[0].parent
    _, history, _ = _wandb_run(tmp_path, json.loads((run / "trackers.json").read_text())["wandb"]["run_id"])
    steps = {h["_step"] for h in history}
    assert {int(row["global_step"]) for row in logged} <= steps, (len(logged), sorted(steps))


# ------------------------------------------------------------------------------------------------------ failures


def test_a_tracker_that_cannot_start_is_one_line_before_training(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    argv = ["train", "InvertedPendulum-v4", "--out-dir", str(tmp_path / "runs")] + TINY_PPO
    assert main(argv + ["--track", "mlflow", "--mlflow-uri", "nope://nowhere"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("canter: error: --mlflow-uri nope://nowhere cannot be opened") and "\n" not in err
    # A database it cannot open: MLflow would retry it for about 100 s, a warning each time.
    started = time.monotonic()
    assert main(argv + ["--track", "mlflow", "--mlflow-uri", "sqlite:////proc/no.db"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("canter: error: --mlflow-uri sqlite:////proc/no.db cannot be opened") and "\n" not in err
    assert time.monotonic() - started < 20
    # A bare path is MLflow's file store, which MLflow refuses with a paragraph whose first sentence only says that
    # the file store is in maintenance mode: the refusal itself is named.
    monkeypatch.delenv("MLFLOW_ALLOW_FILE_STORE", raising=False)
    assert main(argv + ["--track", "mlflow", "--mlflow-uri", "notauri"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        "canter: error: --mlflow-uri notauri cannot be opened (MLflow no longer writes to a plain folder, a file "
        "store, unless MLFLOW_ALLOW_FILE_STORE=true is set); pass e.g. --mlflow-uri sqlite:///mlflow.db"
    ), err
    # Online with no key anywhere (no WANDB_API_KEY, an empty netrc): refused before an env or folder is made.
    for name in ("WANDB_MODE", "WANDB_API_KEY", "WANDB_IDENTITY_TOKEN_FILE", "WANDB_BASE_URL"):
        monkeypatch.delenv(name, raising=False)
    (tmp_path / "netrc").write_text("")
    monkeypatch.setenv("NETRC", str(tmp_path / "netrc"))
    assert main(argv + ["--track", "wandb"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        "canter: error: --track wandb has no W&B API key here; run `wandb login` (or set WANDB_API_KEY), or set "
        "WANDB_MODE=offline to keep the runs local"
    )
    monkeypatch.setitem(__import__("sys").modules, "wandb", None)  # as if canter[wandb] were not installed
    assert main(argv + ["--track", "wandb"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "canter: error: --track wandb needs the W&B client; install canter[wandb]"
    assert not (tmp_path / "runs").exists()


@contextlib.contextmanager
def _registered(name: str, tracker: object):
    """The tracker under `name` inside the block, with `--track name` active, and gone after it."""
    register_tracker(name, tracker)
    try:
        with tracking(TrackSpec((name,))):
            yield
    finally:
        TRACKERS.pop(name)


class _InMemoryTracker:
    """A tracker backend that is its own single run: it accepts everything and keeps nothing."""

    run_id = "in-memory-1"

    def check(self, spec):
        pass

    def open_group(self, spec, group):
        return None

    def start(self, context, run_id):
        return self

    def log(self, values, step):
        pass


class _FailsOnSecondRow(_InMemoryTracker):
    """A real tracker backend whose store breaks after the first row."""

    def __init__(self) -> None:
        self.rows = 0

    def log(self, values, step):
        self.rows += 1
        if self.rows >= 2:
            raise ConnectionError("the tracking server went away\nsecond line")

    def finish(self, out, summary):
        raise AssertionError("a dropped tracker is not finished")

    def close(self):
        raise AssertionError("a dropped tracker is not closed")


@pytest.mark.slow
def test_a_tracker_failing_mid_run_warns_once_and_the_run_completes(tmp_path, capsys):
    flaky = _FailsOnSecondRow()
    config = build_config(
        "InvertedPendulum-v4",
        preset="fast",
        sets=["env.backend=envpool", "net.hidden=16,16", "run.tensorboard=false", "env.num_envs=4"]
        + ["ppo.n_steps=128", "ppo.epochs=2", f"run.out_dir={tmp_path}"],
        total_steps=2048,
    )
    with _registered("flaky", flaky):
        result = train(config)
    warnings = [line for line in capsys.readouterr().err.splitlines() if "tracker flaky" in line]
    assert warnings == [
        "canter: warning: tracker flaky failed while logging (the tracking server went away); training goes on "
        "without it, the run folder has everything"
    ]
    assert flaky.rows == 2
    assert result.stop_reason == "budget" and (result.run_dir / "summary.json").is_file()
    assert int(_rows(result.run_dir)[-1]["global_step"]) == result.global_step >= 2048


class _RecordsItsEnd(_InMemoryTracker):
    """A tracker that records how each of its runs started (the id it continues, or None) and ended."""

    def __init__(self) -> None:
        self.ends: list[str] = []
        self.continued: list[str | None] = []

    def start(self, context, run_id):
        self.continued.append(run_id)
        return self

    def finish(self, out, summary):
        self.ends.append("finished")

    def close(self):
        self.ends.append("closed")


@pytest.mark.slow
def test_a_run_that_fails_before_its_first_iteration_closes_its_tracker_runs(tmp_path, monkeypatch):
    import canter.training.device_memory as device_memory

    def too_big(compiled, envs, sizes):
        raise CanterError(f"env.num_envs={envs} does not fit in the device's memory; lower env.num_envs")

    monkeypatch.setattr(device_memory, "check_fits", too_big)
    recorded = _RecordsItsEnd()
    config = build_config(
        "InvertedPendulum-v4",
        preset="fast",
        sets=["net.hidden=8", "run.tensorboard=false", "env.num_envs=2", "ppo.minibatch_size=128"]
        + [f"run.out_dir={tmp_path}"],
        total_steps=1024,
    )
    with _registered("recorded", recorded), pytest.raises(CanterError, match="does not fit"):
        train(config)
    assert recorded.ends == ["closed"]


# ------------------------------------------------------------------------------------------------ tune and bench


def test_a_job_carries_its_trackers_and_an_older_job_file_still_loads():
    from canter.orchestrate.jobs import JobSpec

    tags, opened = (("canter.trial", "3"),), (("mlflow", "tune-S", "p1"),)
    track = TrackSpec(("mlflow", "wandb"), "sqlite:///m.db", "tune-S", "trial_00003", tags, opened)
    spec = JobSpec("[run]\n", {0: "/runs/s0", 1: "/runs/s1"}, 2, track)
    assert JobSpec.from_json(spec.to_json()) == spec
    older = json.loads(spec.to_json())
    del older["track"]
    assert JobSpec.from_json(json.dumps(older)) == JobSpec("[run]\n", {0: "/runs/s0", 1: "/runs/s1"}, 2)


def test_tune_and_bench_check_their_trackers_before_anything_trains(tmp_path, monkeypatch, capsys):
    from test_tune import tiny_args

    monkeypatch.chdir(tmp_path)
    tune = ["tune", "Pendulum-v1", "--trials", "1"] + tiny_args(tmp_path)
    bench = ["bench", "--envs", "InvertedPendulum-v4", "--seeds", "0", "--out", str(tmp_path / "bench")]
    for argv in (tune, bench):
        assert main(argv + ["--track", "mlflow", "--mlflow-uri", "nope://nowhere"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("canter: error: --mlflow-uri nope://nowhere cannot be opened") and "\n" not in err
        assert main(argv + ["--mlflow-uri", f"sqlite:///{tmp_path / 'm.db'}"]) == 2
        err = capsys.readouterr().err.strip()
        assert err == "canter: error: --mlflow-uri sets the store of --track mlflow; also pass --track mlflow"
    assert not (tmp_path / "tune").exists() and not (tmp_path / "bench").exists()


def test_mlflow_jobs_making_parents_at_once_keep_the_oldest_even_if_it_shows_up_late(tmp_path, monkeypatch):
    """Another job's parent, stamped before this job's own but visible only after it: after the settle, both jobs
    pick it, and this job deletes its own."""
    from mlflow.tracking import MlflowClient

    from canter.training.trackers import mlflow_tracker

    client = MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'mlflow.db'}")
    experiment = client.create_experiment("race")
    tags = {mlflow_tracker.PARENT_TAG: "true", mlflow_tracker.GROUP_TAG: "g"}
    other: list[str] = []

    def other_job_commits_late(seconds):
        assert seconds == mlflow_tracker.PARENT_SETTLE_S
        other.append(client.create_run(experiment, start_time=1, run_name="g", tags=tags).info.run_id)

    monkeypatch.setattr(mlflow_tracker.time, "sleep", other_job_commits_late)
    chosen = mlflow_tracker._parent_run_id(client, experiment, "g")
    assert chosen == other[0]
    alive = client.search_runs([experiment], "tags.`canter.parent` = 'true'")
    assert [run.info.run_id for run in alive] == other


def test_mlflow_parents_opened_before_the_jobs_are_the_ones_every_job_uses(tmp_path, monkeypatch):
    """A tune or bench process opens each group's parent once (`open_groups`); its jobs then start their runs under
    it and never make or look for one, so jobs that start together cannot split a group."""
    from mlflow.tracking import MlflowClient

    from canter.errors import CanterError
    from canter.training.trackers import mlflow_tracker, open_groups
    from canter.training.trackers.base import RunContext

    monkeypatch.chdir(tmp_path)  # MLflow's artifacts go to ./mlruns
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setattr(mlflow_tracker, "PARENT_SETTLE_S", 0.0)
    spec = open_groups(TrackSpec(("mlflow",), uri), ["g", "g", "h"])
    [(_, _, parent_g), (_, _, parent_h)] = spec.group_runs
    assert [group for _, group, _ in spec.group_runs] == ["g", "h"]
    assert open_groups(TrackSpec(("mlflow",), uri), ["g"]).group_run("mlflow", "g") == parent_g  # found, not made

    def no_parent_in_jobs(*args):
        raise AssertionError("a job made or looked for a parent run")

    monkeypatch.setattr(mlflow_tracker, "_parent_run_id", no_parent_in_jobs)
    tracker = mlflow_tracker.MlflowTracker()
    children = [tracker.start(RunContext({}, tmp_path / name, "g", name, spec), None) for name in ("a", "b")]
    client = MlflowClient(tracking_uri=uri)
    assert {client.get_run(c.run_id).data.tags["mlflow.parentRunId"] for c in children} == {parent_g}
    parents = client.search_runs([client.get_run(parent_g).info.experiment_id], "tags.`canter.parent` = 'true'")
    assert sorted(run.info.run_id for run in parents) == sorted([parent_g, parent_h])
    # A group the process did not open (a plain `canter train`) still finds or makes its own.
    with pytest.raises(CanterError, match="could not start an MLflow run: a job made or looked for a parent run"):
        tracker.start(RunContext({}, tmp_path / "c", "other", "c", spec), None)


def test_a_tracker_lacking_a_method_is_refused_when_registered_not_when_a_tune_first_calls_it():
    class NoGroups:
        def check(self, spec):
            pass

        def start(self, context, run_id):
            raise AssertionError("never started")

    with pytest.raises(CanterError, match=r"tracker 'partial' lacks open_group; a tracker implements every method"):
        register_tracker("partial", NoGroups())
    assert "partial" not in tracker_names()


def test_mlflow_groups_with_a_quote_are_found_again_and_requests_give_up_in_seconds(tmp_path, monkeypatch):
    from canter.training.trackers import mlflow_tracker, open_groups

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_HTTP_REQUEST_MAX_RETRIES", raising=False)
    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_TIMEOUT", "60")  # a user's own setting stays
    monkeypatch.setattr(mlflow_tracker, "PARENT_SETTLE_S", 0.0)
    monkeypatch.setattr(mlflow_tracker, "_CLIENTS", {})
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    group = "tune-bob's"  # canter tune --study "bob's"
    [(_, _, parent)] = open_groups(TrackSpec(("mlflow",), uri), [group]).group_runs
    assert open_groups(TrackSpec(("mlflow",), uri), [group]).group_run("mlflow", group) == parent  # found, not made
    assert os.environ["MLFLOW_HTTP_REQUEST_MAX_RETRIES"] == "2" and os.environ["MLFLOW_HTTP_REQUEST_TIMEOUT"] == "60"


def test_a_trackers_file_whose_entries_are_not_objects_is_one_line_on_resume(tmp_path):
    from canter.training.trackers.session import read_ids

    (tmp_path / "trackers.json").write_text('{"mlflow": "x"}')
    with pytest.raises(CanterError, match=r"trackers.json is not the JSON canter writes; delete it to resume"):
        read_ids(tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("store", [[], ["--mlflow-uri", "sqlite:///mlflow.db"]], ids=["default", "relative"])
def test_a_resume_from_another_folder_continues_the_mlflow_run_of_its_default_store(
    tmp_path, monkeypatch, capsys, store
):
    """MLflow's default store, like a relative --mlflow-uri, is a file under the working folder; trackers.json records
    it absolute, so a resume started elsewhere finds the run rather than failing on a store that does not hold it."""
    started, elsewhere = tmp_path / "started", tmp_path / "elsewhere"
    started.mkdir()
    elsewhere.mkdir()
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    monkeypatch.chdir(started)
    assert (
        main(
            ["train", "InvertedPendulum-v4", "--out-dir", str(tmp_path / "runs"), "--track", "mlflow"]
            + TINY_PPO
            + store
        )
        == 0
    )
    [run] = list((tmp_path / "runs").iterdir())
    ids = json.loads((run / "trackers.json").read_text())
    assert ids["mlflow"]["uri"] == f"sqlite:///{started / 'mlflow.db'}"
    monkeypatch.chdir(elsewhere)
    assert main(["train", "--resume", str(run), "--total-steps", "4096", "--quiet"]) == 0
    assert json.loads((run / "trackers.json").read_text())["mlflow"]["run_id"] == ids["mlflow"]["run_id"]
    assert not (elsewhere / "mlflow.db").exists()
    # A recorded run the store no longer holds: one line, and the way to go on without it.
    ids["mlflow"]["run_id"] = "0" * 32
    (run / "trackers.json").write_text(json.dumps(ids))
    assert main(["train", "--resume", str(run), "--total-steps", "8192", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.endswith(f"; to resume without it, delete {run / 'trackers.json'}"), err


@pytest.mark.slow
def test_a_resume_from_a_checkpoint_at_step_0_continues_its_tracker_runs(tmp_path):
    """A run whose first iteration was non-finite keeps a checkpoint at step 0; resuming it is still a resume."""
    recorded = _RecordsItsEnd()
    config = build_config(
        "canter_test_envs:NaNAtOnce-v0",
        sets=["net.hidden=8", "run.tensorboard=false", "env.num_envs=1", "ppo.n_steps=64", "ppo.minibatch_size=32"]
        + [f"run.out_dir={tmp_path}"],
        total_steps=1024,
    )
    with _registered("recorded", recorded):
        with pytest.raises(CanterError, match="non-finite"):
            train(config)
        [run] = list(tmp_path.iterdir())
        with pytest.raises(CanterError, match="non-finite"):
            train(resume_config(run, 1024), resume=run)
    assert recorded.continued == [None, "in-memory-1"]


@pytest.mark.slow
def test_a_tracked_run_refused_after_its_compile_leaves_no_folder(tmp_path, monkeypatch, capsys):
    """The tracker run has started by the compile, and trackers.json records it: a refusal there removes that too,
    so that the folder the lock made goes with it."""
    from canter.training import device_memory

    monkeypatch.chdir(tmp_path)  # MLflow's artifacts go to ./mlruns
    monkeypatch.setattr(device_memory, "free_bytes", lambda: None)
    monkeypatch.setattr(device_memory, "required_bytes", lambda compiled: 2**50)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    argv = ["train", "InvertedPendulum-v4", "--out-dir", str(tmp_path / "runs"), "--track", "mlflow"]
    assert main([*argv, "--mlflow-uri", uri, *TINY_PPO]) == 2
    assert "of memory beyond its train state and envs" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()
