"""What a resume starts from: the run's saved config with only its budget changed, the checks that a resumed
config or group is the run it continues, the refusals of folders that cannot go on (a run inside a new run's folder,
lost checkpoints), the restart of a run killed before its first checkpoint, and the summary of a run that trained
its budget but stopped before writing it."""

from __future__ import annotations

import numbers
import sys
from collections.abc import Sequence
from enum import Enum
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from canter.config.schema import Config
from canter.config.values import unlimited_as_none
from canter.errors import CanterError
from canter.parsing import toml_table
from canter.run_layout import (
    ARCHIVED_METRICS_FILE,
    CHECKPOINT_FOLDER,
    CONFIG_FILE,
    METRICS_FILE,
    SUMMARY_FILE,
    VERSIONS_FILE,
    StopReason,
    finished_without_checkpoints,
    has_finished,
    read_summary,
    run_files_in,
    run_format,
)
from canter.training import checkpoint, run_folder, run_lock, trackers
from canter.training.logger import checkpoint_totals, read_rows, row_steps
from canter.training.seed_run import (
    RunResult,
    SeedStart,
    reached_target,
    read_best,
    read_result,
    readable_best,
    recorded_seeds,
    write_summary,
)
from canter.training.videos import TrainingVideos


class Saved(Enum):
    """A budget key left as the run folder saved it."""

    KEEP = "keep"


# The budget keys that a resume sets for every folder it resumes, by the resume's Python argument.
_BUDGET_ARGUMENTS = {
    "run.total_steps": "total_steps",
    "run.max_minutes": "max_minutes",
    "run.stop_at_return": "stop_at_return",
}


def check_one_group(run_dirs: Sequence[str | Path], configs: list[Config]) -> None:
    """Folders resume together as one group when they are distinct runs of one config that differ in run.seed."""
    from canter.config.experiment import differing_keys, flat_config

    seen: dict[Path, str | Path] = {}
    for run_dir in run_dirs:
        if (folder := Path(run_dir).resolve()) in seen:
            other = f" (as {seen[folder]})" if str(seen[folder]) != str(run_dir) else ""
            raise CanterError(
                f"the run folders to resume together have repeated seeds: {run_dir} is given twice{other}; give "
                f"each run folder once"
            )
        seen[folder] = run_dir
    reference = configs[0].with_values("run", seed=0)
    for run_dir, config in zip(run_dirs, configs):
        if config.with_values("run", seed=0) != reference:
            keys = [k for k in differing_keys([configs[0], config], key_of=flat_config) if k != "run.seed"]
            keys.sort(key=lambda k: k not in ("env.id", "run.algo"))  # what tells two experiments apart first
            named = ", ".join(keys[:4]) + (f" and {len(keys) - 4} more keys" if len(keys) > 4 else "")
            if differing_keys([configs[0], config]):
                fix = "they are runs of different experiments, which resume one at a time"
            elif keys and set(keys) <= set(_BUDGET_ARGUMENTS):
                flags = " and ".join(
                    f"--{_BUDGET_ARGUMENTS[key].replace('_', '-')} ({_BUDGET_ARGUMENTS[key]}= from Python)"
                    for key in keys
                )
                fix = f"pass {flags} to give them one budget, or resume them one by one"
            else:
                fix = "resume them one at a time"
            raise CanterError(
                f"{run_dir} differs from {run_dirs[0]} in more than run.seed{f' ({named})' if named else ''}; {fix}"
            )
    seeds = [c.run.seed for c in configs]
    if len(set(seeds)) != len(seeds):
        raise CanterError(
            f"the run folders to resume together have repeated seeds {seeds}; a group needs distinct seeds: resume "
            f"the folders of one seed one at a time"
        )


