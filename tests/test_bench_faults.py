"""canter bench when things go wrong: damaged summary.json and eval.json files, a full disk, a second bench on the
same folder, results paths that cannot be written, and what a re-run says it resumes."""

import csv
import json
import os
import socket
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import canter.orchestrate.bench_local as bench_local
from canter.cli.main import main
from canter.config.serialize import to_toml
from canter.errors import CanterError
from canter.orchestrate.bench_grid import BenchSettings, Cell, make_cells, make_jobs
from canter.orchestrate.bench_results import read_seed
from canter.orchestrate.bench_runs import seeds_finished
from canter.orchestrate.jobs import JOB_START, failure_reason, write_final_eval
from canter.orchestrate.run_status import run_status
from canter.training import checkpoint, run_folder
from conftest import ARCHIVED_RUN
from test_bench import TINY

BUDGET = 2000
EVAL = {"checkpoint": f"ckpt_{BUDGET:012d}.npz", "episodes": 3, "mean": 1.0, "returns": [1.0], "lengths": [5]}


def _save_checkpoint(cell: Cell, run: Path, step: int) -> None:
    config = replace(cell.config, run=replace(cell.config.run, total_steps=BUDGET))
    checkpoint.save(
        run_folder.checkpoint_path(run, step), {"x": np.zeros(1)}, {"global_step": step, "config": to_toml(config)}
    )


def _finished_run(cell: Cell, bench_dir: Path, seed: int) -> Path:
    """A run folder that reads as finished: its final checkpoint, its summary and its evaluation of that checkpoint."""
    run = cell.run_dir(bench_dir, seed)
    _save_checkpoint(cell, run, BUDGET)
    (run / "summary.json").write_text(json.dumps({"global_step": BUDGET, "wall_seconds": 60.0, "sps": 100.0}))
    (run / "eval.json").write_text(json.dumps(EVAL))
    return run


def _one_cell(seeds: tuple[int, ...] = (0,)) -> tuple[BenchSettings, Cell]:
    settings = BenchSettings(("ppo",), ("Hopper-v5",), seeds, BUDGET, eval_episodes=3)
    [cell] = make_cells(settings)
    return settings, cell


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


# ---------------------------------------------------------------------------------------- damaged summary and eval


@pytest.mark.parametrize(
    "content",
    ['"x"', "[1]", '{"global_step": 2000, "wall_seconds": "n/a"}', '{"global_step": 2000, "trained_with": ["a"]}'],
)
def test_a_damaged_summary_is_written_again_from_the_final_checkpoint(tmp_path, content):
    """A summary.json that is not an object, or holds a value of the wrong type, is no reason for a traceback
    (AttributeError, ValueError): the bench writes it again from the final checkpoint, as after a kill between the
    two writes."""
    settings, cell = _one_cell()
    run = _finished_run(cell, tmp_path, 0)
    assert run_status(run, BUDGET) == "done" and seeds_finished(cell, (0,), settings, tmp_path)
    (run / "summary.json").write_text(content)
    assert run_status(run, BUDGET) == "ended"
    assert not seeds_finished(cell, (0,), settings, tmp_path)
    assert read_seed(run, 0).wall_seconds is None  # the table's reader never raises either


def test_a_damaged_summary_without_a_checkpoint_to_rebuild_it_from_is_named(tmp_path):
    settings, cell = _one_cell()
    run = _finished_run(cell, tmp_path, 0)
    (run / "checkpoints" / EVAL["checkpoint"]).unlink()  # a run kept from a results archive
    (run / "summary.json").write_text('{"global_step": 2000, "sps": null}')
    with pytest.raises(CanterError) as raised:
        seeds_finished(cell, (0,), settings, tmp_path)
    assert str(raised.value) == (
        f"{run / 'summary.json'} is damaged (sps is not a number); restore it from a copy, or move {run} away to "
        f"train it again"
    )


