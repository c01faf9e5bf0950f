"""The host loop: build env and state, call the jitted iteration, and between calls log, checkpoint, show progress
and handle stop conditions and signals."""

from __future__ import annotations

import functools
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from os import PathLike
from pathlib import Path
from typing import Any, cast

import numpy as np

from canter.config.algorithms import budget_rounding_note, slow_call_note, warm_up_note
from canter.config.schema import Config
from canter.config.validate import validate
from canter.core.seeding import check_seed
from canter.envs.base import JaxVecEnv
from canter.errors import CanterError, DiscreteActionsError, DoesNotFitError
from canter.files import WriteError, is_write_error
from canter.run_layout import (
    CONFIG_FILE,
    SUMMARY_FILE,
    StopReason,
)
from canter.signals import StopFlag
from canter.training import checkpoint, device_memory, disk_room, host_memory, run_folder, run_lock
from canter.training.evaluation import check_episodes_end, evaluation_backend
from canter.training.group_program import (
    Chunk,
    GroupProgram,
    fewer_envs_when_out_of_device_memory,
    initial_state_program,
)
from canter.training.progress import Progress
from canter.training.resume import (
    Saved,
    check_one_group,
    check_same_experiment_and_seed,
    has_its_budget,
    need_a_run_to_resume,
    repair_config_of_a_finished_run,
    resume_config,
    saved_config,
    start_of_seed,
    start_over,
    summarize_if_it_ended,
    unreadable_config,
)
from canter.training.seed_run import RunResult, SeedRun, SeedStart

STOP_NOTICE = "stopping at the next safe point, with a checkpoint to resume from"
# A call of the jitted program this long gets a note: until it returns, a signal only waits (a td3 batch of 100,000
# makes a call of 1,000 updates last many minutes).
SLOW_CALL_SECONDS = 60.0


def train(
    config: Config, *, resume: str | Path | None = None, quiet: bool = True, run_dir: str | Path | None = None
) -> RunResult:
    """Train a policy. With `resume`, continue the newest checkpoint of that run folder; `config` may then differ
    in its budget: run.total_steps (the learning-rate schedule is stretched to the new total), run.max_minutes and
    run.stop_at_return, and in keys that do not change what is learned (outputs and bookkeeping,
    `canter.config.experiment`), but not in its seed or in what is learned."""
    _need_quiet(quiet)
    _need_a_config(config)
    need_a_folder(run_dir, "run_dir")
    need_a_folder(resume, "resume")
    if resume is not None and run_dir is not None:
        raise CanterError(
            "resume= goes on in the run's own folder, so run_dir= cannot be given with it; drop run_dir= (or copy "
            "the run folder first, and resume the copy)"
        )
    if resume is not None:
        need_a_run_to_resume(Path(resume))  # before the setup, which takes seconds
    if resume is not None and has_its_budget(Path(resume), config):
        check_same_experiment_and_seed(saved_config(Path(resume), note=False), config, Path(resume))
        if (summarized := summarize_if_it_ended(Path(resume))) is not None:
            return summarized
        if (repaired := repair_config_of_a_finished_run(Path(resume))) is not None:
            return repaired
    return _train_group([config], [resume], [run_dir], quiet)[0]


def train_seeds(
    config: Config, seeds: Sequence[int], *, quiet: bool = True, run_dirs: Sequence[str | Path] | None = None
) -> list[RunResult]:
    """Train one run per seed in a single vmapped program (see canter.training.seedgroup); `config.run.seed` is
    replaced by each seed. Every seed writes its own run folder, the same as `train(config with that seed)` would, and
    follows the same curve up to floating-point reassociation. Results are in the order of `seeds`."""
    _need_quiet(quiet)
    _need_a_config(config)
    seeds = _checked_seeds(seeds)
    if not seeds:
        raise CanterError("no seeds given; pass at least one, e.g. --seeds 0,1,2 (seeds=[0, 1, 2] from Python)")
    if len(set(seeds)) != len(seeds):
        raise CanterError(f"seeds repeat in {seeds}; each seed of a group must be different")
    if run_dirs is not None:
        _need_folders(run_dirs)
    if run_dirs is not None and len(run_dirs) != len(seeds):
        raise CanterError(f"{len(run_dirs)} run folders given for {len(seeds)} seeds")
    configs = [config.with_values("run", seed=seed) for seed in seeds]
    dirs: list[str | Path | None] = list(run_dirs) if run_dirs is not None else [None] * len(seeds)
    return _train_group(configs, [None] * len(seeds), dirs, quiet)


