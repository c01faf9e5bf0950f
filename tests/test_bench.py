"""canter bench: grid cells and their names, bad input, published scores, a 2x1x2 tiny grid with its table, and
resume after an interruption."""

import csv
import json
import math
import shutil
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from canter.cli.main import main
from canter.orchestrate.bench_grid import BenchSettings, make_cells, make_jobs, varying_keys
from canter.orchestrate.bench_results import published_for
from conftest import ARCHIVED_RUN

TINY = [
    "--set",
    "net.hidden=16,16",
    "--set",
    "run.tensorboard=false",
    "--set",
    "env.num_envs=4",
    "--set",
    "ppo.n_steps=128",
    "--set",
    "ppo.minibatch_size=256",
    "--set",
    "ppo.epochs=2",
    "--set",
    "run.checkpoint_every=512",
]


def test_published_scores_are_shipped_with_their_sources():
    assert published_for("ppo", "Hopper-v5", 1_000_000) == "CR 2383±272, TS 2609±701, Zoo 2410±10"
    assert published_for("ppo", "Hopper-v5", 3_000_000) == "TS 3128"
    assert published_for("td3", "HalfCheetah-v5", 50_000) == "CR 9583, TS 10201 @1M"
    assert published_for("ppo", "Pendulum-v1", 1_000_000) == ""
    # The package holds its own copy: nothing outside it is read.
    from importlib import resources

    text = resources.files("canter.data").joinpath("published.toml").read_text()
    assert "vwxyzjn/cleanrl" in text and "thu-ml/tianshou" in text and "rl-baselines3-zoo" in text
    for module in Path(__file__).parent.parent.joinpath("src/canter/orchestrate").glob("bench*.py"):
        assert "/work/shared" not in module.read_text(), module


def test_cells_have_deterministic_names_and_are_labelled_by_what_differs():
    settings = BenchSettings(
        algos=("ppo",),
        envs=("Hopper-v5", "Walker2d-v5"),
        seeds=(0, 1),
        total_steps=1000,
        grid=(("ppo.ent_coef", ("0.01", "1e-4", "0")), ("net.hidden", ("64-64",)), ("ppo.clip", ("0.2",))),
    )
    cells = make_cells(settings)
    assert len(cells) == 2 * 3
    names = [c.name for c in cells]
    assert names[0] == "Hopper-v5__ppo__ppo.ent_coef=0.01__net.hidden=64-64__ppo.clip=0.2"
    assert names[1] == "Hopper-v5__ppo__ppo.ent_coef=0.0001__net.hidden=64-64__ppo.clip=0.2"
    assert names == [c.name for c in make_cells(settings)] and len(set(names)) == len(names)
    assert cells[1].config.ppo.ent_coef == 1e-4 and cells[1].config.net.hidden == (64, 64)
    assert cells[3].config.env.id == "Walker2d-v5"
    assert varying_keys(cells) == ["ppo.ent_coef"]
    assert cells[0].run_dir(Path("b"), 1) == Path("b") / (names[0] + "__s1")
    # run.algo as a grid axis is the algorithm axis (seed 000's ablation: PPO vs RPO, entropy coef).
    algo_cells = make_cells(
        BenchSettings(
            algos=(),
            envs=("Hopper-v5",),
            seeds=(0,),
            total_steps=1000,
            grid=(("run.algo", ("ppo", "rpo")), ("ppo.ent_coef", ("0", "0.01"))),
        )
    )
    assert [(c.algo, c.config.run.algo, c.config.ppo.ent_coef) for c in algo_cells] == [
        ("ppo", "ppo", 0.0),
        ("ppo", "ppo", 0.01),
        ("rpo", "rpo", 0.0),
        ("rpo", "rpo", 0.01),
    ]
    assert algo_cells[3].name == "Hopper-v5__rpo__ppo.ent_coef=0.01"


def test_an_axis_that_changes_only_the_outputs_is_noted_as_a_speed_axis(capsys):
    grid = (("ppo.ent_coef", ("0", "0.01")), ("run.tensorboard", ("true", "false")), ("env.envpool_shards", ("0", "1")))
    cells = make_cells(BenchSettings(("ppo",), ("Hopper-v5",), (0,), 1000, grid=grid))
    assert len(cells) == 8
    notes = capsys.readouterr().err.splitlines()
    assert [line.split()[3] for line in notes] == ["run.tensorboard", "env.envpool_shards"]
    assert notes[0] == (
        "canter: note: --grid run.tensorboard changes how the work is done or written, not what is learned: its cells "
        "learn the same numbers, so compare their speed, not their scores"
    )