@pytest.mark.parametrize(
    "content", ["[1]", '"x"', json.dumps({**EVAL, "mean": None}), json.dumps({**EVAL, "mean": "1"})]
)
def test_a_damaged_evaluation_is_done_again(tmp_path, monkeypatch, content):
    """An eval.json that is not an object, or whose mean is not a number, is no reason for a traceback
    (AttributeError, TypeError): the seed is unfinished until its job evaluates it again."""
    import canter.use.evaluate
    import canter.use.policy

    settings, cell = _one_cell()
    run = _finished_run(cell, tmp_path, 0)
    (run / "eval.json").write_text(content)
    assert not seeds_finished(cell, (0,), settings, tmp_path)
    assert read_seed(run, 0).eval_mean is None

    class Evaluated:
        mean, std = 2.0, 0.0

        def summary(self):
            return {"returns": [2.0], "lengths": [5], "backend": "envpool", "physics": {}}

    monkeypatch.setattr(canter.use.policy, "load", lambda run_dir: None)
    monkeypatch.setattr(canter.use.evaluate, "evaluate", lambda *args, **kwargs: Evaluated())
    assert write_final_eval(run, 3)["mean"] == 2.0
    assert seeds_finished(cell, (0,), settings, tmp_path)


@pytest.mark.slow
def test_a_bench_rerun_over_damaged_files_writes_them_again_and_says_what_it_resumes(tmp_path, capsys):
    """A re-run over damaged files writes each of them again without a traceback, and its `start` lines tell a job
    that trains anew from one that resumes."""
    out = tmp_path / "bench"
    argv = ["bench", "--envs", "InvertedPendulum-v4", "--seeds", "0,1", "--total-steps", "1024", "--episodes", "2"]
    argv += ["--grid", "ppo.ent_coef=0,0.01", "--jobs", "2", "--out", str(out)] + TINY
    assert main(argv) == 0, capsys.readouterr().err
    capsys.readouterr()
    damaged, cut = "InvertedPendulum-v4__ppo__ppo.ent_coef=0.0", "InvertedPendulum-v4__ppo__ppo.ent_coef=0.01"
    (out / f"{damaged}__s0" / "summary.json").write_text('"x"')
    summary = json.loads((out / f"{damaged}__s1" / "summary.json").read_text())
    (out / f"{damaged}__s1" / "summary.json").write_text(json.dumps({**summary, "wall_seconds": "n/a"}))
    (out / f"{damaged}__s0" / "eval.json").write_text("[1]")
    evaluation = json.loads((out / f"{damaged}__s1" / "eval.json").read_text())
    (out / f"{damaged}__s1" / "eval.json").write_text(json.dumps({**evaluation, "mean": None}))
    interrupted = out / f"{cut}__s1"  # stopped after its first checkpoint
    *_, kept, final = sorted((interrupted / "checkpoints").glob("ckpt_*.npz"))
    for path in (final, interrupted / "summary.json", interrupted / "eval.json"):
        path.unlink()
    newest = run_folder.step_of(sorted((out / f"{cut}__s0" / "checkpoints").glob("ckpt_*.npz"))[-1])

    assert main(argv) == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    assert f"evaluate {damaged} (seeds 0,1; trained to the budget)" in printed
    resumed = f"seed 0 done at step {newest:,}, seed 1 from step {run_folder.step_of(kept):,}"  # seed 0 finished
    assert f"resume {cut} (seeds 0,1): {resumed}" in printed
    for seed in (0, 1):
        assert isinstance(json.loads((out / f"{damaged}__s{seed}" / "eval.json").read_text())["mean"], float)
        assert isinstance(json.loads((out / f"{damaged}__s{seed}" / "summary.json").read_text())["wall_seconds"], float)
    with open(out / "results.csv", newline="") as f:
        assert [row["seeds"] for row in csv.DictReader(f)] == ["2", "2"]

    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "2 of 2 jobs already done" in printed and f"skip {cut} (finished)" in printed