def _need_quiet(quiet: object) -> None:
    if not isinstance(quiet, bool | np.bool_):  # a string such as "no" would read as true
        raise CanterError(f"quiet must be True or False, got {quiet!r}")


def _need_a_config(config: object) -> None:
    """Anything else given as the config (a dict of settings, an env id) would fail deep in the trainer."""
    if isinstance(config, Config):
        return
    built = f"canter.build_config({config!r})" if isinstance(config, str) else 'canter.build_config("Pendulum-v1")'
    raise CanterError(
        f"config must be a canter Config, got {type(config).__name__}; build one with {built} (settings go in its "
        'sets=["section.key=value"])'
    )


def need_a_folder(folder: object, name: str, optional: bool = True) -> None:
    """An empty path reads as the working folder, which a run would fill with its files (or resume by chance).
    `optional`: the argument may be left out (None), which the fix then offers."""
    if folder is None and optional:
        return
    if not isinstance(folder, str | PathLike):
        raise CanterError(f"{name}= must be a folder path (str or Path), got {type(folder).__name__}")
    if not str(folder).strip():
        leave = ", or leave it out" if optional else ""
        raise CanterError(f"{name}= is empty, which would be the working folder; give a run folder{leave}")


def _need_folders(run_dirs: object) -> None:
    if isinstance(run_dirs, str | bytes | PathLike) or not isinstance(run_dirs, Sequence):
        raise CanterError(f"run_dirs= must be a list of folders, one per seed, got {run_dirs!r}")
    for folder in run_dirs:
        need_a_folder(folder, "run_dirs")


def _checked_seeds(seeds: object) -> list[int]:
    """Seeds are a list, tuple, range or 1-d array of whole numbers: the keys of a dict or the digits of a string
    would train other seeds than meant."""
    listed = isinstance(seeds, Sequence) and not isinstance(seeds, str | bytes)
    if not (listed or (isinstance(seeds, np.ndarray) and seeds.ndim == 1)):
        count = isinstance(seeds, int) and not isinstance(seeds, bool) and seeds > 0
        hint = f"; for {seeds} seeds pass range({seeds})" if count else ""
        raise CanterError(f"seeds must be a list of whole numbers, e.g. [0, 1, 2], got {seeds!r}{hint}")
    return [check_seed(s) for s in cast(Sequence[object], seeds)]