def check_same_experiment_and_seed(saved: Config, config: Config, run_dir: Path) -> None:
    """A resume continues the run it finds: a config that differs in what is learned (`canter.config.experiment`)
    or in its seed would train another run on its state. Budget, output and bookkeeping keys may differ."""
    from canter.config.experiment import differing_keys

    differing = [key for key in differing_keys([saved, config]) if key != "run.seed"]
    if saved.run.seed != config.run.seed:
        differing.insert(0, "run.seed")
    if differing:
        raise CanterError(
            f"the config to resume {run_dir} with differs from the run's in {', '.join(differing)}; a resume may "
            f"change only its budget (run.total_steps, run.max_minutes, run.stop_at_return) and keys that do not "
            f"change what is learned: resume it with canter.resume_seeds([{str(run_dir)!r}], total_steps=...), "
            f"which reads the run's own config"
        )


def has_its_budget(run_dir: Path, config: Config) -> bool:
    newest = run_folder.list_checkpoints(run_dir)
    return bool(newest) and int(checkpoint.read_header(newest[-1]).get("global_step", 0)) >= config.run.total_steps


def summarize_if_it_ended(run_dir: Path) -> RunResult | None:
    """Write summary.json of a run that trained its own budget (the one its newest checkpoint was trained toward)
    but stopped before its summary (a kill between the two writes), as `summarize_ended_run` does for a bench, and
    say so; None for a run whose summary is there, or that stopped short of its own budget."""
    with run_lock.RunLocks() as locks:
        locks.take(run_dir)
        newest = run_folder.list_checkpoints(run_dir)[-1]
        step = run_folder.step_of(newest)
        if step < header_config(checkpoint.read_header(newest), newest).run.total_steps:
            return None  # a lower --total-steps than the run's own: refused as it was
        summarized = (read_summary(run_dir) or {}).get("global_step")
        if isinstance(summarized, int) and summarized >= step:
            return None
        result = summarize_ended_run(run_dir)
    print(
        f"canter: note: {run_dir} had trained its budget ({step:,} steps) but stopped before writing its "
        f"{SUMMARY_FILE}, which is written now from its final checkpoint",
        file=sys.stderr,
    )
    return result


def repair_config_of_a_finished_run(run_dir: Path) -> RunResult | None:
    """A finished run whose config.toml is missing or damaged has it written again from its newest checkpoint,
    which is all that a resume of it has to do (and what every reader of such a file advises); None for any other
    run."""
    if not (unreadable_config(run_dir) and has_finished(run_dir)):
        return None
    result = read_result(run_dir)
    if result is None:
        return None
    with run_lock.RunLocks() as locks:
        locks.take(run_dir)
        newest = checkpoint.latest(run_dir)
        run_folder.write_config(run_dir, header_config(checkpoint.read_header(newest), newest))
        run_folder.migrate(run_dir)
    print(
        f"canter: note: {run_dir} has trained its budget ({result.global_step:,} steps), so nothing is trained: its "
        f"{CONFIG_FILE} is written again from {newest.name} (pass a larger --total-steps, total_steps= from Python, "
        "to train it on)",
        file=sys.stderr,
    )
    return result


def summarize_ended_run(run_dir: Path) -> RunResult:
    """Write summary.json of a run whose final checkpoint was saved but whose summary was not (a full disk, or a kill
    between the two writes), from that checkpoint's header: the run then reads as finished, as it is. The videos
    whose snapshots the killed process left unrendered are rendered first, as a finished run is not resumed again."""
    newest = checkpoint.latest(run_dir)
    header = checkpoint.read_header(newest)
    step = int(header["global_step"])
    totals = checkpoint_totals(header, run_folder.metrics_file(run_dir))
    recent = totals.recent_returns
    train_seconds = totals.train_seconds
    config = header_config(header, newest)
    TrainingVideos(Path(run_dir), config.run.video_every, step, resumed=True).close()
    checkpoint.kept_best_path(run_dir).unlink(missing_ok=True)  # best.npz is the final checkpoint's
    reached = reached_target(recent, config.run.stop_at_return)
    result = RunResult(
        run_dir=Path(run_dir),
        global_step=step,
        recent_return=float(np.mean(recent)) if recent else None,
        episodes=totals.episodes,
        wall_seconds=totals.wall_seconds,
        compile_seconds=totals.compile_seconds,
        sps=step / train_seconds if train_seconds > 0 else 0.0,
        stop_reason=StopReason.TARGET if reached else StopReason.BUDGET,  # the loop's order: target, then budget
        trained_with=recorded_seeds(header.get("trained_with")),
    )
    summary = write_summary(result)
    trackers.open_for_run(config, Path(run_dir), resumed=True).finish(Path(run_dir), summary)
    return result