# ---------------------------------------------------------------------------------------------------- full disk


@pytest.mark.slow
def test_a_full_disk_when_a_job_starts_is_one_line_and_leaves_no_half_written_spec(tmp_path):
    """A file-size limit makes every write past 1 KiB fail as a full disk does (EFBIG, one of its errors), without
    root or a small file system: the bench's lock fits, a job's job.json (1.4 KB) does not. It was a traceback."""

    # The limit is set in the child itself: a preexec_fn would fork this process, which runs JAX's threads.
    program = (
        "import resource, signal, sys; signal.signal(signal.SIGXFSZ, signal.SIG_IGN); "  # the error, not the kill
        "resource.setrlimit(resource.RLIMIT_FSIZE, (1024, 1024)); "
        "from canter.cli.main import main; sys.exit(main(sys.argv[1:]))"
    )
    out = tmp_path / "b"
    argv = ["bench", "--envs", "InvertedPendulum-v4", "--seeds", "0", "--total-steps", "1000", "--out", str(out)]
    done = subprocess.run([sys.executable, "-c", program, *argv], capture_output=True, text=True, timeout=300)
    job = out / ".cells" / "InvertedPendulum-v4__ppo"
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr == (
        f"canter: error: cannot write {job / 'job.json'}: File too large; free space in {job}, then run the command "
        f"again\n"
    )
    assert not [p.name for p in job.iterdir()]


# ---------------------------------------------------------------------------------------- two benches, one folder