def resume_seeds(
    run_dirs: Sequence[str | Path],
    total_steps: int | None = None,
    *,
    max_minutes: float | None = None,
    stop_at_return: float | None | Saved = Saved.KEEP,
    quiet: bool = True,
) -> list[RunResult]:
    """Resume several run folders together as one group. Their saved configs must be equal apart from run.seed
    (as the folders of one `train_seeds` group are); each continues from its own newest checkpoint exactly as it
    would resumed alone. Any folder can also be resumed alone with `train(..., resume=folder)`. A folder that has
    its budget already (a seed of the group that finished before a signal stopped the others) is left out with a
    note; the results are those of the folders resumed."""
    _need_quiet(quiet)
    _need_folders(run_dirs)
    if not run_dirs:
        raise CanterError(
            "run_dirs= is empty; pass the run folders to resume, e.g. the run_dir of each train_seeds result"
        )
    configs = [resume_config(Path(d), total_steps, max_minutes, stop_at_return) for d in run_dirs]
    # Checked before the seeds: two runs of different experiments repeat seeds too, which would hide the cause.
    check_one_group(run_dirs, configs)
    finished = [has_its_budget(Path(d), c) for d, c in zip(run_dirs, configs)]
    summarized = [
        summarize_if_it_ended(Path(d)) or repair_config_of_a_finished_run(Path(d))
        for d, done in zip(run_dirs, finished)
        if done
    ]
    if all(finished) and any(summarized):  # what was left to do is done; a finished run is refused only otherwise
        return [result for result in summarized if result is not None]
    if len(run_dirs) > 1 and any(finished) and not all(finished):
        for run_dir in (d for d, done in zip(run_dirs, finished) if done):
            print(
                f"canter: note: {run_dir} already has its run.total_steps; the others resume without it",
                file=sys.stderr,
            )
        run_dirs = [d for d, done in zip(run_dirs, finished) if not done]
        configs = [c for c, done in zip(configs, finished) if not done]
    return _train_group(configs, list(run_dirs), [None] * len(configs), quiet)


def _train_group(configs: list[Config], resumes: list[Any], run_dirs: list[Any], quiet: bool) -> list[RunResult]:
    """Train len(configs) seeds (configs equal but for run.seed) together; one seed runs without vmap. Each run
    folder's writer lock (`canter.training.run_lock`) is held throughout."""
    with run_lock.RunLocks() as locks:
        return _train_locked(configs, resumes, run_dirs, quiet, locks)


def _train_locked(
    configs: list[Config], resumes: list[Any], run_dirs: list[Any], quiet: bool, locks: run_lock.RunLocks
) -> list[RunResult]:
    try:
        return _train_checked(configs, resumes, run_dirs, quiet, locks)
    except DoesNotFitError as exc:
        resumed = [Path(resume) for resume in resumes if resume is not None]
        if not resumed:
            raise
        raise exc.for_a_resume(resumed[0] / CONFIG_FILE) from None  # --resume refuses --set


def _train_checked(
    configs: list[Config], resumes: list[Any], run_dirs: list[Any], quiet: bool, locks: run_lock.RunLocks
) -> list[RunResult]:
    from canter.algos import get_algorithm
    from canter.core.runtime import announce_physics, setup_jax
    from canter.envs import resolve_backend
    from canter.envs.registry import note_replay, refuse_mujoco_py_replay

    backend = resolve_backend(configs[0].env.id, configs[0].env.backend)
    setup_jax(backend, announce=False)
    for config in configs:
        validate(config)
    algorithm = get_algorithm(configs[0].run.algo)  # before a folder is made
    played = evaluation_backend(configs[0].env.id, configs[0].run.eval_backend, backend)  # before a folder is made
    if configs[0].run.video_every and all(resume is None for resume in resumes):  # a resume cannot change its config
        refuse_mujoco_py_replay(  # the videos play on the single-env backend
            configs[0].env.id,
            "run.video_every renders its videos",
            "drop --video-every (run.video_every), or train {newer} instead",
        )
    if configs[0].run.eval_every:
        check_episodes_end(configs[0].env.id, played, instead=", or train without --eval-every (run.eval_every=0)")
    _check_resources(configs, backend)  # before a folder is made, and before the envs' seed lists are
    # The notes after the checks that refuse a run on its settings alone, so that such a refusal stays one line.
    announce_physics(backend)
    if configs[0].run.eval_every:
        announce_physics(played)
    note_replay(configs[0].env.id, backend, played)
    started = time.perf_counter()
    # From the moment a run folder exists, SIGINT and SIGTERM stop the run with a checkpoint to resume from: one
    # that lands during setup or compilation stops it before its first iteration.
    with StopFlag(notice=STOP_NOTICE) as stop:
        starts = _start_seeds(configs, resumes, run_dirs, backend, locks)
        env = None
        try:
            seeds = [seed for config, start in zip(configs, starts) for seed in start.env_seeds(config)]
            env = _make_env(configs[0], backend, seeds)
            spec = replace(env.spec, num_envs=configs[0].env.num_envs)  # what one seed sees
            algorithm.validate(configs[0], spec)
            if all(start.state is None for start in starts):  # a resumed state was checked when its run started
                host_memory.check_state_fits(algorithm, configs[0], spec, len(configs), device_memory.free_bytes())
            # Each checkpoint of a JAX env also holds its envs' state, the episodes in flight.
            jax_env = isinstance(env, JaxVecEnv)
            carry_bytes = disk_room.state_bytes(env.state_shapes()) // len(configs) if jax_env else 0
            initial_state = initial_state_program(algorithm, configs[0], spec)
            states = [_prepare_seed(config, start, initial_state) for config, start in zip(configs, starts)]
            run_dirs = [start.run_dir for start in starts]
            leaves_out = algorithm.policy_checkpoint_leaves_out
            disk_room.warn_if_checkpoints_will_not_fit(run_dirs, states, configs[0], leaves_out, carry_bytes)
            # The resumed states read from the checkpoints live on in `states` alone (a replay buffer twice over
            # for the whole run otherwise).
            starts = [replace(start, state=None) for start in starts]
            with fewer_envs_when_out_of_device_memory(configs[0].env.num_envs):  # the first reset of JAX envs
                carry = _initial_carry(env, spec, [start.resumed_from for start in starts])
            return _loop(configs, algorithm, env, spec, states, carry, starts, quiet, started, stop)
        except (CanterError, OSError) as exc:  # a full disk or unwritable folder: one line, and how to go on
            if isinstance(exc, CanterError):
                _discard_new_runs(starts)
            error = training_write_error(exc, [start.run_dir for start in starts])
            if error is None:
                raise
            raise error from None
        finally:
            if env is not None:
                env.close()


