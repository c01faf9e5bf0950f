"""The run folders of a bench's cells: what a job that trains them is given, whether they are finished, whether they
were trained with this bench's settings, and the line a job's start prints."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from canter.config.serialize import to_toml
from canter.config.values import set_text
from canter.errors import CanterError
from canter.orchestrate.bench_grid import BenchSettings, Cell, Job
from canter.orchestrate.jobs import JobSpec
from canter.orchestrate.run_status import is_number, run_status
from canter.run_layout import CONFIG_FILE, EVAL_FILE, evaluates_newest_checkpoint, read_object


def job_spec(job: Job, settings: BenchSettings, bench_dir: Path) -> JobSpec:
    cell = job.cell
    config = cell.config.with_values("run", out_dir=str(bench_dir))
    return JobSpec(
        to_toml(config),
        {s: str(cell.run_dir(bench_dir, s).resolve()) for s in job.seeds},
        settings.eval_episodes,
        settings.track,
    )


def seeds_finished(cell: Cell, seeds: tuple[int, ...], settings: BenchSettings, bench_dir: Path) -> bool:
    """Each seed trained to the budget, with its final evaluation of its newest checkpoint (one left from a smaller
    budget, whose extension stopped before the evaluations, does not count; a run restored from a results archive
    keeps its evaluation and no checkpoint)."""
    for seed in seeds:
        run_dir = cell.run_dir(bench_dir, seed)
        if run_status(run_dir, settings.total_steps, cell.config.run.stop_at_return) != "done":
            return False
        evaluation = read_object(run_dir / EVAL_FILE) or {}  # a damaged one is evaluated again
        if (
            evaluation.get("episodes") != settings.eval_episodes
            or not evaluates_newest_checkpoint(run_dir, evaluation)
            or not is_number(evaluation.get("mean"))
        ):
            return False
    return True


def check_existing_runs(cells: list[Cell], settings: BenchSettings, bench_dir: Path) -> None:
    """Refuse a bench folder whose run folders were trained with other settings than this command gives their
    cells (a changed --set, --config or preset): reusing them would put old results under the new settings. A run
    folder belongs to its cell when it is a seed of the same experiment (`canter.config.experiment`), so a larger
    --total-steps extends finished runs."""
    from canter.config.experiment import experiment_key
    from canter.training.run_folder import read_config

    for cell in cells:
        expected = dict(experiment_key(cell.config))
        for seed in settings.seeds:
            saved = cell.run_dir(bench_dir, seed) / CONFIG_FILE
            if not saved.is_file():
                continue
            try:
                found = dict(experiment_key(read_config(saved.parent)))
            except (CanterError, OSError):
                continue  # unreadable: the run is not usable anyway, and training it anew rewrites the file
            differing = [k for k in expected if found.get(k) != expected[k]]
            if differing:
                key = differing[0]
                more = f" and {len(differing) - 1} more keys" if len(differing) > 1 else ""
                raise CanterError(
                    f"{saved.parent} was trained with {key}={set_text(found.get(key))}{more}, but this bench "
                    f"gives {key}={set_text(expected[key])}; use a new --out, or delete that folder to retrain it"
                )


STOPPED_EARLY = "stopped before its budget (a signal or run.max_minutes); it is checkpointed and a re-run resumes it"


@dataclass(frozen=True)
class SeedProgress:
    """Where a seed of a job stands before the job starts."""

    step: int | None  # its newest checkpoint's step; None where it has none (a seed that trains anew)
    done: bool  # done training (to the budget, or to its return target): the job only evaluates it


def seed_progress(job: Job, settings: BenchSettings, bench_dir: Path) -> list[SeedProgress]:
    """Each seed's newest checkpoint step, which a stopped seed goes on from, and whether it is done training, as
    the job (`canter.orchestrate.jobs.run_job`) decides it."""
    from canter.training import run_folder

    progress = []
    for seed in job.seeds:
        run_dir = job.cell.run_dir(bench_dir, seed)
        found = run_folder.list_checkpoints(run_dir)
        try:
            status = run_status(run_dir, settings.total_steps, job.cell.config.run.stop_at_return)
        except CanterError:  # refused: the job says why
            status = "refused"
        # A checkpoint at step 0 was written by a stop before the first iteration: the seed starts as a new one does.
        step = run_folder.step_of(found[-1]) if found else 0
        progress.append(SeedProgress(step or None, status in ("done", "ended")))
    return progress


def start_text(job: Job, progress: list[SeedProgress], total_steps: int) -> str:
    """The line a job's start prints: whether it trains anew, resumes checkpointed runs (from which step), or only
    evaluates runs done training; where its seeds differ, what each one does. It says `resume` only where a seed
    goes on training from a checkpoint: a seed done training is evaluated, not resumed."""
    seeds = f"seeds {','.join(map(str, job.seeds))}"
    steps = [p.step for p in progress]
    if all(p.done for p in progress):
        if all(step is not None and step >= total_steps for step in steps):
            return f"evaluate {job.name} ({seeds}; trained to the budget)"
        return f"evaluate {job.name} ({seeds}; done training)"  # a seed stopped at its return target
    if all(step is None and not p.done for step, p in zip(steps, progress)):
        return f"start {job.name} ({seeds})"
    if not any(p.done for p in progress) and len(set(steps)) == 1:
        return f"resume {job.name} ({seeds}) from step {steps[0]:,}"

    def one(seed: int, p: SeedProgress) -> str:
        if p.done:
            return f"seed {seed} done" + ("" if p.step is None else f" at step {p.step:,}")
        return f"seed {seed} " + ("anew" if p.step is None else f"from step {p.step:,}")

    verb = "resume" if any(p.step is not None and not p.done for p in progress) else "start"
    return f"{verb} {job.name} ({seeds}): {', '.join(one(s, p) for s, p in zip(job.seeds, progress))}"