def _note_a_changed_backend(run_dir: Path, recorded: str, backend: str, start_step: int) -> None:
    """`env.backend = auto` picks what this machine has, which can differ from what the run started on: say so."""
    if recorded != backend:
        print(
            f"canter: note: {run_dir} was trained on {recorded} up to step {start_step:,}; env.backend=auto picks "
            f"{backend} here, which steps it from now on (install {recorded} to keep one backend)",
            file=sys.stderr,
        )


def start_of_seed(config: Config, resume: Any, run_dir: Any, backend: str, locks: run_lock.RunLocks) -> SeedStart:
    """Take one seed's run folder and, for a resume, read its newest checkpoint; refuse a run that has its budget."""
    if resume is not None:
        from canter.training.restore import load_state

        folder = Path(resume)
        need_a_run_to_resume(folder)
        locks.take(folder)  # before its newest checkpoint is read: another writer may be finishing it
        if _never_checkpointed(folder):
            check_same_experiment_and_seed(saved_config(folder), config, folder)
            _refuse_lost_checkpoints(folder, config)
            return SeedStart(folder, restarted=True)
        latest = checkpoint.latest(folder)
        saved, _, state, header = load_state(folder, latest)
        check_same_experiment_and_seed(saved, config, folder)
        step = int(header["global_step"])
        _note_a_changed_backend(folder, header["env"]["backend"], backend, step)
        earlier = checkpoint_totals(header, run_folder.metrics_file(folder))
        # Read, and made to fit the checkpoint, also where this session does not evaluate: the run may again.
        best = read_best(folder) if config.run.eval_every else readable_best(folder)
        kept = readable_best(folder, checkpoint.kept_best_path(folder))
        untrained = bool(header.get("untrained", False))
        start = SeedStart(folder, state, step, earlier, latest, untrained=untrained, best=best, kept_best=kept)
    else:
        if run_dir is not None:
            _refuse_a_run_in(Path(run_dir))
            _refuse_a_folder_of_runs(Path(run_dir))
        start = SeedStart(Path(run_dir) if run_dir is not None else run_folder.new_run_dir(config))
    if start.step >= config.run.total_steps:
        if resume is not None and unreadable_config(start.run_dir):
            # `saved_config` promised it: a finished run repaired by a resume that trains nothing
            run_folder.write_config(start.run_dir, saved)
        raise CanterError(
            f"{start.run_dir} already has {start.step} of run.total_steps={config.run.total_steps} "
            f"steps; pass a --total-steps (total_steps= from Python) larger than {start.step} to extend it"
        )
    if resume is not None and reached_target(start.earlier.recent_returns, config.run.stop_at_return):
        # Not refused: a bench re-run given a target resumes such a seed so that it ends there, as an uncut run would.
        mean = float(np.mean(start.earlier.recent_returns))
        print(
            f"canter: note: {start.run_dir} has reached its return target run.stop_at_return="
            f"{config.run.stop_at_return:g} already (the mean of its last training episodes is {mean:.1f}), so it "
            "stops after one iteration; to train it on, pass --stop-at-return with a higher target, or inf for none",
            file=sys.stderr,
        )
    if resume is None:
        locks.take(start.run_dir)  # before anything is written to it
        # At once: a process killed while its envs are made or its program compiles leaves a run that a resume
        # starts again, not a folder that holds nothing but the lock.
        try:
            run_folder.create(start.run_dir, config)
        except BaseException:  # a full disk after config.toml, say: what it wrote goes
            run_folder.discard_unstarted(start.run_dir)
            raise
    return start