def _start_seeds(
    configs: list[Config], resumes: list[Any], run_dirs: list[Any], backend: str, locks: run_lock.RunLocks
) -> list[SeedStart]:
    """Each seed's start, its folder locked (and a new run's folder made); the folders of the seeds before one that is
    refused are left as they were found."""
    starts: list[SeedStart] = []
    try:
        for config, resume, run_dir in zip(configs, resumes, run_dirs):
            starts.append(start_of_seed(config, resume, run_dir, backend, locks))
    except (CanterError, OSError):
        _discard_new_runs(starts)
        raise
    return starts


def _discard_new_runs(starts: list[SeedStart]) -> None:
    """A new folder that holds no checkpoint and no row goes; a restarted run keeps its config to resume again."""
    for start in starts:
        if not (start.resumed or start.restarted):
            run_folder.discard_unstarted(start.run_dir)


def _check_resources(configs: list[Config], backend: str) -> None:
    """Refuse a group that the process's open files or the machine's memory cannot hold, before anything is made:
    the list of env seeds alone grows with the envs."""
    from canter.envs.registry import env_options, get_backend

    run_lock.check_open_files(len(configs))
    env = configs[0].env
    options = env_options(env, backend)
    chosen = get_backend(backend)
    if chosen.jax_native:  # sized from one env's shapes; the compiled program is checked as well
        one_env = functools.partial(_one_env_state_bytes, chosen, env.id, options)
        host_memory.check_jax_envs_fit(one_env, env.num_envs, len(configs), device_memory.free_bytes())
    else:
        host_memory.check_envs_fit(env.id, backend, options, env.num_envs, len(configs))


def _one_env_state_bytes(backend: Any, env_id: str, options: dict[str, Any]) -> int:
    """The memory one env's state takes on a JAX backend, from its shapes (the env is never reset)."""
    env = backend.make(env_id, 1, [0], **options)
    assert isinstance(env, JaxVecEnv)
    return env.state_bytes()