def test_off_policy_seeds_are_separate_jobs_and_on_policy_seeds_one_group():
    cells = make_cells(BenchSettings(algos=("ppo", "td3", "sac"), envs=("Hopper-v5",), seeds=(0, 1), total_steps=1000))
    jobs = make_jobs(cells, (0, 1))
    assert [(j.name, j.seeds) for j in jobs] == [
        ("Hopper-v5__ppo", (0, 1)),
        ("Hopper-v5__td3__s0", (0,)),
        ("Hopper-v5__td3__s1", (1,)),
        ("Hopper-v5__sac__s0", (0,)),
        ("Hopper-v5__sac__s1", (1,)),
    ]
    assert jobs[1].cell is jobs[2].cell is cells[1]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--algos", "ppo,nope"], "unknown algorithm 'nope'"),
        (["--envs", "Hopper-v5,Hoper-v5"], "unknown env id 'Hoper-v5'"),
        (["--grid", "ppo.entcoef=0,1"], "unknown config key 'ppo.entcoef'"),
        (["--grid", "ppo.epochs=1,x"], "ppo.epochs: expected an integer"),
        (["--grid", "ppo.gamma=0.99,2"], "ppo.gamma must be in (0, 1]"),
        (["--grid", "run.seed=1,2"], "use --seeds"),
        (
            ["--grid", "run.preset=fast,cleanrl"],
            "--grid run.preset is not a grid axis (a preset sets many keys); run one bench per --preset",
        ),
        (["--grid", "ppo.clip"], "--grid expects KEY=V1,V2"),
        (["--grid", "ppo.clip=0.2,0.20"], "canter: error: --grid ppo.clip repeats 0.2; give each value once"),
        # A tuple typed with commas is split into one value per entry: the line says so, and how tuples are written.
        (
            ["--grid", "net.hidden=16-16,16,16"],
            "canter: error: --grid net.hidden repeats 16: 16-16,16,16 is 3 values, as values are separated by commas "
            "and a tuple's entries by '-'; write tuples as --grid net.hidden=16-16,32-32",
        ),
        (["--seeds", "0,x"], "expected whole numbers separated by commas"),
        (["--seeds", "1,2,1"], "each seed may appear once"),
        (["--seeds", "0,-1"], "expected seeds from 0 to 4294967295"),
        (["--envs", "Hopper-v5,Hopper-v5"], "each name may appear once"),
        (["--algos", "ppo,td3,ppo"], "each name may appear once"),
        # The grid's own algo and env axes refuse repeats as --algos and --envs do: the cells would share run folders.
        (["--grid", "run.algo=ppo,ppo"], "canter: error: --grid run.algo repeats ppo; give each value once"),
        (["--grid", "env.id=Hopper-v5,Hopper-v5"], "--grid env.id repeats Hopper-v5; give each value once"),
        # A run folder's name keeps only the env id's tail, so these two would train the same folders.
        (
            ["--envs", "Hopper-v5,gymnasium:Hopper-v5"],
            "canter: error: cells (Hopper-v5, ppo) and (gymnasium:Hopper-v5, ppo) would share the run folders "
            "Hopper-v5__ppo__s*; bench them in two benches with their own --out",
        ),
        (["--heartbeat", "0", "--storage", "sqlite:///x.db"], "--heartbeat (heartbeat_seconds) must be >= 1, got 0"),
        (["--storage", "postgresql://u@host:abc/db"], "is not a database URL; use sqlite:///path/study.db"),
        (["--storage", "foo://host/db"], "foo"),  # parses, but no such driver: refused when opened
        # Without a storage there is no study to name nor trial to heartbeat: refused rather than ignored.
        (["--study", "x"], "--study goes with --storage only"),
        (["--heartbeat", "5"], "--heartbeat goes with --storage only"),
        (["--study", "x", "--heartbeat", "5"], "--study and --heartbeat go with --storage only"),
        (["--storage", "", "--study", "x"], "add --storage URL to share the grid, or leave out --study"),
    ],
)
def test_bad_grid_is_refused_before_any_cell_runs(tmp_path, capsys, argv, message):
    base = ["bench", "--seeds", "0", "--total-steps", "1000", "--out", str(tmp_path / "b")]
    if "--envs" not in argv and not any(arg.startswith("env.id=") for arg in argv):
        base += ["--envs", "Hopper-v5"]
    code = main(base + argv)
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "b").exists()