def _never_checkpointed(run_dir: Path) -> bool:
    """A run folder with its config.toml, stopped before its first checkpoint (a kill while it compiled or before
    run.checkpoint_every steps; a seed of a group killed between the seeds' first checkpoints). An archive, a
    finished run kept without its checkpoints, is not one: `checkpoint.latest` refuses it."""
    folder = run_folder.checkpoint_dir(run_dir)
    whole = folder.is_dir() or not (folder.exists() or folder.is_symlink())  # else latest() names what is wrong
    return (
        whole
        and not run_folder.list_checkpoints(run_dir)
        and (run_dir / CONFIG_FILE).is_file()
        and not finished_without_checkpoints(run_dir)
    )


def _refuse_lost_checkpoints(run_dir: Path, config: Config) -> None:
    """A run killed before its first checkpoint has logged at most one row at or past run.checkpoint_every (each
    iteration logs its row before its checkpoint) and may have a best.npz of an evaluation. More rows mean its
    checkpoints were lost, and training it again must not throw away its rows or its best policy unasked."""
    try:
        rows = read_rows(run_folder.metrics_file(run_dir))[1]
    except CanterError:  # damaged: its own refusal comes when the resume reads it
        rows = []
    every = config.run.checkpoint_every
    past = [step for step in row_steps(rows) if every > 0 and step >= every]
    best = checkpoint.best_path(run_dir)
    logged_to = max(row_steps(rows), default=0.0)
    if len(past) > 1:
        raise CanterError(
            f"{run_dir} has no checkpoint but has logged rows up to step {max(past):,.0f}, past its first checkpoint "
            f"(run.checkpoint_every={every:,}): its checkpoints were lost; restore them from a copy, or move its "
            f"metrics.csv away to train it again from step 0"
        )
    if best.is_file() and not _evaluated_within(best, logged_to):
        raise CanterError(
            f"{run_dir} has no checkpoint but has {best.name}, the best policy its evaluations found; restore its "
            f"checkpoints from a copy, or move {best} away to train it again from step 0"
        )


def _evaluated_within(best: Path, logged_to: float) -> bool:
    """Whether a best.npz comes from an evaluation at a step the run's rows reach: with rows that stop before a
    second checkpoint was due, it is the best of training the restart does again (`--eval-every` below
    run.checkpoint_every evaluates before the first checkpoint). One past them, or a best.npz without rows, shows
    training whose checkpoints were lost."""
    try:
        step = checkpoint.read_header(best).get("global_step")
    except CanterError:
        return False
    return isinstance(step, int) and 0 < step <= logged_to


def start_over(run_dir: Path) -> None:
    """Such a run has nothing to resume from, so it starts again at step 0 in its own folder, as it first started:
    what it logged of the training it lost is cleared first (once every seed of the group has been checked), so that
    its folder reads as one run."""
    try:
        rows = len(read_rows(run_folder.metrics_file(run_dir))[1])
    except CanterError:  # a damaged file: it is cleared all the same
        rows = 0
    run_folder.clear_for_a_restart(run_dir)
    print(
        f"canter: note: {run_dir} stopped before its first checkpoint, so it trains again from step 0 in its "
        f"folder" + (f" (the {rows} metrics rows it had logged are dropped)" if rows else ""),
        file=sys.stderr,
    )


# The files a resume writes at the top of its run folder, whatever its settings.
WRITTEN_BY_A_RESUME = (CONFIG_FILE, METRICS_FILE, SUMMARY_FILE, VERSIONS_FILE)


def refuse_folders_for_files(run_dir: Path) -> None:
    """A folder where the resume will write one of the run's files is refused before anything is trained: else the
    resume would train to its end and then fail, or read a config.toml folder as a missing file."""
    for name in WRITTEN_BY_A_RESUME:
        path = run_dir / name
        if path.is_dir():
            raise CanterError(
                f"{path} is a folder, where the run keeps its {name} file; move it out of the way, then resume"
            )