def _make_env(config: Config, backend: str, seeds: list[int]) -> Any:
    """The group's vector env: one env per seed in `seeds`, the seeds of a group one block after another."""
    from canter.envs import make_vec_env
    from canter.envs.registry import env_options

    options = env_options(config.env, backend)
    try:
        return make_vec_env(config.env.id, backend, len(seeds), seeds, config.env.envpool_shards, **options)
    except DiscreteActionsError as exc:
        raise CanterError(
            f"{config.run.algo} is continuous-only, but {exc.env_id} has discrete actions "
            f"({exc.space}); choose an env with Box actions"
        ) from None


def _prepare_seed(config: Config, start: SeedStart, initial_state: Callable[[int], Any]) -> Any:
    """Migrate a resumed seed's run folder (a new one was made as it was locked), and return the state it trains
    from: its checkpoint's, or `initial_state(seed)`."""
    state = start.state if start.state is not None else initial_state(config.run.seed)
    start.run_dir.mkdir(parents=True, exist_ok=True)
    if start.restarted:
        start_over(start.run_dir)
    if start.resumed:
        # A damaged config.toml is replaced before the migrations, which read it. The resume's own budget is written
        # once its program is known to fit (`_open_seeds`): a refused resume leaves the run's config as it was.
        if unreadable_config(start.run_dir):
            run_folder.write_config(start.run_dir, config)
        run_folder.migrate(start.run_dir)
    return state


def training_write_error(exc: BaseException, run_dirs: list[Path]) -> WriteError | None:
    """A write error that stopped training (None for any other exception), with the fix that continues it:
    `canter train --resume` of the run folders when each holds a checkpoint, else training again."""
    if isinstance(exc, WriteError):
        error = exc
    elif is_write_error(exc):
        assert isinstance(exc, OSError)
        error = WriteError(exc.filename or run_dirs[0], exc)
    else:
        return None
    if error.path.name == SUMMARY_FILE:  # written after the final checkpoint: nothing is left to train
        return error.resumable("use the run as it is (training finished and its last checkpoint is saved)")
    folders = [str(d) for d in run_dirs]
    resume = f"`canter train --resume {' '.join(folders)}` (canter.resume_seeds({folders!r}) from Python)"
    if all(run_folder.list_checkpoints(d) for d in run_dirs):
        return error.resumable(resume)
    if all((d / CONFIG_FILE).is_file() for d in run_dirs):
        # Training the same command again would leave this folder behind and start another.
        return error.resumable(f"{resume}, which trains a run without a checkpoint again from step 0 in its folder")
    return error.resumable("train again (no checkpoint was written to resume from)")


def _initial_carry(env: Any, spec: Any, resumed_from: list[Path | None]) -> Any:
    """The env loop's first carry: fresh episodes, or for a backend whose env state is a pytree, the episodes in
    flight that each resumed seed's checkpoint holds. Seeds of a group are stacked on a leading axis."""
    from canter.envs.episodes import init_env_carry
    from canter.training import seedgroup

    group = len(resumed_from)
    first_obs = seedgroup.split_first_obs(env.reset(), group)
    if group > 1 and isinstance(env, JaxVecEnv):
        handles = seedgroup.split_env_state(env.initial_state(), group)
    else:
        handles = [env.initial_state()] * group
    carries = [init_env_carry(handle, obs, spec.info_keys) for handle, obs in zip(handles, first_obs)]
    if isinstance(env, JaxVecEnv):
        carries = [
            checkpoint.restore_env_carry(fresh, path) if path is not None else fresh
            for fresh, path in zip(carries, resumed_from)
        ]
    return carries[0] if group == 1 else seedgroup.stack(carries)


