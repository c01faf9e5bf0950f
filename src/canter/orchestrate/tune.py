"""`canter tune`: Optuna search over a shipped, editable search space, on one machine or many.

A trial samples a config from the search space and trains it (one child process per trial, all seeds of the trial in
it, see `canter.orchestrate.jobs`), evaluating during training every 1/`evaluations` of the budget and at its end
(`run.eval_every`, `run.eval_episodes`: the protocol of `canter eval`, on the same eval env seeds in every trial).
The worker reads those evaluations from the runs' metrics.csv as they are logged and reports their mean over the
trial's seeds to Optuna's median pruner; a pruned trial's training is stopped. The objective is the evaluation at
the end of the budget, averaged over `--seeds-per-trial` seeds (the same seeds for every trial, so trials differ
only in their hyperparameters).

Evaluating during training rather than training in chunks keeps the learning-rate schedule of a trial identical to
that of a single `canter train` of the same config, so the best trial's preset reproduces what was measured.

Parallel `--jobs` are spawned worker processes, no more than the trials the study still lacks, each pinned to its
share of the cores with XLA's thread pools capped; the workers share the study through its storage (SQLite in the
study folder by default, or `--storage postgresql://...`, where any number of machines run the same command).

With `--track`, each seed of a trial is a tracker run named `trial_NNNNN-sSEED`, and every trial of the study is in one
tracker group, `tune-STUDY` (`trial_track`).
"""

from __future__ import annotations

import functools
import math
import os
import re
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from canter.config.build import build_config
from canter.config.overrides import parse_set_args
from canter.config.schema import Config
from canter.config.serialize import to_toml, toml_tables
from canter.errors import CanterError, joined
from canter.files import make_folder, refuse_out_dir_in_a_run
from canter.orchestrate.bench_folder import bench_files_in
from canter.orchestrate.env_check import check_continuous
from canter.orchestrate.job_resources import worker_count
from canter.orchestrate.jobs import JobSpec, failure_reason, start_job, stop_jobs
from canter.orchestrate.search_space import SearchSpace, apply_sample, load_space
from canter.orchestrate.study import (
    DB_FILE,
    FAIL_REASON,
    SETTINGS_ATTR,
    TRIAL_MARKS,
    TRIALS_FOLDER,
    Outcome,
    StorageSettings,
    check_at_least,
    claim_study,
    counts,
    open_storage,
    quiet_optuna,
    restart_study,
    retrying,
    run_worker,
    say,
    study_storage,
    unread_stdout,
)
from canter.run_layout import METRICS_FILE
from canter.training import run_lock
from canter.training.logger import cell_number, read_rows, row_steps
from canter.training.trackers import TrackSpec, check_trackers, open_groups

BEST_FILE = "best.toml"
STUDY_SUMMARY_FILE = "summary.md"
PRESET_ATTR = TRIAL_MARKS["tune"]


@dataclass(frozen=True)
class TuneSettings:
    env_id: str
    algo: str = "ppo"
    trials: int = 50
    jobs: int = 1
    total_steps: int = 1_000_000
    seeds: tuple[int, ...] = (0,)  # every trial trains these seeds
    startup_trials: int = 10  # random trials before TPE; also the pruner's startup
    evaluations: int = 20  # evaluations during training per trial
    eval_episodes: int = 5  # episodes per evaluation
    trial_minutes: float | None = None
    study_hours: float | None = None
    preset: str | None = None  # None: the one the config file's run.preset names, else fast
    config_file: str | None = None
    sets: tuple[str, ...] = ()
    space_file: str | None = None
    out_dir: str = "tune"
    study_name: str | None = None
    storage_url: str | None = None
    heartbeat_seconds: int = 60
    sampler_seed: int | None = None
    poll_seconds: float = 0.5
    track: TrackSpec = field(default_factory=TrackSpec)  # `--track`: see `trial_track`

    def __post_init__(self) -> None:
        check_at_least(
            [
                ("--trials", self.trials, 1),
                ("--jobs", self.jobs, 1),
                ("--evaluations", self.evaluations, 1),
                ("--eval-episodes (eval_episodes)", self.eval_episodes, 1),
                ("--seeds-per-trial (the number of seeds)", len(self.seeds), 1),
                ("--startup-trials (startup_trials)", self.startup_trials, 0),
                ("--heartbeat (heartbeat_seconds)", self.heartbeat_seconds, 1),
            ]
        )
        for name, limit in (
            ("--trial-minutes (trial_minutes)", self.trial_minutes),
            ("--study-hours (study_hours)", self.study_hours),
        ):
            if limit is not None and not limit > 0:
                raise CanterError(f"{name} must be > 0, got {limit:g}")
        if self.study_name is not None:
            check_study_name(self.study_name)
        if not self.out_dir:  # an empty path is the working folder, where the study would scatter its files
            raise CanterError("--out-dir is empty; give a folder for the study folders, or drop --out-dir")

    @property
    def name(self) -> str:
        return self.study_name or f"{self.env_id.split(':')[-1]}__{self.algo}"

    @property
    def study_dir(self) -> Path:
        return Path(self.out_dir) / self.name

    @property
    def storage(self) -> StorageSettings:
        url = self.storage_url or f"sqlite:///{(self.study_dir / DB_FILE).resolve()}"
        return study_storage(url, self.heartbeat_seconds)

    @property
    def eval_interval(self) -> int:
        return max(1, math.ceil(self.total_steps / self.evaluations))