def need_a_run_to_resume(folder: Path) -> None:
    """Refuse a path that holds no run to resume before its writer lock is taken: taking it writes a lock file, which
    a refused folder would keep. Checked without the lock: a run's lock file belongs in its folder anyway."""
    if folder.is_file():  # a checkpoint too: a resume goes on from the run's newest
        raise CanterError(f"{folder} is a file, not a run folder; pass the run folder that holds it")
    if folder.name == CHECKPOINT_FOLDER and CHECKPOINT_FOLDER in run_files_in(folder.parent):
        raise CanterError(f"{folder} is the checkpoints folder of a run, not a run folder; pass {folder.parent}")
    refuse_folders_for_files(folder)
    checkpoint.need_run_folder(folder)


# The fix for a new run's run_dir= that is some other folder: its own is made where none is given.
NEW_RUN_DIR = "give run_dir= a new folder, or leave it out for one under run.out_dir"


def _refuse_a_folder_of_runs(run_dir: Path) -> None:
    """A new run given a folder of run folders (a bench's --out, run.out_dir) would mix its files among theirs."""
    inside = checkpoint.runs_inside(run_dir)
    if inside:
        runs = f"{len(inside)} run folder{'s' if len(inside) > 1 else ''}"
        raise CanterError(f"{run_dir} holds {runs} (a bench's?), such as {inside[0]}; {NEW_RUN_DIR}")


def _refuse_a_run_in(run_dir: Path) -> None:
    """A new run given a folder that holds a run would overwrite it: its checkpoints, config and metrics; given the
    checkpoints folder of a run, it would write its files among them, which every later reading of the run skips."""
    if run_dir.name == CHECKPOINT_FOLDER and CHECKPOINT_FOLDER in run_files_in(run_dir.parent):
        raise CanterError(f"{run_dir} is the checkpoints folder of the run {run_dir.parent}; {NEW_RUN_DIR}")
    present = run_files_in(run_dir)
    held = [name for name in (CONFIG_FILE, METRICS_FILE, ARCHIVED_METRICS_FILE, CHECKPOINT_FOLDER) if name in present]
    if held:
        raise CanterError(
            f"{run_dir} already holds a run ({', '.join(held)}); resume it (canter train --resume, or "
            "train(config, resume=...)), or give a new run folder"
        )


def saved_config(run_dir: Path, note: bool = True) -> Config:
    """The run's config.toml; where it is missing, empty or not TOML, the config its newest checkpoint holds (each
    holds the run's whole config), with a note (`note`: the first reading of it in this resume): the resume writes
    config.toml again, so the run loses nothing. A file that reads but holds a value canter refuses stays an error:
    it was edited, and is not overwritten."""

    run_format(run_dir)  # a folder of a newer format is refused, not read through its checkpoint
    try:
        return _lost_keys_restored(run_dir, run_folder.read_config(run_dir), note)
    except CanterError as damaged:
        if not (run_folder.list_checkpoints(run_dir) and unreadable_config(run_dir)):
            raise
        newest = checkpoint.latest(run_dir)
        config = header_config(checkpoint.read_header(newest), newest)
        if not note:
            return config
        print(
            f"canter: note: {run_dir / CONFIG_FILE} cannot be read ({_reason(damaged)}); resuming with "
            f"the config saved in {newest.name}, which this resume writes back to config.toml",
            file=sys.stderr,
        )
        return config


class _CutConfig(NamedTuple):
    lost: list[str]  # the keys config.toml lost, in the order the checkpoint holds them
    saved: Config  # the newest checkpoint's config
    present: dict[str, Any]  # what config.toml holds, as flat keys
    newest: Path