def _loop(
    configs: list[Config],
    algorithm: Any,
    env: Any,
    spec: Any,
    states: list[Any],
    carry: Any,
    starts: list[SeedStart],
    quiet: bool,
    started: float,
    stop: StopFlag,
) -> list[RunResult]:
    """The host loop of a group. Every seed logs, checkpoints and stops on its own (budget, stop_at_return, a
    non-finite iteration); max_minutes and signals stop the whole group. A seed that is done keeps being computed
    inside the vmapped program until the last seed is done, but nothing of it is kept."""
    config = configs[0]
    program = GroupProgram(config, algorithm, spec, env, states, carry)
    # A group's program holds the seeds' states stacked: their own copies would double its memory for the whole run.
    states.clear()
    runs = _open_seeds(configs, spec, starts, program, started, stop)
    label = f"{spec.id} {config.run.algo}" + (f" x{program.group} seeds" if program.group > 1 else "")
    progress = Progress(config.run.total_steps, min(start.step for start in starts), quiet, label)
    deadline = started + config.run.max_minutes * 60 if config.run.max_minutes else None
    slow_call_noted = False
    try:
        if stop.signal is not None:  # it came during setup or compilation
            _stop_before_training(program, runs, starts)
        # SIGINT and SIGTERM stop the run at the next iteration boundary, with a checkpoint written.
        while any(run.stop_reason is None for run in runs):
            chunk = program.call(runs)
            slow_call_noted = slow_call_noted or _note_a_slow_call(config, chunk.elapsed, stop)
            steps = 0
            for i, run in enumerate(runs):
                if run.stop_reason is None:
                    steps += _take_share(program, i, run, chunk)
            program.advance(chunk)
            _stop_seeds(program, runs, _group_stop_reason(deadline, stop))
            _show_progress(progress, runs, steps / chunk.elapsed)
    finally:
        _close(progress, runs)
    return _results(runs)


def _close(progress: Progress, runs: list[SeedRun]) -> None:
    """Close the progress bar, then each seed's files and tracker runs, also where the bar's close fails (a second
    Ctrl-C landing in it): the bar is only shown, and a seed left open can lose its last TensorBoard events and leaves
    its tracker runs running."""
    try:
        progress.close()
    finally:
        for run in runs:
            run.close()


def _open_seeds(
    configs: list[Config],
    spec: Any,
    starts: list[SeedStart],
    program: GroupProgram,
    started: float,
    stop: StopFlag,
) -> list[SeedRun]:
    """Each seed's host side, then the group's program compiled (not when a signal has already stopped the run). A
    seed's setup or the compile failing still closes what the seeds before it opened (tracker runs)."""
    runs: list[SeedRun] = []
    try:
        group_seeds = tuple(c.run.seed for c in configs)
        for config, start in zip(configs, starts):
            runs.append(SeedRun(config, spec, start, program.algorithm.metric_names, group_seeds, started))
        if stop.signal is not None:  # stopped during setup: nothing will run
            compile_seconds = 0.0
        else:
            compile_seconds = program.compile(runs)
            # After every check that can refuse the run, so that a refusal stays one line.
            for note in (warm_up_note(configs[0]), budget_rounding_note(configs[0])):
                if note is not None:
                    print(f"canter: note: {note}", file=sys.stderr)
        for config, start in zip(configs, starts):
            if start.resumed:  # its new budget, which a later resume of the run goes on to
                run_folder.write_config(start.run_dir, config)
        for run in runs:
            run.compile_seconds = compile_seconds
    except BaseException:
        for run in runs:
            run.close()
        raise
    return runs


def _stop_before_training(program: GroupProgram, runs: list[SeedRun], starts: list[SeedStart]) -> None:
    """A signal during setup or compilation: a new seed saves its initial state, so that its folder resumes; a
    resumed seed keeps its newest checkpoint as it is. Both write summary.json, which says a signal stopped them."""
    # What only further training reads (a replay buffer) is still all zeros, as reading it back gives it: leaving it
    # out spares a Ctrl-C from writing gigabytes of zeros.
    empty = program.algorithm.policy_checkpoint_leaves_out
    for i, (run, start) in enumerate(zip(runs, starts)):
        # A resumed seed may have met its return target already.
        reason = run.stop_reason_after(StopReason.SIGNAL) or StopReason.SIGNAL
        if start.resumed:
            run.finish_untrained(reason)
        else:
            run.finish(program.pick(program.state, i), reason, program.env_carry(program.carry, i), untrained_but=empty)