@pytest.mark.slow
def test_a_second_local_bench_on_the_same_folder_is_refused_at_once(tmp_path, capsys):
    """Two local benches on one --out each failed the cells the other held, with the run lock's error, and wrote a
    table of the rest; the second one's start line went into the first one's job logs."""
    out = tmp_path / "b"
    program = f"from canter.training import run_lock; run_lock.acquire({str(out)!r}); print(flush=True); input()"
    other = subprocess.Popen([sys.executable, "-c", program], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert other.stdout is not None and other.stdout.readline() == b"\n"  # it holds the folder
        argv = ["bench", "--envs", "InvertedPendulum-v4", "--seeds", "0", "--total-steps", "1024", "--episodes", "1"]
        code = main(argv + ["--out", str(out)] + TINY)
        err = _one_line_error(capsys)
    finally:
        other.kill()
        other.wait()
    assert code == 2
    assert f"{out} is in use by another bench (process {other.pid} on " in err
    assert err.endswith("; wait for it to finish, or run both with --storage to share the grid between them")
    assert not (out / ".cells").exists()


def test_a_local_bench_and_a_shared_grids_worker_on_one_folder_refuse_each_other(tmp_path, capsys):
    """A local bench and a bench with --storage on one --out trained the same run folders, each failing the jobs the
    other one held, and overwrote each other's tables. The workers of one shared grid still share the folder."""
    import optuna

    from canter.orchestrate.bench_folder import holding_bench_folder, sharing_bench_folder

    out, url = tmp_path / "b", f"sqlite:///{tmp_path / 'grid.db'}"
    out.mkdir()
    argv = ["bench", "--envs", "InvertedPendulum-v4", "--seeds", "0", "--total-steps", "1024", "--episodes", "1"]
    argv += ["--out", str(out)] + TINY
    who = f"(process {os.getpid()} on {socket.gethostname()}: "
    with holding_bench_folder(out):  # a local bench is running on the folder
        assert main([*argv, "--storage", url, "--study", "grid"]) == 2
        err = _one_line_error(capsys)
    assert f"{out} is in use by a bench without --storage {who}" in err
    assert err.endswith(
        "; wait for it to finish, or stop it and run both with --storage to share the grid between them"
    )
    assert optuna.load_study(study_name="grid", storage=url).trials == []  # it queued no job

    with sharing_bench_folder(out, url):  # a worker of the shared grid is running on it
        with sharing_bench_folder(out, url):  # as may the grid's other workers
            pass
        assert main(argv) == 2
        err = _one_line_error(capsys)
    assert f"{out} is in use by a bench that shares its grid through --storage {url} {who}" in err
    assert err.endswith("; wait for it to finish, or run this command with the same --storage to share the grid")
    assert not (out / ".cells").exists()
    with holding_bench_folder(out):  # the worker has ended: a local bench takes the folder
        pass


def test_a_failure_reason_keeps_the_whole_error_with_its_fix(tmp_path):
    """The run lock's error is over 300 characters, and the cut dropped its fix."""
    error = (
        "canter: error: /home/user/bench/HalfCheetah-v5__ppo__ppo.ent_coef=0.01__net.hidden=64-64__s0 is being "
        "written by process 19801 on host (since 2026-11-29T16:24:35: jobs.py /home/user/bench/.cells/HalfCheetah-v5"
        "__ppo__ppo.ent_coef=0.01__net.hidden=64-64/job.json); one process writes a run folder at a time: wait for it "
        "to finish or stop it, then run the command again"
    )
    (tmp_path / "train.log").write_text(f"{JOB_START} 2026-11-29 16:24:40\n{error}\n")
    assert failure_reason(tmp_path, 2) == f"training process failed (exit 2): {error}"
    # Any other last line (a crash's) stays cut short.
    (tmp_path / "train.log").write_text(f"{JOB_START} 2026-11-29 16:24:40\nValueError: {'x' * 1000}\n")
    assert len(failure_reason(tmp_path, 1)) < 400


# ----------------------------------------------------------------------------------------------- results paths


@pytest.mark.parametrize("name", ["results.md", "results.csv", "plot_InvertedPendulum-v4.png"])
@pytest.mark.parametrize("kind", ["folder", "link"])
def test_a_results_path_that_cannot_be_written_is_refused_before_any_job(tmp_path, capsys, name, kind):
    """They were found once every job had trained, with the results.md of write_output's "give a file path", for a
    path that bench has no flag for."""
    out = tmp_path / "b"
    out.mkdir()
    if kind == "folder":
        (out / name).mkdir()
    else:
        (out / name).symlink_to(tmp_path / "elsewhere")
    argv = ["bench", "--envs", "InvertedPendulum-v4", "--seeds", "0", "--total-steps", "1024", "--episodes", "1"]
    assert main(argv + ["--out", str(out)] + TINY) == 2
    assert _one_line_error(capsys) == (
        f"canter: error: cannot write {out / name}: it is not a plain file (a folder or a link), and the bench "
        f"writes its results there; move it away, then run the command again"
    )
    assert not (out / ".cells").exists()


# --------------------------------------------------------------------------------------------- what a re-run says


def test_a_jobs_start_line_says_whether_it_trains_anew_resumes_or_evaluates():
    from canter.orchestrate.bench_runs import SeedProgress, start_text

    _, cell = _one_cell((0, 1))
    [job] = make_jobs([cell], (0, 1))
    new, done = SeedProgress(None, False), SeedProgress(BUDGET, True)
    assert start_text(job, [new, new], BUDGET) == "start Hopper-v5__ppo (seeds 0,1)"
    stopped = SeedProgress(1024, False)
    assert start_text(job, [stopped, stopped], BUDGET) == "resume Hopper-v5__ppo (seeds 0,1) from step 1,024"
    assert (
        start_text(job, [stopped, new], BUDGET)
        == "resume Hopper-v5__ppo (seeds 0,1): seed 0 from step 1,024, seed 1 anew"
    )
    assert (
        start_text(job, [SeedProgress(2048, True), done], BUDGET)
        == "evaluate Hopper-v5__ppo (seeds 0,1; trained to the budget)"
    )
    # Stopped at its return target before the budget: done, and evaluated.
    assert start_text(job, [SeedProgress(1024, True), done], BUDGET) == (
        "evaluate Hopper-v5__ppo (seeds 0,1; done training)"
    )


def test_a_start_line_says_resume_only_of_seeds_that_go_on_training():
    """A seed added to a finished bench: the finished seeds are done, not resumed; a stopped one resumes."""
    from canter.orchestrate.bench_runs import SeedProgress, start_text

    _, cell = _one_cell((0, 1, 2))
    [job] = make_jobs([cell], (0, 1, 2))
    done0, done1, new = SeedProgress(5746, True), SeedProgress(5763, True), SeedProgress(None, False)
    assert start_text(job, [done0, done1, new], BUDGET) == (
        "start Hopper-v5__ppo (seeds 0,1,2): seed 0 done at step 5,746, seed 1 done at step 5,763, seed 2 anew"
    )
    assert start_text(job, [done0, SeedProgress(1024, False), new], BUDGET) == (
        "resume Hopper-v5__ppo (seeds 0,1,2): seed 0 done at step 5,746, seed 1 from step 1,024, seed 2 anew"
    )
    # A done seed and a stopped one at the same step do not share a `from step`.
    assert start_text(job, [SeedProgress(1024, True), SeedProgress(1024, False), new], BUDGET) == (
        "resume Hopper-v5__ppo (seeds 0,1,2): seed 0 done at step 1,024, seed 1 from step 1,024, seed 2 anew"
    )


def test_a_jobs_seed_progress_reads_which_seeds_are_done_from_their_run_folders(tmp_path):
    from canter.orchestrate.bench_runs import SeedProgress, seed_progress

    settings, cell = _one_cell((0, 1, 2))
    [job] = make_jobs([cell], (0, 1, 2))
    _finished_run(cell, tmp_path, 0)
    _save_checkpoint(cell, cell.run_dir(tmp_path, 1), 512)
    assert seed_progress(job, settings, tmp_path) == [
        SeedProgress(BUDGET, True),
        SeedProgress(512, False),
        SeedProgress(None, False),
    ]


def test_a_rerun_counts_the_jobs_already_done_and_names_the_step_each_resumes_from(tmp_path, capsys, monkeypatch):
    settings = BenchSettings(
        ("ppo",),
        ("Hopper-v5",),
        (0, 1),
        BUDGET,
        grid=(("ppo.ent_coef", ("0", "0.01")),),
        eval_episodes=3,
        poll_seconds=0,
    )
    finished, partial = make_cells(settings)
    for seed in (0, 1):
        _finished_run(finished, tmp_path, seed)
    _save_checkpoint(partial, partial.run_dir(tmp_path, 0), 512)

    class Stopped:
        def poll(self):
            return 0

    started = []
    monkeypatch.setattr(bench_local, "start_job", lambda spec, folder, caps: started.append(folder) or Stopped())
    bench_local.run_local([finished, partial], settings, tmp_path)
    lines = capsys.readouterr().out.splitlines()
    assert lines[:3] == [
        "1 of 2 jobs already done",
        f"skip {finished.name} (finished)",
        f"resume {partial.name} (seeds 0,1): seed 0 from step 512, seed 1 anew",
    ]
    assert started == [tmp_path / ".cells" / partial.name]


def test_a_damaged_checkpoint_of_a_bench_seed_gets_the_bench_s_own_fix(archived_run):
    from canter.orchestrate.jobs import bench_advice_for_damaged_checkpoints
    from canter.training import checkpoint, run_folder

    newest = run_folder.list_checkpoints(archived_run)[-1]
    newest.write_bytes(newest.read_bytes()[:1000])
    with pytest.raises(CanterError) as refused, bench_advice_for_damaged_checkpoints():
        checkpoint.read(newest)
    assert str(refused.value) == (
        f"checkpoint {newest} is corrupt or truncated; move it out of {newest.parent}, and the re-run resumes the "
        "seed from the checkpoint before it"
    )
    for path in run_folder.list_checkpoints(archived_run)[:-1]:
        path.unlink()
    with pytest.raises(CanterError) as refused, bench_advice_for_damaged_checkpoints():
        checkpoint.read(newest)
    assert str(refused.value) == (
        f"checkpoint {newest} is corrupt or truncated; it is the seed's only one: move the folder {archived_run} "
        "away, and the re-run trains that seed anew"
    )
    # Train's own advice, outside a bench: start the run again with its config.
    with pytest.raises(checkpoint.DamagedCheckpoint, match="start the run again with canter train --config"):
        checkpoint.read(newest)


def test_a_bench_job_that_resumes_a_damaged_seed_gives_the_bench_s_fix(archived_run):
    from canter.config.serialize import to_toml
    from canter.orchestrate.jobs import JobSpec, run_job
    from canter.training import run_folder

    newest = run_folder.list_checkpoints(archived_run)[-1]
    newest.write_bytes(newest.read_bytes()[:1000])
    config = run_folder.read_config(archived_run)
    spec = JobSpec(to_toml(config.with_values("run", total_steps=10**6)), {config.run.seed: str(archived_run)})
    with pytest.raises(CanterError, match=r"move it out of .*, and the re-run resumes the seed from the checkpoint"):
        run_job(spec)


def test_a_bench_plot_leaves_out_a_seed_folder_that_logged_nothing(archived_run, tmp_path, capsys):
    """On a machine whose job was killed before it logged, a cell another machine trained since still has that
    folder here: the plot goes on without it, and says so."""
    import shutil

    from canter.orchestrate.bench_results import plot_env

    killed = tmp_path / "killed"
    killed.mkdir()
    shutil.copy(archived_run / "config.toml", killed / "config.toml")
    (killed / "metrics.csv").write_text("global_step,iteration\n")
    plot_env([archived_run, killed], tmp_path / "plot_x.png")
    assert (tmp_path / "plot_x.png").stat().st_size > 0
    assert capsys.readouterr().err.startswith("canter: note: plot_x.png leaves out killed: ")


def test_a_job_whose_run_folder_another_process_writes_exits_busy_not_as_a_refusal(archived_run, tmp_path):
    """A killed bench's job may still be writing its checkpoint when the bench runs again: that job's folder is busy
    for a while, which a later try finds free, so the job does not exit as a refusal that a retry meets again."""
    from canter.config.serialize import to_toml
    from canter.orchestrate import jobs
    from canter.training import run_folder

    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"from canter.training import run_lock; run_lock.acquire({str(archived_run)!r}); "
            "print('held', flush=True); import time; time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline() == "held\n"
        config = run_folder.read_config(archived_run)
        spec = jobs.JobSpec(to_toml(config.with_values("run", total_steps=10**6)), {config.run.seed: str(archived_run)})
        (tmp_path / "job.json").write_text(spec.to_json())
        job = subprocess.run(
            [sys.executable, "-m", "canter.orchestrate.jobs", str(tmp_path / "job.json")],
            capture_output=True,
            text=True,
        )
        assert job.returncode == jobs.BUSY and "is being written by process" in job.stderr, job.stderr
        assert not jobs.needs_a_fix(jobs.failure_reason(tmp_path, jobs.BUSY))
    finally:
        holder.kill()
        holder.wait()


def test_a_busy_job_is_queued_again_after_its_retry_time_until_it_has_waited_its_time():
    clock = [100.0]
    settings = BenchSettings(("ppo",), ("Hopper-v5",), (0,), BUDGET, grid=(("ppo.ent_coef", ("0", "0.01")),))
    job, second = make_jobs(make_cells(settings), (0,))
    busy = bench_local.BusyRetries(wait_seconds=30.0, retry_seconds=10.0, clock=lambda: clock[0])
    pending = [second]
    assert busy.retry(job, pending) and pending == [second, job]
    assert busy.next_due(pending) is second and busy.next_due(pending) is None  # job waits for its retry
    clock[0] = 110.0
    assert busy.next_due(pending) is job and pending == []
    clock[0] = 125.0
    assert busy.retry(job, pending) and busy.next_due(pending) is None
    clock[0] = 130.0  # 30 s since its first busy exit: it fails as any job does
    assert not busy.retry(job, [])


@pytest.mark.slow
def test_a_bench_waits_for_a_run_folder_that_a_stopping_job_still_writes(tmp_path, capsys, monkeypatch):
    """A bench run again right after it was killed finds its jobs' folders held by the old jobs, which still write
    their checkpoints: it tries them again rather than fail their cells."""
    import threading

    monkeypatch.setattr(bench_local, "BUSY_RETRY_SECONDS", 1.0)
    bench = tmp_path / "bench"
    run = bench / "InvertedPendulum-v4__ppo__s0"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"from canter.training import run_lock; run_lock.acquire({str(run)!r}); "
            "print('held', flush=True); import time; time.sleep(300)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )

    def release_once_refused() -> None:
        while holder.poll() is None:
            logs = [log.read_text() for log in bench.glob(".cells/*/train.log")]
            if any("is being written by" in log for log in logs):
                holder.kill()
            threading.Event().wait(0.2)

    assert holder.stdout.readline() == "held\n"
    releaser = threading.Thread(target=release_once_refused)
    releaser.start()
    try:
        argv = ["bench", "--envs", "InvertedPendulum-v4", "--seeds", "0", "--total-steps", "512", "--episodes", "1"]
        code = main([*argv, "--out", str(bench), *TINY])
    finally:
        holder.kill()
        releaser.join()
    out, err = capsys.readouterr()
    assert code == 0, err
    wait = f"wait  InvertedPendulum-v4__ppo: {run} is being written by process {holder.pid} on "
    assert wait in out and "; trying again every 1 s, for up to 4 min" in out, out
    assert (run / "eval.json").is_file() and "FAIL" not in out


def test_a_seed_stopped_before_its_first_iteration_starts_anew_in_the_start_line(tmp_path):
    """A stop during the warm-up leaves a checkpoint at step 0, from which the seed starts as a new one does."""
    from canter.orchestrate.bench_runs import seed_progress, start_text

    settings, cell = _one_cell((0, 1))
    [job] = make_jobs([cell], (0, 1))
    for seed, step in ((0, 0), (1, 0)):
        folder = cell.run_dir(tmp_path, seed) / "checkpoints"
        folder.mkdir(parents=True)
        (folder / f"ckpt_{step:012d}.npz").write_bytes(b"")
    progress = seed_progress(job, settings, tmp_path)
    assert start_text(job, progress, BUDGET) == "start Hopper-v5__ppo (seeds 0,1)"


def test_a_bench_plot_keeps_a_seed_whose_metrics_are_archived(tmp_path, monkeypatch):
    """A bench folder restored from a results archive holds metrics.csv.gz, which plot reads as it reads metrics.csv."""
    import gzip
    import shutil

    from canter.orchestrate import bench_results
    from canter.orchestrate.bench_grid import BenchSettings, make_cells
    from canter.training.run_folder import read_config

    config = read_config(ARCHIVED_RUN)
    settings = BenchSettings((config.run.algo,), (config.env.id,), (config.run.seed,), config.run.total_steps)
    cells = make_cells(settings)
    run = cells[0].run_dir(tmp_path, config.run.seed)
    shutil.copytree(ARCHIVED_RUN, run)
    (run / "metrics.csv.gz").write_bytes(gzip.compress((run / "metrics.csv").read_bytes()))
    (run / "metrics.csv").unlink()
    plotted = []
    monkeypatch.setattr(bench_results, "plot_env", lambda run_dirs, path: plotted.append(run_dirs))
    bench_results.write_results(cells, [], settings, tmp_path)
    assert plotted == [[run]]