def test_jobs_over_cores_warns_once_the_command_is_valid(tmp_path, capsys, monkeypatch):
    import canter.orchestrate.jobs

    monkeypatch.setattr(canter.orchestrate.jobs.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    canter.orchestrate.job_resources.warn_if_more_jobs_than_cores(3, 3)
    assert capsys.readouterr().err == (
        "canter: warning: --jobs 3 is more than the 2 CPU cores; the jobs will slow each other down\n"
    )
    canter.orchestrate.job_resources.warn_if_more_jobs_than_cores(3, 2)
    assert capsys.readouterr().err == ""
    # A refused command prints its one-line error and nothing else, whatever --jobs says.
    code = main(["bench", "--envs", "Hopper-v5", "--algos", "nope", "--jobs", "999", "--out", str(tmp_path / "b")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "unknown algorithm 'nope'" in err, err


def test_worker_count_never_passes_the_work_left():
    from canter.orchestrate.job_resources import worker_count

    assert [worker_count(1000, 1), worker_count(4, 10), worker_count(4, 4), worker_count(3, 2)] == [1, 4, 4, 2]
    # One even with nothing left: it finds that out, or waits for what runs elsewhere, and the results are written.
    assert worker_count(8, 0) == worker_count(8, -2) == 1


def test_jobs_far_over_the_cores_are_refused_before_anything_starts(tmp_path, capsys, monkeypatch):
    import canter.orchestrate.jobs
    from canter.errors import CanterError

    monkeypatch.setattr(canter.orchestrate.jobs.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)

    def no_process(*args, **kwargs):
        raise AssertionError("a refused command started a process")

    monkeypatch.setattr(canter.orchestrate.jobs, "run_workers", no_process)
    monkeypatch.setattr(canter.orchestrate.jobs, "start_job", no_process)
    canter.orchestrate.job_resources.check_jobs(8)  # 4 per core: slow, but a choice; the warning says so
    with pytest.raises(CanterError) as refused:
        canter.orchestrate.job_resources.check_jobs(9)
    assert str(refused.value) == (
        "--jobs 9 is more than 4 per CPU core, and this machine lets canter use 2; pass --jobs 2 (one per core), or "
        "at most --jobs 8"
    )
    out = tmp_path / "b"
    for through_storage in (False, True):
        storage = ["--storage", f"sqlite:///{tmp_path / 'grid.db'}"] if through_storage else []
        code = main(["bench", "--envs", "Hopper-v5", "--seeds", "0", "--jobs", "1000", "--out", str(out), *storage])
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1 and "--jobs 1000 is more than 4 per CPU core" in err, err
        assert "pass --jobs 2" in err and "Traceback" not in err and not out.exists()
    assert not (tmp_path / "grid.db").exists()
    # The command of the report: one trial, a thousand jobs.
    tune_dir = tmp_path / "t"
    code = main(
        ["tune", "Pendulum-v1", "--trials", "1", "--jobs", "1000", "--total-steps", "1024"]
        + ["--out-dir", str(tune_dir)]
    )
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "--jobs 1000 is more than 4 per CPU core" in err, err
    assert not tune_dir.exists()


def test_a_local_bench_makes_no_more_slots_than_jobs_left(tmp_path, capsys, monkeypatch):
    import canter.orchestrate.bench_local
    from canter.orchestrate.bench_local import run_local

    settings = BenchSettings(("ppo",), ("Hopper-v5",), (0,), 1000, grid=(("ppo.ent_coef", ("0", "0.01")),), jobs=6)
    layouts = []

    class Stop(Exception):
        pass

    def layout(jobs):
        layouts.append(jobs)
        raise Stop  # before any job starts

    monkeypatch.setattr(canter.orchestrate.bench_local, "job_layout", layout)
    with pytest.raises(Stop):
        run_local(make_cells(settings), settings, tmp_path)
    # Each slot's share of the cores and of a GPU's memory is cut for the 2 jobs there are, not for 6.
    assert layouts == [2]


def test_a_shared_bench_starts_no_more_workers_than_unfinished_jobs(tmp_path, capsys, monkeypatch):
    import canter.orchestrate.bench_distributed as distributed

    url = f"sqlite:///{tmp_path / 'grid.db'}"
    settings = BenchSettings(
        ("ppo",), ("Hopper-v5",), (0,), 1000, grid=(("ppo.ent_coef", ("0", "0.01", "0.02")),), jobs=6, storage_url=url
    )
    cells = make_cells(settings)
    started = []
    monkeypatch.setattr(distributed, "run_workers", lambda work, args, name: started.append(len(args)) or [])
    monkeypatch.setattr(distributed, "_grid_worker", lambda *args: started.append(1))
    storage, study = distributed.open_grid_study(settings, tmp_path)
    distributed.run_distributed(cells, settings, tmp_path, storage, study)
    assert started == [3]  # the grid's 3 jobs, not --jobs 6
    for _ in range(2):  # two jobs finished (by a worker elsewhere): one is left
        study.tell(study.ask(), 1.0)
    distributed.run_distributed(cells, settings, tmp_path, storage, study)
    assert started == [3, 1]


def read_rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_grid_table_and_resume_after_an_interruption(tmp_path, capsys, monkeypatch):
    from mlflow.tracking import MlflowClient

    import canter.use.statistics
    from canter.use.evaluate import evaluate
    from canter.use.policy import load

    monkeypatch.chdir(tmp_path)  # MLflow's artifacts go to ./mlruns
    monkeypatch.setattr(canter.use.statistics, "REPS", 100)  # the table's and plot's statistics: the plumbing
    mlflow_uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    out = tmp_path / "bench"
    argv = [
        "bench",
        "--envs",
        "InvertedPendulum-v4",
        "--seeds",
        "0,1",
        "--total-steps",
        "1024",
        "--grid",
        "ppo.ent_coef=0,0.01",
        "--episodes",
        "2",
        "--jobs",
        "2",
        "--out",
        str(out),
        "--track",
        "mlflow",
        "--mlflow-uri",
        mlflow_uri,
    ] + TINY
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 0, captured.err
    # --track: an MLflow run per seed, named as its folder; a cell's seeds are the children of one parent run.
    client = MlflowClient(tracking_uri=mlflow_uri)

    def tracked(run_dir: Path):
        return client.get_run(json.loads((run_dir / "trackers.json").read_text())["mlflow"]["run_id"])

    parents = {}
    for run_dir in out.glob("*__s*"):
        assert tracked(run_dir).info.run_name == run_dir.name and tracked(run_dir).info.status == "FINISHED"
        parents.setdefault(run_dir.name.rsplit("__", 1)[0], set()).add(tracked(run_dir).data.tags["mlflow.parentRunId"])
    assert len(parents) == 2 and all(len(p) == 1 for p in parents.values())
    # The bench process made each cell's parent before its jobs started, under the group each seed's run records.
    for job_file in (out / ".cells").glob("*/job.json"):
        track = json.loads(job_file.read_text())["track"]
        for run_dir in json.loads(job_file.read_text())["run_dirs"].values():
            group = json.loads((Path(run_dir) / "trackers.json").read_text())["mlflow"]["group"]
            assert [["mlflow", group, tracked(Path(run_dir)).data.tags["mlflow.parentRunId"]]] == [
                run for run in track["group_runs"] if run[1] == group
            ]
    assert len(set.union(*parents.values())) == 2
    rows = read_rows(out / "results.csv")
    assert [r["ppo.ent_coef"] for r in rows] == ["0.0", "0.01"]
    for row in rows:
        runs = [out / f"InvertedPendulum-v4__ppo__ppo.ent_coef={row['ppo.ent_coef']}__s{s}" for s in (0, 1)]
        means = [json.loads((r / "eval.json").read_text())["mean"] for r in runs]
        assert float(row["return_mean"]) == pytest.approx(np.mean(means), abs=1e-3)
        assert float(row["return_std"]) == pytest.approx(np.std(means), abs=1e-3)
        assert float(row["return_median"]) == pytest.approx(np.median(means), abs=1e-3)
        assert row["seeds"] == "2" and float(row["sps"]) > 0
        assert row["published"] == "CR 963±22, TS 1000±0 @1M"
    # eval.json is the deterministic evaluation of the final policy.
    run = out / "InvertedPendulum-v4__ppo__ppo.ent_coef=0.01__s1"
    again = evaluate(load(run), episodes=2, deterministic=True, seed=0)
    assert json.loads((run / "eval.json").read_text())["returns"] == pytest.approx(list(again.returns))
    assert json.loads((run / "eval.json").read_text())["lengths"] == [int(n) for n in again.lengths]
    assert {k: json.loads((run / "eval.json").read_text())[k] for k in ("backend", "physics")} == {
        "backend": again.backend,
        "physics": {},
    }
    for folder in out.glob("*__s*"):  # every eval.json the bench writes holds each episode's return and length
        evaluation = json.loads((folder / "eval.json").read_text())
        assert len(evaluation["returns"]) == len(evaluation["lengths"]) == 2
    assert (out / "plot_InvertedPendulum-v4.png").stat().st_size > 0
    assert "| InvertedPendulum-v4 | ppo | 0.01 |" in (out / "results.md").read_text()
    # Below the table, the statistics of the seeds' evaluations, and all of them in statistics.json.
    assert "| InvertedPendulum-v4 | ppo, ent_coef=0.01 | 2 | " in (out / "results.md").read_text()
    statistics = json.loads((out / "statistics.json").read_text())
    assert [c["method"] for c in statistics["cells"]] == ["ppo, ent_coef=0.0", "ppo, ent_coef=0.01"]
    assert statistics["cells"][1]["scores"] == pytest.approx(means)
    assert statistics["probability_of_improvement"][0]["x"] == "ppo, ent_coef=0.0"

    # Interrupt one run after its first checkpoint: no final checkpoint, summary or evaluation.
    cut = out / "InvertedPendulum-v4__ppo__ppo.ent_coef=0.0__s1"
    checkpoints = sorted((cut / "checkpoints").glob("ckpt_*.npz"))
    first, final = [int(p.stem[5:]) for p in checkpoints]  # steps count real env steps, not autoreset steps
    assert 512 <= first < 1024 <= final
    for path in (checkpoints[-1], cut / "summary.json", cut / "eval.json"):
        path.unlink()
    untouched = {p: p.stat().st_mtime_ns for p in out.glob("*__s*/summary.json")}
    rows_before = len(read_rows(cut / "metrics.csv"))
    tracked_before, resumed_ms = tracked(cut).info.run_id, time.time() * 1000
    # Re-run without --track: the resumed seed still continues the MLflow run its trackers.json records.
    untracked = [a for a in argv if a not in ("--track", "mlflow", "--mlflow-uri", mlflow_uri)]
    code = main(untracked)
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "skip InvertedPendulum-v4__ppo__ppo.ent_coef=0.01" in captured.out
    # Seed 0 finished: it is done, not resumed; seed 1 goes on from its first checkpoint.
    assert "resume InvertedPendulum-v4__ppo__ppo.ent_coef=0.0 (seeds 0,1): seed 0 done at step " in captured.out
    assert f", seed 1 from step {first:,}\n" in captured.out
    assert all(p.stat().st_mtime_ns == t for p, t in untouched.items())  # finished runs were not retrained
    summary = json.loads((cut / "summary.json").read_text())
    assert summary["global_step"] >= 1024
    # Continued from the first checkpoint: the rows after it were lost work, so they were dropped and redone.
    steps = [int(r["global_step"]) for r in read_rows(cut / "metrics.csv")]
    assert first in steps and steps == sorted(set(steps)) and steps[-1] >= 1024 and len(steps) == rows_before
    # The resumed seed continued its MLflow run. It keeps the rows of the lost work too (a tracker cannot take rows
    # back), and the redone rows may fall on other steps.
    assert tracked(cut).info.run_id == tracked_before and tracked(cut).info.status == "FINISHED"
    history = client.get_metric_history(tracked_before, "sps")
    assert set(steps) <= {m.step for m in history}
    assert {m.step for m in history if m.timestamp >= resumed_ms} == {s for s in steps if s > first}
    assert len(read_rows(out / "results.csv")) == 2

    # The same folder with other settings: its runs would pass for results of those settings, so it is refused.
    untouched = {p: p.stat().st_mtime_ns for p in out.glob("*__s*/summary.json")}
    code = main(argv + ["--set", "ppo.lr=1e-4"])
    captured = capsys.readouterr()
    assert code != 0 and "Traceback" not in captured.err
    assert "was trained with ppo.lr=0.0003, but this bench gives ppo.lr=0.0001" in captured.err
    assert "use a new --out" in captured.err and len(captured.err.strip().splitlines()) == 1
    assert all(p.stat().st_mtime_ns == t for p, t in untouched.items())


def _stored_jobs(url: str, study: str) -> list[tuple[str, str]]:
    import optuna

    from canter.orchestrate.bench_distributed import trial_job

    # The experiment's digest ends every key; the tests read the rest.
    trials = optuna.load_study(study_name=study, storage=url).trials
    return sorted((t.state.name, trial_job(t).rpartition("|experiment=")[0]) for t in trials)


@pytest.mark.slow
def test_grid_through_an_optuna_storage(tmp_path, capsys):
    """With --storage every job is one queued trial; a re-run queues only what it adds: a cell, or a seed."""
    import optuna

    from canter.orchestrate.bench_distributed import trial_job

    url = f"sqlite:///{tmp_path / 'grid.db'}"

    def argv(clips: str, seeds: str = "0") -> list[str]:
        return [
            "bench",
            "--envs",
            "InvertedPendulum-v4",
            "--seeds",
            seeds,
            "--total-steps",
            "512",
            "--grid",
            f"ppo.clip={clips}",
            "--episodes",
            "1",
            "--storage",
            url,
            "--study",
            "grid",
            "--heartbeat",
            "2",
            "--out",
            str(tmp_path / "bench"),
        ] + TINY

    cell = "InvertedPendulum-v4__ppo__ppo.clip={}"
    key = cell + "|seeds={}|steps=512|episodes=1"
    assert main(argv("0.1")) == 0, capsys.readouterr().err  # a grid of one job (Optuna's GridSampler failed it)
    assert main(argv("0.1,0.2")) == 0, capsys.readouterr().err  # a changed grid: only the new cell trains
    assert _stored_jobs(url, "grid") == [("COMPLETE", key.format("0.1", "0")), ("COMPLETE", key.format("0.2", "0"))]
    for t in optuna.load_study(study_name="grid", storage=url).trials:
        [record] = t.user_attrs["records"]
        folder = tmp_path / "bench" / f"{trial_job(t).partition('|')[0]}__s0"
        evaluation = json.loads((folder / "eval.json").read_text())
        assert t.value == pytest.approx(evaluation["mean"]) == pytest.approx(record["eval_mean"])
        assert record["seed"] == 0 and record["sps"] > 0
    assert main(argv("0.1,0.2")) == 0
    assert len(_stored_jobs(url, "grid")) == 2  # nothing ran twice
    assert len(read_rows(tmp_path / "bench" / "results.csv")) == 2
    # Another bench in the same study, whose --set makes its cell another experiment under the same name, trains
    # its own job rather than report the first bench's records as its own.
    other = [a if a != str(tmp_path / "bench") else str(tmp_path / "other") for a in argv("0.1")]
    assert main([*other, "--set", "ppo.gamma=0.9"]) == 0, capsys.readouterr().err
    assert _stored_jobs(url, "grid").count(("COMPLETE", key.format("0.1", "0"))) == 2
    assert (tmp_path / "other" / f"{cell.format('0.1')}__s0" / "eval.json").is_file()

    # Another seed: each cell's job is queued again with both seeds; seed 0's finished run is kept, seed 1 trains.
    seed0 = (tmp_path / "bench" / f"{cell.format('0.1')}__s0" / "summary.json").stat().st_mtime_ns
    assert main(argv("0.1,0.2", "0,1")) == 0, capsys.readouterr().err
    assert [k for state, k in _stored_jobs(url, "grid") if "seeds=0,1" in k] == [
        key.format("0.1", "0,1"),
        key.format("0.2", "0,1"),
    ]
    assert (tmp_path / "bench" / f"{cell.format('0.1')}__s0" / "summary.json").stat().st_mtime_ns == seed0
    assert {row["seeds"] for row in read_rows(tmp_path / "bench" / "results.csv")} == {"2"}


@pytest.mark.slow
@pytest.mark.parametrize("through_storage", [False, True])
def test_a_cell_stopped_before_its_budget_is_not_reported_done(tmp_path, capsys, through_storage):
    out = tmp_path / "bench"
    url = f"sqlite:///{tmp_path / 'grid.db'}"
    storage = ["--storage", url, "--study", "cut", "--heartbeat", "2"] if through_storage else []
    argv = [
        "bench",
        "--envs",
        "InvertedPendulum-v4",
        "--seeds",
        "0",
        "--total-steps",
        "4096",
        "--episodes",
        "1",
        "--out",
        str(out),
        "--set",
        "run.max_minutes=0.0001",
    ] + TINY
    code = main(argv + storage)
    captured = capsys.readouterr()
    assert code != 0 and "Traceback" not in captured.err
    assert "cells failed (stopped before its budget" in captured.err and "re-run the same command" in captured.err
    if through_storage:  # the trial failed, so a re-run queues the job again
        assert _stored_jobs(url, "cut") == [("FAIL", "InvertedPendulum-v4__ppo|seeds=0|steps=4096|episodes=1")]
    else:
        assert "STOP  InvertedPendulum-v4__ppo: stopped before its budget" in captured.out
        assert "done  InvertedPendulum-v4__ppo" not in captured.out
    assert not (out / "results.csv").exists()
    summary = json.loads((out / "InvertedPendulum-v4__ppo__s0" / "summary.json").read_text())
    assert summary["stop_reason"] == "max_minutes" and summary["global_step"] < 4096


TINY_TD3 = [
    "--set",
    "td3.hidden=16,16",
    "--set",
    "run.tensorboard=false",
    "--set",
    "td3.learning_starts=100",
    "--set",
    "td3.buffer_size=1000",
    "--set",
    "td3.batch_size=32",
    "--set",
    "td3.steps_per_call=100",
    "--set",
    "run.checkpoint_every=200",
]


@pytest.mark.slow
def test_off_policy_seeds_run_as_jobs_through_a_storage_and_the_table_merges_them(tmp_path, capsys):
    """Each td3 seed is its own trial; the cell's row combines both seeds' records, locally as from the storage."""
    import optuna

    from canter.orchestrate.bench_distributed import trial_job

    out = tmp_path / "bench"
    url = f"sqlite:///{tmp_path / 'grid.db'}"
    argv = [
        "bench",
        "--algos",
        "td3",
        "--envs",
        "Pendulum-v1",
        "--seeds",
        "0,1",
        "--total-steps",
        "400",
        "--episodes",
        "1",
        "--out",
        str(out),
    ] + TINY_TD3
    assert main(argv + ["--storage", url, "--study", "td3", "--heartbeat", "2"]) == 0, capsys.readouterr().err
    study = optuna.load_study(study_name="td3", storage=url)
    done = sorted(
        (trial_job(t).rpartition("|experiment=")[0], [r["seed"] for r in t.user_attrs["records"]])
        for t in study.trials
        if t.state == optuna.trial.TrialState.COMPLETE
    )
    assert done == [
        ("Pendulum-v1__td3__s0|seeds=0|steps=400|episodes=1", [0]),
        ("Pendulum-v1__td3__s1|seeds=1|steps=400|episodes=1", [1]),
    ]
    [stored] = read_rows(out / "results.csv")
    means = [json.loads((out / f"Pendulum-v1__td3__s{s}" / "eval.json").read_text())["mean"] for s in (0, 1)]
    assert stored["seeds"] == "2" and float(stored["return_mean"]) == pytest.approx(np.mean(means), abs=1e-3)
    capsys.readouterr()

    assert main(argv) == 0  # locally: both seeds' jobs are found finished, and the row is the same
    printed = capsys.readouterr().out
    assert "skip Pendulum-v1__td3__s0 (finished)" in printed and "skip Pendulum-v1__td3__s1 (finished)" in printed
    [local] = read_rows(out / "results.csv")
    assert local["return_mean"] == stored["return_mean"] and local["seeds"] == "2"


def test_a_resumed_runs_record_counts_every_session(tmp_path):
    from canter.orchestrate.bench_results import seed_record

    # The summary of the last session, as runs resumed before totals were carried over wrote it.
    (tmp_path / "summary.json").write_text(json.dumps({"global_step": 300, "wall_seconds": 5.0, "sps": 40.0}))
    (tmp_path / "eval.json").write_text(json.dumps({"mean": 7.0}))
    (tmp_path / "metrics.csv").write_text(
        "global_step,iteration,wall_time,sps,episodes\n100,1,10.0,10.0,1\n200,2,20.0,10.0,1\n300,3,5.0,40.0,1\n"
    )
    record = seed_record(tmp_path, 0)
    assert record == {
        "seed": 0,
        "eval_mean": 7.0,
        "wall_seconds": pytest.approx(25.0),
        "sps": pytest.approx(300 / (10 + 10 + 2.5)),
        "trained_with": None,  # a summary written before canter kept it
    }


def test_a_set_reaches_the_cells_whose_algorithm_reads_it():
    from canter.errors import CanterError

    cells = make_cells(
        BenchSettings(
            algos=("ppo", "td3", "sac"),
            envs=("Hopper-v5",),
            seeds=(0,),
            total_steps=1000,
            sets=("td3.tau=0.01", "sac.tau=0.02", "net.hidden=32,32"),
        )
    )
    by_algo = {c.algo: c.config for c in cells}
    assert by_algo["td3"].td3.tau == 0.01 and by_algo["sac"].sac.tau == 0.02
    assert by_algo["ppo"].net.hidden == (32, 32) and by_algo["td3"].td3.hidden == (256, 256)
    with pytest.raises(CanterError, match=r"^--set net.hidden has no effect on td3, .*set td3.hidden instead$"):
        make_cells(
            BenchSettings(
                algos=("td3", "sac"), envs=("Hopper-v5",), seeds=(0,), total_steps=1000, sets=("net.hidden=32,32",)
            )
        )
    # A grid over a key one algorithm ignores would give that algorithm identical cells.
    with pytest.raises(CanterError, match=r"^--grid td3.tau: td3.tau has no effect on sac, .*of its own$"):
        make_cells(
            BenchSettings(
                algos=("td3", "sac"),
                envs=("Hopper-v5",),
                seeds=(0,),
                total_steps=1000,
                grid=(("td3.tau", ("0.01", "0.02")),),
            )
        )


def test_a_cells_wall_time_and_sps_depend_on_how_its_seeds_trained():
    from canter.orchestrate.bench_results import SeedRecord, combine_seeds, results_table

    records = [SeedRecord(0, 10.0, 600.0, 100.0, None), SeedRecord(1, 20.0, 1200.0, 300.0, None)]
    settings = BenchSettings(algos=("ppo", "td3"), envs=("Hopper-v5",), seeds=(0, 1), total_steps=1000)
    ppo, td3 = sorted(make_cells(settings), key=lambda c: c.algo)
    # A vmapped group: one process, so the slowest seed's wall time and the seeds' rates together.
    group = combine_seeds(ppo, records)
    assert group.wall_minutes == 20.0 and group.sps == 400.0
    # Separate jobs, maybe at different times: the mean per seed.
    apart = combine_seeds(td3, records)
    assert apart.wall_minutes == 15.0 and apart.sps == 200.0
    assert apart.return_mean == group.return_mean == 15.0 and apart.return_std == 5.0

    markdown, _ = results_table([group, apart], [], 1000)
    assert "Cell wall min and cell SPS of td3: the mean per seed" in markdown
    markdown, _ = results_table([group], [], 1000)
    assert "mean per seed" not in markdown
    # ppo seeds that trained in two sessions (seed 1 added by a later bench): no one process ran at their summed rate.
    split = [replace(records[0], trained_with=(0,)), replace(records[1], trained_with=(1,))]
    assert combine_seeds(ppo, [replace(r, trained_with=(0, 1)) for r in records]).sps == 400.0
    late = combine_seeds(ppo, split)
    assert late.wall_minutes == 15.0 and late.sps == 200.0
    markdown, _ = results_table([late], [], 1000)
    assert f"Cell wall min and cell SPS of {ppo.name}: the mean per seed, since their seeds did not all" in markdown


def test_bench_defaults_to_five_seeds():
    from canter.cli.main import build_parser

    args = build_parser().parse_args(["bench", "--envs", "Hopper-v5"])
    assert args.seeds == (0, 1, 2, 3, 4)


def test_results_hold_the_aggregates_with_their_intervals(monkeypatch):
    import canter.use.statistics
    from canter.orchestrate.bench_results import combine_records, results_markdown
    from canter.use.reference_scores import normalizer_for

    monkeypatch.setattr(canter.use.statistics, "REPS", 100)  # few resamples: the plumbing, not the coverage
    settings = BenchSettings(
        algos=("ppo", "trpo"), envs=("Hopper-v5", "Walker2d-v5"), seeds=(0, 1, 2, 3, 4), total_steps=1000
    )
    returns = {
        ("ppo", "Hopper-v5"): [3300.0, 3250.0, 2900.0, 3400.0, 1000.0],
        ("ppo", "Walker2d-v5"): [4000.0, 3000.0, 4200.0, 3900.0, 3800.0],
        ("trpo", "Hopper-v5"): [2000.0, 2100.0, 2050.0, 1900.0, 2500.0],
        ("trpo", "Walker2d-v5"): [3500.0, 3600.0, 3700.0, 3400.0, 3300.0],
    }
    results = [
        combine_records(
            cell,
            [
                {"seed": s, "eval_mean": v, "wall_seconds": 60.0, "sps": 100.0}
                for s, v in enumerate(returns[(cell.algo, cell.env_id)])
            ],
        )
        for cell in make_cells(settings)
    ]
    markdown, table_csv, statistics_json = results_markdown(results, [], 1000)
    table, statistics = markdown.split("\n## Statistics\n")
    assert table.startswith("| env | algo | return (mean ± std over seeds) |")
    assert table_csv.splitlines()[0].startswith("env,algo,return_mean,return_std,return_median,seeds")
    for heading in ("Final return per env", "Across envs, normalized", "Performance profile", "Probability of"):
        assert f"### {heading}" in statistics
    assert "| env | method | n | IQM | mean | median | optimality gap | reference |" in statistics
    assert "| Hopper-v5 | ppo | 5 | 3,150.0 [" in statistics  # IQM of 5: one cut at each end
    assert "| ppo | trpo | Hopper-v5, Walker2d-v5 | " in statistics

    data = json.loads(statistics_json)
    hopper = data["cells"][0]
    assert (hopper["env"], hopper["method"], hopper["scores"]) == ("Hopper-v5", "ppo", returns[("ppo", "Hopper-v5")])
    for name in ("iqm", "mean", "median", "optimality_gap"):
        interval = hopper["return"][name]
        assert interval["low"] <= interval["estimate"] <= interval["high"], name
    assert hopper["return"]["mean"]["estimate"] == pytest.approx(np.mean(returns[("ppo", "Hopper-v5")]))
    assert hopper["return"]["gamma"] == 2609.3 and hopper["normalizer"]["reference_source"] == "Tianshou"
    [ppo, _trpo] = data["across_envs"]
    assert ppo["envs"] == ["Hopper-v5", "Walker2d-v5"] and ppo["normalized"]["runs"] == 5
    walker = normalizer_for("ppo", "Walker2d-v5")
    assert ppo["normalized"]["mean"]["estimate"] == pytest.approx(
        np.mean(
            [
                (np.mean(returns[("ppo", "Hopper-v5")]) - hopper["normalizer"]["random"])
                / (2609.3 - hopper["normalizer"]["random"]),
                (np.mean(returns[("ppo", "Walker2d-v5")]) - walker.random) / (walker.reference - walker.random),
            ]
        )
    )
    assert set(data["performance_profiles"]) == {"ppo", "trpo"}
    [comparison] = data["probability_of_improvement"]
    assert (comparison["x"], comparison["y"]) == ("ppo", "trpo") and data["bootstrap"]["reps"] == 100


def test_a_cell_with_a_diverged_seed_is_left_out_of_the_statistics_and_named(monkeypatch):
    """A seed whose eval.json holds a NaN mean (a diverged policy) has no place in the bootstrap statistics: its cell
    stays out of them whole, the results say so, and the results file is still written."""
    import canter.use.statistics
    from canter.orchestrate.bench_results import combine_records, results_markdown

    monkeypatch.setattr(canter.use.statistics, "REPS", 100)
    settings = BenchSettings(algos=("ppo", "trpo"), envs=("Hopper-v5",), seeds=(0, 1, 2), total_steps=1000)
    returns = {"ppo": [3300.0, math.nan, 2900.0], "trpo": [2000.0, 2100.0, 2050.0]}
    results = [
        combine_records(
            cell,
            [{"seed": s, "eval_mean": v, "wall_seconds": 60.0, "sps": 100.0} for s, v in enumerate(returns[cell.algo])],
        )
        for cell in make_cells(settings)
    ]
    markdown, _csv, statistics_json = results_markdown(results, [], 1000)
    ppo_cell = results[0]["cell"]
    assert f"Left out of the statistics: {ppo_cell}, each with a final evaluation that is not finite" in markdown
    assert "| Hopper-v5 | ppo | nan ± nan |" in markdown
    data = json.loads(statistics_json)
    assert [(c["method"], c["scores"]) for c in data["cells"]] == [("trpo", returns["trpo"])]


def test_a_bench_rerun_resumes_its_stopped_seeds_with_the_budget_it_is_given(tmp_path, monkeypatch):
    """A cell stopped by run.max_minutes and run again with another limit resumes under the new one, as `canter
    train --resume --max-minutes` does; the saved limit would stop it again at the same point. The same for the
    return target: a run stopped on reaching a lower one trains on toward the target given now."""
    import shutil
    from dataclasses import replace

    from canter.config.serialize import to_toml
    from canter.orchestrate.jobs import JobSpec, run_job
    from canter.training import loop
    from canter.training.run_folder import read_config

    run = tmp_path / "run"
    shutil.copytree(ARCHIVED_RUN, run)
    saved = read_config(run)
    given = replace(saved, run=replace(saved.run, total_steps=10_000, max_minutes=30.0, stop_at_return=500.0))
    calls = []
    monkeypatch.setattr(loop, "resume_seeds", lambda dirs, total, **kw: calls.append((dirs, total, kw)))
    run_job(JobSpec(to_toml(given), {saved.run.seed: str(run)}))
    assert calls == [([run], 10_000, {"max_minutes": 30.0, "stop_at_return": 500.0, "quiet": True})]


def test_a_job_stopped_by_a_signal_trains_no_further_seeds_and_evaluates_nothing(tmp_path, monkeypatch):
    """A signal stops the group it lands in with a checkpoint; the job's other seeds and its final evaluation wait
    for the re-run, so that bench and tune see it stopped rather than evaluating half-trained policies. That holds
    for a signal after the group's last check too, which leaves its seeds finished."""
    import os
    import signal

    from canter.config.serialize import to_toml
    from canter.orchestrate import jobs
    from canter.signals import StopFlag
    from canter.training import loop
    from canter.training.run_folder import read_config

    run = tmp_path / "resumed"
    shutil.copytree(ARCHIVED_RUN, run)
    saved = read_config(run)
    given = replace(saved, run=replace(saved.run, total_steps=10_000))
    called = []

    def resume_then_signalled(dirs, total, **kw):
        with StopFlag():  # as the group's own does, after its last check
            os.kill(os.getpid(), signal.SIGTERM)
        return []

    monkeypatch.setattr(loop, "resume_seeds", resume_then_signalled)
    monkeypatch.setattr(loop, "train_seeds", lambda *args, **kw: called.append("train_seeds") or [])
    monkeypatch.setattr(jobs, "write_final_eval", lambda *args: called.append("write_final_eval") or {})
    seeds = {saved.run.seed: str(run), saved.run.seed + 1: str(tmp_path / "fresh")}
    jobs.run_job(jobs.JobSpec(to_toml(given), seeds, eval_episodes=5))
    assert called == []

    monkeypatch.setattr(loop, "resume_seeds", lambda dirs, total, **kw: [])
    jobs.run_job(jobs.JobSpec(to_toml(given), seeds, eval_episodes=5))
    assert called == ["train_seeds", "write_final_eval", "write_final_eval"]


def test_a_bench_rerun_refuses_to_retrain_a_finished_run_kept_without_checkpoints(tmp_path):
    """A results archive keeps a run's config, metrics, summary and evaluation without its checkpoints: a bench with
    a larger budget cannot train it on, and must not delete it to start again."""
    import shutil
    from dataclasses import replace

    from canter.config.serialize import to_toml
    from canter.errors import CanterError
    from canter.orchestrate.jobs import JobSpec, run_job
    from canter.training.run_folder import read_config

    run = tmp_path / "run"
    shutil.copytree(ARCHIVED_RUN, run)
    shutil.rmtree(run / "checkpoints")
    (run / "summary.json").write_text(json.dumps({"global_step": 4096, "stop_reason": "budget"}))
    kept = sorted(p.name for p in run.iterdir())
    saved = read_config(run)
    given = replace(saved, run=replace(saved.run, total_steps=10_000))
    with pytest.raises(CanterError, match="holds a finished run without its checkpoints"):
        run_job(JobSpec(to_toml(given), {saved.run.seed: str(run)}))
    assert sorted(p.name for p in run.iterdir() if p.name != ".writer.lock") == kept


def test_a_final_evaluation_of_an_older_checkpoint_does_not_finish_a_seed(tmp_path):
    """An extended budget whose run was interrupted between its training and its final evaluation keeps the old
    eval.json; the seed is not finished until the newest checkpoint is evaluated."""
    import numpy as np

    from canter.config.serialize import to_toml
    from canter.orchestrate.bench_runs import seeds_finished
    from canter.training import checkpoint, run_folder

    settings = BenchSettings(("ppo",), ("Hopper-v5",), (0,), 2000, eval_episodes=3)
    [cell] = make_cells(settings)
    run = cell.run_dir(tmp_path, 0)
    for step in (1000, 2000):
        header = {
            "global_step": step,
            "config": to_toml(replace(cell.config, run=replace(cell.config.run, total_steps=2000))),
        }
        checkpoint.save(run_folder.checkpoint_path(run, step), {"x": np.zeros(1)}, header)
    (run / "summary.json").write_text(json.dumps({"global_step": 2000}))
    (run / "eval.json").write_text(json.dumps({"checkpoint": "ckpt_000000001000.npz", "episodes": 3, "mean": 1.0}))
    assert not seeds_finished(cell, (0,), settings, tmp_path)
    (run / "eval.json").write_text(json.dumps({"checkpoint": "ckpt_000000002000.npz", "episodes": 3, "mean": 1.0}))
    assert seeds_finished(cell, (0,), settings, tmp_path)
    assert not seeds_finished(cell, (0,), replace(settings, eval_episodes=10), tmp_path)
    shutil.rmtree(run / "checkpoints")  # a run restored from a results archive keeps its evaluation only
    assert seeds_finished(cell, (0,), settings, tmp_path)


def test_a_job_whose_evaluation_is_not_a_number_fails_with_its_reason(tmp_path, monkeypatch):
    import optuna

    import canter.orchestrate.bench_distributed as bench_distributed
    from canter.orchestrate.bench_distributed import JOB_ATTR, _job_trial, job_key

    settings = BenchSettings(("ppo",), ("Hopper-v5",), (0,), 1000, eval_episodes=1)
    [job] = make_jobs(make_cells(settings), settings.seeds)
    run = job.cell.run_dir(tmp_path, 0)
    run.mkdir(parents=True)
    (run / "eval.json").write_text('{"mean": NaN, "episodes": 1}')  # as json.dumps writes a NaN

    class Finished:
        def wait(self):
            return 0

    monkeypatch.setattr(bench_distributed, "start_job", lambda spec, folder: Finished())
    monkeypatch.setattr(bench_distributed, "stop_jobs", lambda procs: None)
    monkeypatch.setattr(bench_distributed, "seeds_finished", lambda *args: True)
    study = optuna.create_study(direction="maximize")
    study.enqueue_trial({}, user_attrs={JOB_ATTR: job_key(job, settings)})
    trial = study.ask()
    outcome = _job_trial(study, trial, {job_key(job, settings): job}, settings, tmp_path)
    assert outcome.state == "fail" and outcome.reason.startswith("a seed's eval.json has no finite mean return")


def test_a_failure_reason_is_read_from_the_newest_start_of_the_job(tmp_path):
    from canter.orchestrate.jobs import JOB_START, exit_text, failure_reason

    log = tmp_path / "train.log"
    log.write_text(
        f"{JOB_START} 2026-11-29 07:00:00\n"
        "canter: error: /tmp/run is being written by process 14396; wait for it\n"
        f"{JOB_START} 2026-11-29 07:10:00\n"
        "Hopper-v5 ppo 12,000/20,000\n"
    )
    # The earlier session's error is not why this one failed: a kill left only its progress line.
    assert (
        failure_reason(tmp_path, -9)
        == "training process failed (killed by signal 9 (SIGKILL, probably out of memory)): Hopper-v5 ppo 12,000/20,000"
    )
    log.write_text(log.read_text() + "canter: error: no space left\n")
    assert failure_reason(tmp_path, 2) == "training process failed (exit 2): canter: error: no space left"
    assert (
        exit_text(0) == "exit 0"
        and exit_text(-15) == "killed by signal 15 (SIGTERM)"
        and exit_text(-99) == "killed by signal 99"
    )
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "train.log").write_text("canter: error: a log written before starts were marked\n")
    assert failure_reason(tmp_path / "old", 2).endswith("a log written before starts were marked")


def test_a_storage_url_in_an_error_keeps_its_password_out(capsys):
    from canter.orchestrate.study import redacted

    assert main(["bench", "--envs", "Hopper-v5", "--storage", "postgresql://tuner:s3cret@dbhost:54x/canter"]) == 2
    err = capsys.readouterr().err
    assert "s3cret" not in err and "tuner:***@dbhost:54x/canter" in err and err.count("\n") == 1
    assert redacted("sqlite:///a/b.db") == "sqlite:///a/b.db"
    assert redacted("postgresql://u@h/db") == "postgresql://u@h/db"
    assert redacted("postgresql://u:p@ss@h:5432/db") == "postgresql://u:***@h:5432/db"
    assert redacted("postgresql://u:se/cr@t@h/db") == "postgresql://u:***@h/db"  # SQLAlchemy takes a / in one


def test_a_password_with_an_unencoded_at_sign_is_refused_without_showing_it(capsys):
    assert main(["bench", "--envs", "Hopper-v5", "--storage", "postgresql://tuner:s3@cret@dbhost/canter"]) == 2
    err = capsys.readouterr().err
    assert "cret" not in err and "%40" in err and err.count("\n") == 1


def test_runs_without_a_finished_episode_get_a_note_instead_of_a_plot(tmp_path, capsys):
    """A budget in which no episode ended once failed every bench, and every rerun, with plot's "no column
    episodic_return" error after the results were written."""
    from canter.orchestrate.bench_results import plot_env

    run = tmp_path / "run"
    shutil.copytree(ARCHIVED_RUN, run)
    rows = list(csv.reader((run / "metrics.csv").read_text().splitlines()))
    column = rows[0].index("episodic_return")
    for row in rows[1:]:
        row[column] = ""
    with open(run / "metrics.csv", "w", newline="") as f:
        csv.writer(f).writerows(rows)
    plot_env([run], tmp_path / "plot_InvertedPendulum-v5.png")
    assert not (tmp_path / "plot_InvertedPendulum-v5.png").exists()
    assert capsys.readouterr().err == (
        "canter: note: no plot plot_InvertedPendulum-v5.png: no training episode ended within the budget; a larger "
        "--total-steps gives one\n"
    )