def _take_share(program: GroupProgram, i: int, run: SeedRun, chunk: Chunk) -> int:
    """Seed i's share of an iteration: its metrics.csv row (with an evaluation when one is due), then a video and a
    checkpoint when due; a non-finite iteration stops the seed instead. Returns the env steps it adds to the group's
    SPS."""
    metrics = program.pick(chunk.metrics, i)
    if not bool(metrics["finite"]):
        # A donated state is gone; such an algorithm returns the last good state itself.
        last_good = chunk.state if program.algorithm.donate_state else program.state
        run.fail(program.pick(last_good, i), program.env_carry(program.carry, i))
        return 0
    row = run.record(metrics, int(program.pick(chunk.iterations, i)), chunk.elapsed)
    if run.evaluation_due():
        row.update(run.evaluate(program.pick(chunk.state, i)))
    run.logger.log(row)
    run.trackers.log(row)
    # The video's snapshot before the checkpoint: a resume from this checkpoint renders a snapshot of its step that
    # the process left, but records none of steps up to it. Seed i's part of the state is picked only when one is due.
    run.videos.snapshot_if_due(run.global_step, lambda path: run.save_snapshot(path, program.pick(chunk.state, i)))
    if run.checkpoint_due():
        run.save_periodic(program.pick(chunk.state, i), program.env_carry(chunk.carry, i))
    run.videos.render_snapshot()
    return int(metrics["steps"])


def _note_a_slow_call(config: Config, seconds: float, stop: StopFlag) -> bool:
    """A call that takes SLOW_CALL_SECONDS or more is noted, and from then on a stop's notice says how long it will
    wait. Returns whether it noted one, as the run notes only the first."""
    if seconds < SLOW_CALL_SECONDS:
        return False
    print(f"canter: note: {slow_call_note(config, seconds)}", file=sys.stderr)
    stop.notice = (
        f"stopping when the current call ends (each takes about {seconds:,.0f} s), with a checkpoint to resume from"
    )
    return True


def _group_stop_reason(deadline: float | None, stop: StopFlag) -> str | None:
    """What stops every seed after this iteration: the wall-minute limit, else a signal."""
    if deadline is not None and time.perf_counter() >= deadline:
        return StopReason.MAX_MINUTES
    if stop.signal is not None:
        return StopReason.SIGNAL
    return None


def _stop_seeds(program: GroupProgram, runs: list[SeedRun], group_reason: str | None) -> None:
    """Finish, with a final checkpoint and summary, each seed still training that is done after this iteration."""
    for i, run in enumerate(runs):
        if run.stop_reason is None and (reason := run.stop_reason_after(group_reason)) is not None:
            run.finish(program.pick(program.state, i), reason, program.env_carry(program.carry, i))


def _show_progress(progress: Progress, runs: list[SeedRun], sps: float) -> None:
    """The bar follows the seed furthest behind among those still training."""
    active = [run for run in runs if run.stop_reason is None] or runs
    recents = [run.recent_mean for run in runs if run.recent_mean is not None]
    progress.update(min(run.global_step for run in active), sps, float(np.mean(recents)) if recents else None)


def _results(runs: list[SeedRun]) -> list[RunResult]:
    """Each seed's result; a seed that failed makes the group's error instead, which says how the others stopped."""
    failed = [run for run in runs if run.error is not None]
    if failed:
        if len(runs) == 1:
            raise CanterError(failed[0].error)
        others = [run for run in runs if run.error is None]
        tail = "; ".join(f"seed {run.config.run.seed} stopped: {run.stop_reason}" for run in others)
        raise CanterError(
            "; ".join(f"seed {run.config.run.seed}: {run.error}" for run in failed) + (f"; {tail}" if tail else "")
        )
    results = [run.result for run in runs if run.result is not None]
    assert len(results) == len(runs), "a seed that did not fail has finished"
    return results