def _cut_config(run_dir: Path) -> _CutConfig | None:
    """A config.toml that parses but lost keys that its newest checkpoint holds: a file cut short at a line's end
    still reads, and each key it lost would take canter's default (the run's budget among them, so a resume would
    train on to the default's 1M steps). A key counts where the checkpoint's config text holds it and a run of that
    config reads it: a format-1 checkpoint holds every section, and an older file leaves out the keys whose value is
    none, as its checkpoint does. A last line without its newline counts as lost (`_whole_lines`). None where nothing
    is lost or no readable checkpoint can say."""
    import tomllib

    from canter.config.overrides import flatten_toml
    from canter.config.serialize import from_toml_text, written_keys

    if not run_folder.list_checkpoints(run_dir):
        return None
    path = Path(run_dir) / CONFIG_FILE
    try:
        newest = checkpoint.latest(run_dir)
        saved_text = checkpoint.config_text(checkpoint.read_header(newest), newest)
        saved = from_toml_text(saved_text, str(newest))
        present = flatten_toml(toml_table(_whole_lines(path.read_text(errors="replace"))), str(path))
    except (CanterError, OSError, tomllib.TOMLDecodeError):
        return None  # the reading of that file or checkpoint by its own reader says what is wrong with it
    read = {f"{section}.{name}" for section, names in written_keys(saved) for name in names}
    lost = [key for key in flatten_toml(toml_table(saved_text), str(newest)) if key in read and key not in present]
    return _CutConfig(lost, saved, present, newest) if lost else None


def _whole_lines(text: str) -> str:
    """The text up to its last newline. canter writes config.toml whole, ending in a newline, so a last line without
    one was cut, perhaps inside a number that still parses (`total_steps = 10` of 100000): its key counts as lost."""
    return text if text.endswith("\n") else text[: text.rfind("\n") + 1]


def _lost_keys_restored(run_dir: Path, config: Config, note: bool) -> Config:
    """`config`, read from the run's config.toml, with the keys that the file lost taken from its newest checkpoint
    (`_cut_config`)."""
    from canter.config.overrides import apply_overrides
    from canter.config.validate import validate

    cut = _cut_config(run_dir)
    if cut is None:
        return config
    path = run_dir / CONFIG_FILE
    restored = apply_overrides(cut.saved, cut.present, str(path))
    validate(restored)
    if note:
        named = ", ".join(cut.lost[:3]) + (f" and {len(cut.lost) - 3} more" if len(cut.lost) > 3 else "")
        print(
            f"canter: note: {path} lacks {named} (cut short?); resuming with the values saved in {cut.newest.name}, "
            "which this resume writes back to config.toml",
            file=sys.stderr,
        )
    return restored


def header_config(header: dict[str, Any], path: Path) -> Config:
    """The run's whole config, as a checkpoint's header holds it."""
    from canter.config.serialize import from_toml_text

    return from_toml_text(checkpoint.config_text(header, path), str(path))


def unreadable_config(run_dir: Path) -> bool:
    """A config.toml missing, empty, not TOML or cut short (`_cut_config`): damaged, where a file that parses whole
    was written or edited as it is."""
    import tomllib

    path = run_dir / CONFIG_FILE
    if not path.is_file():
        return True
    text = path.read_text(errors="replace")
    try:
        toml_table(text)
    except tomllib.TOMLDecodeError:
        return True
    return not text.strip() or _cut_config(run_dir) is not None


def _reason(error: CanterError) -> str:
    """The cause in a config error, without the advice that follows it (here the resume is the fix)."""
    return str(error).split("; ")[0]


def _lifts_the_limit(value: object) -> bool:
    """Whether a limit given to a resume is inf, which lifts the saved one: a numpy number too, as float() takes it."""
    return isinstance(value, numbers.Real) and unlimited_as_none(float(value)) is None


def resume_config(
    run_dir: Path,
    total_steps: int | None,
    max_minutes: float | None = None,
    stop_at_return: float | None | Saved = Saved.KEEP,
) -> Config:
    """The saved config of a run, with only its budget changed: the step budget, the wall-minute limit of the
    resuming process (a saved run.max_minutes otherwise applies again to each process that resumes the run), and
    the return target (a bench re-run gives its own; None: no target)."""
    need_a_run_to_resume(Path(run_dir))
    config = saved_config(Path(run_dir))
    # Checked as a --set of the key is (a string, a NaN or 4096.9 steps refused), not cut to a whole number.
    if total_steps is not None:
        config = config.with_values("run", total_steps=total_steps)
    if max_minutes is not None:  # inf lifts a saved limit
        config = config.with_values("run", max_minutes=None if _lifts_the_limit(max_minutes) else max_minutes)
    if not isinstance(stop_at_return, Saved):
        config = config.with_values("run", stop_at_return=stop_at_return)
    return config