def refuse_bench_folder(settings: TuneSettings) -> None:
    """Refuse an --out-dir, or a study folder, that is a bench's --out folder: the study would write its database,
    trials and tables among the bench's run folders and results."""
    held = bench_files_in(Path(settings.out_dir))
    if held:
        raise CanterError(
            f"--out-dir {settings.out_dir} is a folder of canter bench (it holds {joined(held)}), not a folder for "
            f"tune studies; give another --out-dir"
        )
    held = bench_files_in(settings.study_dir)
    if held:
        raise CanterError(
            f"the study folder {settings.study_dir} (--out-dir/--study) is a folder of canter bench (it holds "
            f"{joined(held)}); give another --out-dir or --study"
        )


def _remove_empty(folders: list[Path]) -> None:
    """Remove `folders`, innermost first, up to the first that holds something."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:  # it holds something (another command's study, say), so it and those above it stay
            return


# A study's folder is OUT_DIR/STUDY: a name with a path in it would put the study elsewhere, or nest it. Any other
# name is kept, since studies already made under it must still resume.
_PATH_CHARACTERS = tuple(c for c in ("/", "\\", os.sep, os.altsep, "\0") if c)


def check_study_name(name: str) -> None:
    if not name or name in (".", "..") or any(c in name for c in _PATH_CHARACTERS) or any(c < " " for c in name):
        raise CanterError(
            f"--study {name!r} is not a plain name; give one without '/', '\\' or control characters (and not '.' "
            f"or '..'), since the study's folder is --out-dir/STUDY"
        )


def seeds_text(seeds: tuple[int, ...], shown: int = 5) -> str:
    """Seeds as a message shows them: '0-99999' for a run of consecutive seeds, else the first few and the count;
    a study of many seeds per trial would otherwise fill a screen."""
    if len(seeds) > 2 and list(seeds) == list(range(seeds[0], seeds[0] + len(seeds))):
        return f"{seeds[0]}-{seeds[-1]}"
    if len(seeds) > shown:
        return f"{', '.join(map(str, seeds[:shown]))}, ... ({len(seeds)} seeds)"
    return ", ".join(map(str, seeds))


def base_config(settings: TuneSettings) -> Config:
    return build_config(
        settings.env_id,
        preset=settings.preset,
        config_file=settings.config_file,
        sets=list(settings.sets),
        seed=settings.seeds[0],
        total_steps=settings.total_steps,
        algo=settings.algo,
    )


def owned_keys(settings: TuneSettings, trial_dir: Path) -> dict[str, tuple[Any, str]]:
    """The keys that every trial takes from tune, whatever its base config holds: key -> (value, what sets it, as
    an error names it)."""
    return {
        "run.out_dir": (str(trial_dir), "tune's --out-dir (each trial trains in its own folder of the study)"),
        "run.eval_every": (settings.eval_interval, "tune's --evaluations (an evaluation every 1/N of the budget)"),
        "run.eval_episodes": (settings.eval_episodes, "tune's --eval-episodes"),
        "run.max_minutes": (None, "tune, as none (a trial trains its whole budget; --trial-minutes limits a trial)"),
        "run.stop_at_return": (None, "tune, as none (every trial trains its whole budget, so that objectives compare)"),
        "run.checkpoint_every": (0, "tune, as 0 (a trial keeps its final checkpoint only)"),
        "run.keep_checkpoints": (1, "tune, as 1 (a trial keeps its final checkpoint only)"),
        "run.tensorboard": (False, "tune, as false (a trial's curves are in its metrics.csv)"),
    }


# The keys that make a study what it is, each with what sets it: a search space that sampled one would train other
# envs, algorithms, seeds or budgets under this study's name, in trials that no longer compare.
STUDY_KEYS = {
    "env.id": "tune's ENV argument (a study tunes one env; tune another in a study of its own)",
    "run.algo": "tune's --algo (a study tunes one algorithm)",
    "run.seed": "tune's --seed and --seeds-per-trial (every trial trains the same seeds)",
    "run.total_steps": "tune's --total-steps (every trial trains the same budget)",
    "run.preset": "tune's --preset (the base config under the sampled values)",
}


# The study keys that tune passes to every trial's config as arguments, over a --set of them.
TRIAL_ARGUMENTS = ("run.seed", "run.total_steps")


def fixed_keys(settings: TuneSettings) -> dict[str, str]:
    """The keys a search space cannot sample, each with what sets it instead."""
    return STUDY_KEYS | {key: what for key, (_, what) in owned_keys(settings, Path()).items()}


def check_owned_keys(settings: TuneSettings) -> None:
    """Refuse a --set of a key tune sets in every trial: it would be dropped. A --config file may give them (a run
    folder's config.toml gives them all), and tune's values win, as a command's own flags beat a file."""
    owned = owned_keys(settings, Path())
    for key in parse_set_args(list(settings.sets)):
        if key in owned:
            raise CanterError(f"{key} is set by {owned[key][1]}; leave out --set {key}")
        if key in TRIAL_ARGUMENTS:
            raise CanterError(f"{key} is set by {STUDY_KEYS[key]}; leave out --set {key}")


def check_settings(settings: TuneSettings) -> tuple[Config, SearchSpace]:
    """Everything that can be refused before a trial starts (`TuneSettings` checks its own values)."""
    check_owned_keys(settings)
    config = base_config(settings)
    from canter.envs import resolve_backend

    resolve_backend(config.env.id, config.env.backend)
    space = load_space(settings.space_file, config.run.algo, fixed_keys(settings))
    from canter.config.algorithms import reads_key, unread_key_error

    for key in space.keys:
        if not reads_key(config.run.algo, key):
            raise CanterError(f"search space {space.source}: {unread_key_error(config.run.algo, key)}")
    check_sets_not_sampled(settings.sets, space)
    check_continuous(config.env.id, config.env.backend)  # last: it makes an env
    return config, space


def check_sets_not_sampled(sets: tuple[str, ...], space: SearchSpace) -> None:
    """Refuse a --set of a key the space samples: the sampled value would replace it in every trial."""
    for key in parse_set_args(list(sets)):
        if key in space.keys:
            raise CanterError(
                f"{key} is given by --set and sampled by the search space too ({space.source}); drop --set {key} "
                f"to search it, or drop [{key}] from the space to fix its value"
            )


def trial_config(base: Config, values: dict[str, Any], trial_dir: Path, settings: TuneSettings) -> Config:
    config = apply_sample(base, values)
    owned = {key.partition(".")[2]: value for key, (value, _) in owned_keys(settings, trial_dir).items()}
    return config.with_values("run", **owned)


# ------------------------------------------------------------------------------------------------- the config file


def config_file_toml(config: Config) -> str:
    """The config as a TOML file that `canter train --config FILE` takes as it is: the keys that define the
    experiment (`canter.config.experiment`), the step budget the trials trained for, which the learning-rate
    schedule follows, and the preset they were built on, so that a run trained from the file is laid over that
    preset and named by it, as the trials were."""
    from canter.config.experiment import flat_config, learning_keys

    flat = flat_config(config)
    tables: dict[str, list[tuple[str, Any]]] = {}
    for key in [*learning_keys(config), "run.total_steps", "run.preset"]:
        section, _, name = key.partition(".")
        tables.setdefault(section, []).append((name, flat[key]))
    return toml_tables(tables.items())


# ------------------------------------------------------------------------------------------------------- a trial


def evaluation_index(step: int, settings: TuneSettings) -> int:
    """Which of the trial's evaluations one at `step` is: 1 .. evaluations, the last for the one at the end of the
    budget. Seeds count their own env steps (EnvPool's autoreset steps are not steps), so the seeds of a group reach
    an evaluation point at slightly different steps; their evaluations are matched by this index."""
    if step >= settings.total_steps:
        return settings.evaluations
    return max(1, min(step // settings.eval_interval, settings.evaluations - 1))


def logged_evaluations(run_dir: Path, settings: TuneSettings) -> dict[int, float]:
    """Evaluation index -> mean return of the evaluations a run has logged to its metrics.csv so far (a line the
    trainer is still writing is left for the next look)."""
    found = {}
    for row in read_rows(run_dir / METRICS_FILE)[1]:
        step, text = cell_number(row.get("global_step")), row.get("eval/return_mean") or ""
        value = cell_number(text)
        damaged = math.isnan(value) and text.strip().lower() != "nan"  # "nan" is a diverged evaluation
        if math.isfinite(step) and text and not damaged and row.get("eval/episodes"):
            found[evaluation_index(int(step), settings)] = value
    return found


def logged_steps(run_dir: Path) -> int:
    """The env steps of the last row a run has logged to its metrics.csv; 0 before its first."""
    steps = row_steps(read_rows(run_dir / METRICS_FILE)[1])
    return int(steps[-1]) if steps else 0


def study_group(settings: TuneSettings) -> str:
    """The tracker group of every trial of the study."""
    return f"tune-{settings.name}"


def trial_track(settings: TuneSettings, number: int) -> TrackSpec:
    """The trackers of a trial: its seeds' runs named after the trial, in the group of the whole study."""
    if not settings.track.names:
        return settings.track
    return replace(
        settings.track,
        group=study_group(settings),
        run_prefix=f"trial_{number:05d}",
        tags=(("canter.study", settings.name), ("canter.trial", str(number))),
    )


_SET_HINT = re.compile(r"--set ([A-Za-z0-9_.]+)=([^\s;,)]+)")


def space_hint(message: str, space: SearchSpace) -> str:
    """`message` with each `--set KEY=VALUE` it offers, for a KEY that the space samples, turned into the space's
    entry to change: a --set of a sampled key is refused, and the sample would override it anyway."""
    sampled = {p.key: p.same_as or p.key for p in space.params}

    def hint(found: re.Match[str]) -> str:
        key, value = found.groups()
        return f"{value} in the search space's [{sampled[key]}]" if key in sampled else found[0]

    return _SET_HINT.sub(hint, message)


def run_trial(trial: Any, settings: TuneSettings, base: Config, space: SearchSpace) -> Outcome:
    """Train and evaluate one trial. Works with an Optuna trial or an `optuna.trial.FixedTrial`."""
    from canter.training import checkpoint

    values = space.suggest(trial)
    trial_dir = settings.study_dir / TRIALS_FOLDER / f"trial_{trial.number:05d}"
    try:
        config = trial_config(base, values, trial_dir, settings)
    except CanterError as exc:
        return Outcome("fail", reason=f"invalid sample: {space_hint(str(exc), space)}")
    url = settings.storage.url
    for attr, text in ((PRESET_ATTR, config_file_toml(config)), ("trial_dir", str(trial_dir.resolve()))):
        retrying(functools.partial(trial.set_user_attr, attr, text), url, "recording a trial")
    run_dirs = {seed: trial_dir / f"s{seed}" for seed in settings.seeds}
    sampled = ", ".join(f"{_short(key)} {_fmt(value)}" for key, value in values.items())
    print(f"start trial {trial.number} ({sampled}) in {trial_dir}", flush=True)

    spec = JobSpec(to_toml(config), {s: str(d) for s, d in run_dirs.items()}, track=trial_track(settings, trial.number))
    proc = start_job(spec, trial_dir)
    deadline = time.monotonic() + settings.trial_minutes * 60 if settings.trial_minutes else None
    reported: dict[int, float] = {}  # evaluation index -> mean return over seeds
    try:
        while True:
            code = proc.poll()
            found = [logged_evaluations(d, settings) for d in run_dirs.values()]
            ready = set.intersection(*(set(f) for f in found)) - set(reported)
            # The final evaluation may be read in the same poll as the one before it, while the trainer is still
            # closing: the trial has then trained its whole budget, and nothing is left to cut.
            finished = settings.evaluations in ready
            for index in sorted(ready):
                value = float(np.mean([f[index] for f in found]))
                reported[index] = value
                step = min(index * settings.eval_interval, settings.total_steps)  # nominal, the same for all trials
                retrying(functools.partial(trial.report, value, step), url, "reporting an evaluation")
                # Once the training has ended (code set), its evaluations are only read late: nothing is left to cut.
                pruning = code is None and not finished and index < settings.evaluations
                if pruning and retrying(trial.should_prune, url, "asking the pruner"):
                    stop_jobs([proc])
                    return Outcome("pruned", reason=f"pruned at step {step} with return {value:.1f}")
            if code is not None:
                break
            if deadline is not None and time.monotonic() > deadline:
                stop_jobs([proc], grace_seconds=5)
                done = min(logged_steps(d) for d in run_dirs.values())
                return Outcome(
                    "fail",
                    reason=f"exceeded --trial-minutes {settings.trial_minutes:g} (stopped after {done:,} steps)",
                )
            time.sleep(settings.poll_seconds)
    finally:
        stop_jobs([proc])
        for d in run_dirs.values():
            if d.is_dir():
                checkpoint.prune(d, 1)
    if code != 0:
        reason = failure_reason(trial_dir, code)
        if "non-finite" in reason:  # divergence is a result of the hyperparameters: the worst outcome, not an error
            return Outcome("pruned", reason=f"diverged: {reason}")
        return Outcome("fail", reason=reason)
    if not reported:
        return Outcome("fail", reason="training stopped before its first evaluation (a signal?)")
    if max(reported) < settings.evaluations:  # a signal stopped the training, which then exits cleanly
        return Outcome(
            "fail", reason=f"stopped before its budget, after {max(reported)} of {settings.evaluations} evaluations"
        )
    return Outcome("complete", value=reported[settings.evaluations])


# ------------------------------------------------------------------------------------------------------ the study


def sampler_seed(seed: int | None, job: int, trials: int) -> int | None:
    """The TPE seed of job `job` joining a study that holds `trials` trials. For a new study: the seed itself for
    job 0, and one drawn from (seed, job) for the others, so that parallel jobs do not propose the same random
    trials, nor do the jobs of machines given seeds a step apart (seed + job gave machine 0's job 1 and machine 1's
    job 0 the same seed). For a study that has trials, one drawn from (seed, job, trials), so that a resumed worker
    does not replay the proposals the study already ran."""
    if seed is None:
        return None
    if trials == 0:
        return seed if job == 0 else int(np.random.SeedSequence([seed, job]).generate_state(1)[0])
    return int(np.random.SeedSequence([seed, job, trials]).generate_state(1)[0])


def make_study(settings: TuneSettings, storage: Any, job: int = 0, trials_before: int | None = None) -> Any:
    """The study with this worker's sampler and pruner (they are not stored; every worker makes its own), seeded by
    `sampler_seed` with --sampler-seed from `trials_before`, the trials the study held when the command started
    (counted here where not given: a worker that counted for itself would see its siblings' first trials)."""
    import optuna

    quiet_optuna()
    pruner = optuna.pruners.MedianPruner(
        n_startup_trials=max(1, settings.startup_trials // 2), n_warmup_steps=settings.total_steps // 3
    )
    study = optuna.create_study(
        storage=storage,
        study_name=settings.name,
        direction="maximize",
        pruner=pruner,
        load_if_exists=True,
    )
    if trials_before is None:
        trials_before = len(study.get_trials(deepcopy=False))
    seed = sampler_seed(settings.sampler_seed, job, trials_before)
    study.sampler = optuna.samplers.TPESampler(n_startup_trials=settings.startup_trials, seed=seed, constant_liar=True)
    return study


def worker(settings: TuneSettings, job: int = 0, trials_before: int | None = None) -> None:
    """One worker: run trials until the study has its number of finished trials."""
    config, space = check_settings(settings)
    storage = open_storage(settings.storage)
    url = settings.storage.url
    study = retrying(functools.partial(make_study, settings, storage, job, trials_before), url, "opening the study")
    deadline = retrying(functools.partial(_study_deadline, study, settings), url, "reading the study")
    run_worker(
        study,
        storage,
        settings.trials,
        lambda trial: announced(trial.number, lambda: run_trial(trial, settings, config, space)),
        heartbeat_seconds=settings.heartbeat_seconds,
        poll_seconds=settings.poll_seconds,
        deadline=deadline,
    )


TRIAL_ENDS = {"complete": "done ", "pruned": "PRUNE", "fail": "FAIL "}


def announced(number: int, run: Callable[[], Outcome]) -> Outcome:
    """Run a trial and print how it ended, as bench prints its jobs: a study of long trials is otherwise silent
    until its summary."""
    started = time.monotonic()
    try:
        outcome = run()
    except Exception as exc:  # the worker records the failure; the line says so here too
        if not unread_stdout(exc):
            say(f"{TRIAL_ENDS['fail']} trial {number}: {type(exc).__name__}: {exc}"[:500])
        raise
    except KeyboardInterrupt:
        say(f"{TRIAL_ENDS['fail']} trial {number}: interrupted")
        raise
    minutes = (time.monotonic() - started) / 60
    told = f"return {outcome.value:.1f}" if outcome.value is not None else (outcome.reason or "no reason recorded")
    say(f"{TRIAL_ENDS[outcome.state]} trial {number} in {minutes:.1f} min: {told}")
    return outcome


def _study_deadline(study: Any, settings: TuneSettings) -> float | None:
    """--study-hours counts from the study's first trial, so workers that join later share the same end."""
    if settings.study_hours is None:
        return None
    starts = [t.datetime_start.timestamp() for t in study.get_trials(deepcopy=False) if t.datetime_start]
    return min(starts, default=time.time()) + settings.study_hours * 3600


def _param_text(param: Any) -> str:
    if param.same_as is not None:
        return f"same as {param.same_as}"
    if param.choices is not None:
        return f"choices {list(param.choices)}"
    return (
        f"{param.low} to {param.high}" + (", log" if param.log else "") + (f", step {param.step}" if param.step else "")
    )


def study_settings(settings: TuneSettings, base: Config, space: SearchSpace) -> dict[str, str]:
    """What makes the trials of a study comparable: their budget, seeds and evaluations, the base config and the
    search space. A resumed study is refused when these differ (`check_study_settings`)."""
    from canter.config.experiment import experiment_key

    found = {
        "--total-steps": str(settings.total_steps),
        "seeds (--seed, --seeds-per-trial)": ",".join(map(str, settings.seeds)),
        "--evaluations": str(settings.evaluations),
        "--eval-episodes": str(settings.eval_episodes),
    }
    found |= {f"the base config's {key}": repr(value) for key, value in experiment_key(base)}
    # Not a key that changes what is learned, but the backend of every evaluation: tune's objective and what the
    # pruner judges. Kept only when set, so that a study stored before it was kept resumes as it was.
    if base.run.eval_backend:
        found["the base config's run.eval_backend"] = repr(base.run.eval_backend)
    found |= {f"the search space's [{p.key}]": _param_text(p) for p in space.params}
    return found


def check_study_settings(study: Any, wanted: dict[str, str], trials_dir: Path) -> Any:
    """Refuse to resume a study with settings that make its trials incomparable, and a new study whose trial
    folders would land on those of an earlier one (a deleted or another database under the same --out-dir). A study
    with no finished trial has nothing to compare, so it restarts with other settings (`restart_study`), as a give-up
    says to fix the cause and run again; not while a trial runs, under the old ones. Returns the study to run."""
    stored = study.user_attrs.get(SETTINGS_ATTR)
    claim_study(study, "tune")
    if stored is None:
        if study.trials == [] and trials_dir.is_dir() and any(trials_dir.iterdir()):
            raise CanterError(
                f"{trials_dir} holds the trials of an earlier study that this database does not know; move it "
                f"away, or pick another --out-dir or --study"
            )
        study.set_user_attr(SETTINGS_ATTR, wanted)
        return study
    differs = _first_difference(stored, wanted)
    if differs is None:
        return study
    n = counts(study)
    if n["COMPLETE"] + n["PRUNED"] + n["RUNNING"] == 0:
        study = restart_study(study)
        study.set_user_attr(SETTINGS_ATTR, wanted)
        print(
            f"canter: note: study '{study.study_name}' had no finished trial, so it now runs with this command's "
            f"settings",
            file=sys.stderr,
        )
        return study
    name, was, now = differs
    raise CanterError(
        f"study '{study.study_name}' was run with {name} {was}, but this command gives {now}; its trials would not "
        f"compare: use the same settings, or a new --study"
    )


def _first_difference(stored: dict[str, str], wanted: dict[str, str]) -> tuple[str, str, str] | None:
    """(setting, stored value, wanted value) of the first setting that differs, as an error shows them."""
    missing = "(not set)"
    for name in dict.fromkeys([*stored, *wanted]):
        if stored.get(name, missing) != wanted.get(name, missing):
            was, now = (setting_text(str(found.get(name, missing))) for found in (stored, wanted))
            return name, was, now
    return None


_SEED_LIST = re.compile(r"[0-9]+(,[0-9]+)*")


def setting_text(value: str, limit: int = 200) -> str:
    """A study setting as an error shows it: a list of seeds as `seeds_text` shows it, and any other value cut at
    `limit` characters, so that the error stays a line."""
    if _SEED_LIST.fullmatch(value):
        return seeds_text(tuple(map(int, value.split(","))))
    return value if len(value) <= limit else f"{value[:limit]}... ({len(value):,} characters)"


def progress_line(study: Any, target: int) -> str:
    """What a resumed study holds, said as the command starts: its finished trials of `target`, and the failed,
    queued (a stopped or dead worker's trial, to run again, while the study lacks trials) and running ones."""
    n = counts(study)
    done = n["COMPLETE"] + n["PRUNED"]
    if done >= target:  # no worker asks for a trial, so queued copies left by a stop do not run
        n["WAITING"] = 0
    line = (
        f"resuming study '{study.study_name}': {done} of {target} trials done "
        f"({n['COMPLETE']} complete, {n['PRUNED']} pruned)"
    )
    words = (("FAIL", "failed"), ("WAITING", "queued"), ("RUNNING", "running"))
    return ", ".join([line, *(f"{n[state]} {word}" for state, word in words if n[state])])


def _trials_lacking(study: Any, settings: TuneSettings) -> int:
    """The trials the study still lacks of --trials, counted as workers count them (`run_worker`: finished means
    complete or pruned)."""
    n = retrying(functools.partial(counts, study), settings.storage.url, "reading the study")
    return settings.trials - n["COMPLETE"] - n["PRUNED"]


def tune_workers(study: Any, settings: TuneSettings) -> int:
    """The worker processes to start: --jobs, but no more than the trials the study still lacks; a worker beyond
    those would find no trial to run."""
    return worker_count(settings.jobs, _trials_lacking(study, settings))


def tune(settings: TuneSettings) -> Any:
    """Check everything, create (or join) the study, run the workers, and write the best preset and the summary."""
    from canter.orchestrate.job_resources import check_jobs, warn_if_more_jobs_than_cores
    from canter.orchestrate.jobs import exit_text, run_workers

    base, space = check_settings(settings)
    refuse_out_dir_in_a_run(settings.out_dir, "--out-dir")
    check_trackers(settings.track)  # a missing library or a bad --mlflow-uri, before any trial
    check_jobs(settings.jobs)  # before the study folder is made
    refuse_bench_folder(settings)
    # A refused command leaves no folder behind: neither the study folder nor the --out-dir above it, when it made
    # them and they still hold nothing.
    made = run_lock.missing_folders(settings.study_dir)
    try:
        if settings.storage_url is None:
            make_folder(settings.study_dir)  # the SQLite file's folder
        storage = open_storage(settings.storage)  # a bad URL fails here, before any worker starts
        if settings.storage_url is not None:
            make_folder(settings.study_dir)  # the trials' folders, once the storage is reached, before any trial
        study = make_study(settings, storage)
        trials_before = len(study.get_trials(deepcopy=False))  # one count for every worker's sampler seed
        wanted = study_settings(settings, base, space)
        check = functools.partial(check_study_settings, study, wanted, settings.study_dir / TRIALS_FOLDER)
        study = retrying(check, settings.storage.url, "reading the study")  # another command's, or other settings
    except BaseException:
        _remove_empty(made)
        raise
    if trials_before:
        print(
            retrying(
                functools.partial(progress_line, study, settings.trials), settings.storage.url, "reading the study"
            )
        )
    # The study's tracker group (MLflow's parent run) is made here, once, not by trials that start together.
    settings = replace(settings, track=open_groups(settings.track, [study_group(settings)]))
    workers = tune_workers(study, settings)
    warn_if_more_jobs_than_cores(settings.jobs, workers)
    write = functools.partial(
        retrying, functools.partial(write_results, study, settings), settings.storage.url, "reading the results"
    )
    failed = []
    try:
        if workers == 1:
            worker(settings, 0, trials_before)
        else:
            failed = run_workers(worker, [(settings, i, trials_before) for i in range(workers)], "canter-tune")
    except (CanterError, KeyboardInterrupt, OSError):  # a worker that gives up, a stop, or a stdout nobody reads
        write()  # what the study holds, in the files first
        raise
    # What the study holds is written even when a worker ended early: the others may have finished its trials.
    write()
    if failed and _trials_lacking(study, settings) <= 0:
        print(
            f"canter: note: {len(failed)} of {workers} tune workers ended early ({exit_text(failed[0])}), but the "
            f"others finished the study's {settings.trials} trials",
            file=sys.stderr,
        )
    elif failed:
        raise CanterError(
            f"{len(failed)} of {workers} tune workers ended early ({exit_text(failed[0])}; a worker's own "
            f"error, if it had one, is printed above); the summary above holds what the study has, and the same "
            f"command goes on with it"
        )
    return study


# ---------------------------------------------------------------------------------------------------- the report


def _short(key: str) -> str:
    return key.split(".", 1)[1] if "." in key else key


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def summary_table(study: Any, top: int = 10) -> str:
    """Counts by state, the best trials as a markdown table, and the reasons of failed trials."""
    from optuna.trial import TrialState

    n = counts(study)
    lines = [f"study '{study.study_name}': " + ", ".join(f"{v} {k.lower()}" for k, v in n.items() if v)]
    done = [t for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)) if t.value is not None]
    done.sort(key=lambda t: -t.value)
    if done:
        keys = list(done[0].params)
        lines += [
            "",
            "| trial | return | minutes | " + " | ".join(_short(k) for k in keys) + " |",
            "|---:|---:|---:|" + "---:|" * len(keys),
        ]
        for t in done[:top]:
            minutes = (t.datetime_complete - t.datetime_start).total_seconds() / 60 if t.datetime_start else math.nan
            lines.append(
                f"| {t.number} | {t.value:.1f} | {minutes:.1f} | "
                + " | ".join(_fmt(t.params.get(k)) for k in keys)
                + " |"
            )
    reasons: dict[str, int] = {}
    for t in study.get_trials(deepcopy=False, states=(TrialState.FAIL, TrialState.PRUNED)):
        reason = t.user_attrs.get(FAIL_REASON) or t.user_attrs.get("note")
        if t.state == TrialState.FAIL and not reason:
            reason = "worker died (heartbeat lost); a copy of the trial was retried"
        if reason and (t.state == TrialState.FAIL or reason.startswith("diverged")):
            reasons[reason] = reasons.get(reason, 0) + 1
    if reasons:
        lines += ["", "failed or diverged trials:"] + [f"- {count} x {reason}" for reason, count in reasons.items()]
    return "\n".join(lines)


def write_results(study: Any, settings: TuneSettings) -> Path | None:
    """Print the summary, and write it and the best trial's preset into the study folder."""
    from optuna.trial import TrialState

    from canter.files import write_output

    table = summary_table(study)
    summary = settings.study_dir / STUDY_SUMMARY_FILE
    write_output(summary, (table + "\n").encode())  # before the print, which fails where nothing reads stdout
    complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if not complete:
        print(table)
        print(f"summary written to {summary}; no trial completed, so there is no best preset yet")
        return None
    best = max(complete, key=lambda t: t.value)
    header = (
        f"canter tune: best trial {best.number} of study '{study.study_name}' ({len(complete)} complete)\n"
        f"objective {best.value:.2f}: deterministic evaluation return, mean over seeds "
        f"{seeds_text(settings.seeds)}; the best of {len(complete)} on the seeds that chose it, so it "
        f"overstates what the preset scores on new seeds\n"
        f"train with: canter train --config {BEST_FILE} --seed {max(settings.seeds) + 1}  (a seed the study did "
        f"not tune on; --seed {settings.seeds[0]} repeats the best trial's first run)"
    )
    body = best.user_attrs[PRESET_ATTR]
    path = settings.study_dir / BEST_FILE
    write_output(path, ("\n".join(f"# {line}" for line in header.splitlines()) + "\n" + body).encode())
    print(table)
    print(f"best trial {best.number}: return {best.value:.1f}; preset written to {path}, summary to {summary}")
    return path
