"""The host loop: build env and state, call the jitted iteration, and between calls log, checkpoint, show progress
and handle stop conditions and signals."""

from __future__ import annotations

import json
import math
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from datetime import datetime
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np

from canter.config.algorithms import budget_rounding_note
from canter.config.schema import Config
from canter.config.serialize import to_toml
from canter.config.validate import validate
from canter.core.seeding import RESUME, TRAIN, env_seeds
from canter.errors import CanterError, DiscreteActionsError
from canter.files import WriteError, atomic_write_bytes, is_write_error
from canter.signals import StopFlag
from canter.training import checkpoint, device_memory, disk_room, host_memory, run_folder, run_lock, trackers
from canter.training.evaluation import DURING_TRAINING_SEED, TrainingEvaluation, evaluation_backend
from canter.training.logger import MetricsLogger, Progress, logged, totals_until
from canter.training.videos import TrainingVideos

RECENT_EPISODES = 20


@dataclass(frozen=True)
class RunResult:
    run_dir: Path
    global_step: int
    recent_return: float | None  # mean raw return of the last 20 training episodes
    episodes: int
    wall_seconds: float  # the whole run, compile and earlier sessions of a resumed run included
    compile_seconds: float  # this session's compile
    sps: float  # env steps per second over the whole run, compile excluded
    stop_reason: str  # budget | stop_at_return | max_minutes | signal
    # The seeds of the process that trained its last session (itself alone, or its vmapped group); None unknown.
    trained_with: tuple[int, ...] | None = None


class Saved(Enum):
    """A budget key left as the run folder saved it."""

    KEEP = "keep"


def _env_header(spec: Any) -> dict[str, Any]:
    return {
        "id": spec.id,
        "backend": spec.backend,
        "obs_dim": spec.obs_dim,
        "act_dim": spec.act_dim,
        "action_low": list(spec.action_low),
        "action_high": list(spec.action_high),
        "max_episode_steps": spec.max_episode_steps,
        "info_keys": list(spec.info_keys),
    }


def train(
    config: Config, *, resume: str | Path | None = None, quiet: bool = True, run_dir: str | Path | None = None
) -> RunResult:
    """Train a policy. With `resume`, continue the newest checkpoint of that run folder; `config` may then only
    differ in its budget: run.total_steps (the learning-rate schedule is stretched to the new total) and
    run.max_minutes."""
    return _train_group([config], [resume], [run_dir], quiet)[0]


def train_seeds(
    config: Config, seeds: Sequence[int], *, quiet: bool = True, run_dirs: Sequence[str | Path] | None = None
) -> list[RunResult]:
    """Train one run per seed in a single vmapped program (see canter.training.seedgroup); `config.run.seed` is
    replaced by each seed. Every seed writes its own run folder, the same as `train(config with that seed)` would, and
    follows the same curve up to floating-point reassociation. Results are in the order of `seeds`."""
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise CanterError("no seeds given; pass at least one, e.g. --seeds 0,1,2")
    if len(set(seeds)) != len(seeds):
        raise CanterError(f"seeds repeat in {seeds}; each seed of a group must be different")
    if run_dirs is not None and len(run_dirs) != len(seeds):
        raise CanterError(f"{len(run_dirs)} run folders given for {len(seeds)} seeds")
    configs = [replace(config, run=replace(config.run, seed=seed)) for seed in seeds]
    dirs: list[str | Path | None] = list(run_dirs) if run_dirs is not None else [None] * len(seeds)
    return _train_group(configs, [None] * len(seeds), dirs, quiet)


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
    configs = [resume_config(Path(d), total_steps, max_minutes, stop_at_return) for d in run_dirs]
    seeds = [c.run.seed for c in configs]
    if len(set(seeds)) != len(seeds):
        raise CanterError(
            f"the run folders to resume together have repeated seeds {seeds}; a group needs distinct seeds"
        )
    reference = replace(configs[0].run, seed=0)
    for run_dir, config in zip(run_dirs, configs):
        if replace(config, run=replace(config.run, seed=0)) != replace(configs[0], run=reference):
            raise CanterError(
                f"{run_dir} has a config that differs from {run_dirs[0]} in more than run.seed; resume "
                f"folders with different configs one at a time"
            )
    finished = [_has_its_budget(Path(d), c) for d, c in zip(run_dirs, configs)]
    if len(run_dirs) > 1 and any(finished) and not all(finished):
        for run_dir in (d for d, done in zip(run_dirs, finished) if done):
            print(
                f"canter: note: {run_dir} already has its run.total_steps; the others resume without it",
                file=sys.stderr,
            )
        run_dirs = [d for d, done in zip(run_dirs, finished) if not done]
        configs = [c for c, done in zip(configs, finished) if not done]
    return _train_group(configs, list(run_dirs), [None] * len(configs), quiet)


def _check_only_the_budget_differs(saved: Config, config: Config, run_dir: Path) -> None:
    """A resume continues the run it finds: a config that differs in what is learned (`canter.config.experiment`)
    would train another experiment on its state."""
    from canter.config.experiment import differing_keys

    differing = [key for key in differing_keys([saved, config]) if key != "run.seed"]
    if saved.run.seed != config.run.seed:
        differing.insert(0, "run.seed")
    if differing:
        raise CanterError(
            f"the config to resume {run_dir} with differs from the run's in {', '.join(differing)}; a resume may "
            f"change only its budget (run.total_steps, run.max_minutes, run.stop_at_return): use resume_config"
        )


def _has_its_budget(run_dir: Path, config: Config) -> bool:
    newest = checkpoint.list_checkpoints(run_dir)
    return bool(newest) and int(checkpoint.read_header(newest[-1]).get("global_step", 0)) >= config.run.total_steps


def _train_group(configs: list[Config], resumes: list[Any], run_dirs: list[Any], quiet: bool) -> list[RunResult]:
    """Train len(configs) seeds (configs equal but for run.seed) together; one seed runs without vmap. Each run
    folder's writer lock (`canter.training.run_lock`) is held throughout."""
    with run_lock.RunLocks() as locks:
        return _train_locked(configs, resumes, run_dirs, quiet, locks)


def _write_summary(result: RunResult) -> dict[str, Any]:
    summary = {k: (str(v) if isinstance(v, Path) else v) for k, v in result.__dict__.items()}
    atomic_write_bytes(
        result.run_dir / run_folder.SUMMARY_FILE, lambda f: f.write(json.dumps(summary, indent=2).encode())
    )
    return summary


def summarize_ended_run(run_dir: Path) -> RunResult:
    """Write summary.json of a run whose final checkpoint was saved but whose summary was not (a full disk, or a kill
    between the two writes), from that checkpoint's header: the run then reads as finished, as it is."""
    from canter.config.serialize import from_toml_text

    newest = checkpoint.latest(run_dir)
    header = checkpoint.read_header(newest)
    step = int(header["global_step"])
    totals = header.get("totals") or totals_until(run_folder.metrics_file(run_dir), step)
    recent = totals.get("recent_returns") or []
    train_seconds = float(totals.get("train_seconds", 0.0))
    config = from_toml_text(header["config"], str(newest))
    target = config.run.stop_at_return
    reached = target is not None and bool(recent) and float(np.mean(recent)) >= target
    result = RunResult(
        run_dir=Path(run_dir),
        global_step=step,
        recent_return=float(np.mean(recent)) if recent else None,
        episodes=int(totals.get("episodes", 0)),
        wall_seconds=float(totals.get("wall_seconds", 0.0)),
        compile_seconds=float(totals.get("compile_seconds", 0.0)),
        sps=step / train_seconds if train_seconds > 0 else 0.0,
        stop_reason="stop_at_return" if reached else "budget",  # the loop's order: the target, then the budget
    )
    summary = _write_summary(result)
    trackers.open_for_run(config, Path(run_dir), resumed=True).finish(Path(run_dir), summary)
    return result


def _note_a_changed_backend(out: Path, recorded: str, backend: str, start_step: int) -> None:
    """`env.backend = auto` picks what this machine has, which can differ from what the run started on: say so."""
    if recorded != backend:
        print(
            f"canter: note: {out} was trained on {recorded} up to step {start_step:,}; env.backend=auto picks "
            f"{backend} here, which steps it from now on (install {recorded} to keep one backend)",
            file=sys.stderr,
        )


def _train_locked(
    configs: list[Config], resumes: list[Any], run_dirs: list[Any], quiet: bool, locks: run_lock.RunLocks
) -> list[RunResult]:
    from canter.algos import get_algorithm
    from canter.core.runtime import setup_jax
    from canter.envs import resolve_backend
    from canter.envs.registry import note_replay

    backend = resolve_backend(configs[0].env.id, configs[0].env.backend)
    setup_jax(backend)
    for config in configs:
        validate(config)
    played = evaluation_backend(configs[0].env.id, configs[0].run.eval_backend, backend)  # before a folder is made
    note_replay(configs[0].env.id, backend, played)
    started = time.perf_counter()

    starts = [_start_of(c, resume, run_dir, backend, locks) for c, resume, run_dir in zip(configs, resumes, run_dirs)]
    seeds = [seed for config, start in zip(configs, starts) for seed in start.env_seeds(config)]
    env = _make_env(configs[0], backend, seeds)
    spec = replace(env.spec, num_envs=configs[0].env.num_envs)  # what one seed sees
    algorithm = get_algorithm(configs[0].run.algo)
    try:
        algorithm.validate(configs[0], spec)
        states = [_prepare_seed(config, start, algorithm, spec) for config, start in zip(configs, starts)]
        carry = _initial_carry(env, spec, [start.resumed_from for start in starts])
        return _loop(configs, algorithm, env, spec, states, carry, starts, quiet, started)
    except (CanterError, OSError) as exc:  # a full disk or unwritable folder: one line, and how to go on
        error = training_write_error(exc, [start.out for start in starts])
        if error is None:
            raise
        raise error from None
    finally:
        env.close()


@dataclass(frozen=True)
class _SeedStart:
    """Where one seed of a group starts: its run folder and, for a resume, what its newest checkpoint holds."""

    out: Path
    state: Any = None  # None: the algorithm's initial state
    step: int = 0
    # Wall seconds, training seconds, episodes and recent returns of the sessions before a resume; None: a new run.
    earlier: dict[str, Any] | None = None
    resumed_from: Path | None = None  # the checkpoint

    @property
    def resumed(self) -> bool:
        return self.resumed_from is not None

    def env_seeds(self, config: Config) -> list[int]:
        """Exactly the seeds its single-seed run would give its envs, wherever it sits in the group."""
        purpose, salt = (RESUME, self.step) if self.resumed else (TRAIN, 0)
        return env_seeds(config.run.seed, config.env.num_envs, purpose, salt)


def _start_of(config: Config, resume: Any, run_dir: Any, backend: str, locks: run_lock.RunLocks) -> _SeedStart:
    """Take one seed's run folder and, for a resume, read its newest checkpoint; refuse a run that has its budget."""
    if resume is not None:
        from canter.training.restore import load_state

        out = Path(resume)
        locks.take(out)  # before its newest checkpoint is read: another writer may be finishing it
        latest = checkpoint.latest(out)
        saved, _, state, header = load_state(out, latest)
        _check_only_the_budget_differs(saved, config, out)
        step = int(header["global_step"])
        _note_a_changed_backend(out, header["env"]["backend"], backend, step)
        earlier = header.get("totals") or totals_until(run_folder.metrics_file(out), step)
        start = _SeedStart(out, state, step, earlier, latest)
    else:
        start = _SeedStart(Path(run_dir) if run_dir is not None else run_folder.new_run_dir(config))
    if start.step >= config.run.total_steps:
        raise CanterError(
            f"{start.out} already has {start.step} of run.total_steps={config.run.total_steps} "
            f"steps; pass --total-steps larger than {start.step} to extend it"
        )
    if resume is None:
        locks.take(start.out)  # before anything is written to it
    return start


def _make_env(config: Config, backend: str, seeds: list[int]) -> Any:
    """The group's vector env: one env per seed in `seeds`, the seeds of a group one block after another."""
    from canter.envs import make_vec_env
    from canter.envs.registry import env_options, get_backend

    options = env_options(config.env, backend)
    try:
        if not get_backend(backend).jax_native:  # JAX envs are checked on the compiled program instead
            host_memory.check_envs_fit(config.env.id, backend, options, len(seeds))
        return make_vec_env(config.env.id, backend, len(seeds), seeds, config.env.envpool_shards, **options)
    except DiscreteActionsError as exc:
        raise CanterError(
            f"{config.run.algo} is continuous-only, but {exc.env_id} has discrete actions "
            f"({exc.space}); choose an env with Box actions"
        ) from None


def _prepare_seed(config: Config, start: _SeedStart, algorithm: Any, spec: Any) -> Any:
    """Make (or migrate) the seed's run folder with this config, and return the state it trains from."""
    state = start.state if start.state is not None else algorithm.init_state(config, spec)
    start.out.mkdir(parents=True, exist_ok=True)
    if start.resumed:
        run_folder.migrate(start.out)
        run_folder.write_config(start.out, config)
    else:
        run_folder.create(start.out, config)
    disk_room.warn_if_checkpoints_will_not_fit(start.out, state, config, algorithm.policy_checkpoint_leaves_out)
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
    if error.path.name == run_folder.SUMMARY_FILE:  # written after the final checkpoint: nothing is left to train
        return error.resumable("use the run as it is (training finished and its last checkpoint is saved)")
    if all(checkpoint.list_checkpoints(d) for d in run_dirs):
        return error.resumable(f"`canter train --resume {' '.join(str(d) for d in run_dirs)}`")
    return error.resumable("train again (no checkpoint was written to resume from)")


def _initial_carry(env: Any, spec: Any, resumed_from: list[Path | None]) -> Any:
    """The env loop's first carry: fresh episodes, or for a backend whose env state is a pytree, the episodes in
    flight that each resumed seed's checkpoint holds. Seeds of a group are stacked on a leading axis."""
    from canter.envs.episodes import init_env_carry
    from canter.training import seedgroup

    group = len(resumed_from)
    first_obs = seedgroup.split_first_obs(env.reset(), group)
    if group > 1 and getattr(env, "vmappable", False):
        handles = seedgroup.split_env_state(env.initial_state(), group)
    else:
        handles = [env.initial_state()] * group
    carries = [init_env_carry(handle, obs, spec.info_keys) for handle, obs in zip(handles, first_obs)]
    if getattr(env, "resumes_exactly", False):
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
    starts: list[_SeedStart],
    quiet: bool,
    started: float,
) -> list[RunResult]:
    """The host loop of a group. Every seed logs, checkpoints and stops on its own (budget, stop_at_return, a
    non-finite iteration); max_minutes and signals stop the whole group. A seed that is done keeps being computed
    inside the vmapped program until the last seed is done, but nothing of it is kept."""
    config = configs[0]
    program = _GroupProgram(config, algorithm, spec, env, states, carry)
    runs = _open_seeds(configs, spec, starts, program, started)
    label = f"{spec.id} {config.run.algo}" + (f" x{program.group} seeds" if program.group > 1 else "")
    progress = Progress(config.run.total_steps, min(start.step for start in starts), quiet, label)
    deadline = started + config.run.max_minutes * 60 if config.run.max_minutes else None
    try:
        # SIGINT and SIGTERM stop the run at the next iteration boundary, with a checkpoint written.
        with StopFlag() as stop:
            while any(run.stop_reason is None for run in runs):
                chunk = program.call(runs)
                steps = 0
                for i, run in enumerate(runs):
                    if run.stop_reason is None:
                        steps += _take_share(program, i, run, chunk)
                program.advance(chunk)
                _stop_seeds(program, runs, _group_stop_reason(deadline, stop))
                _show_progress(progress, runs, steps / chunk.elapsed)
    finally:
        progress.close()
        for run in runs:
            run.close()
    return _results(runs)


def _open_seeds(
    configs: list[Config], spec: Any, starts: list[_SeedStart], program: _GroupProgram, started: float
) -> list[_SeedRun]:
    """Each seed's host side, then the group's program compiled. A seed's setup or the compile failing still closes
    what the seeds before it opened (tracker runs)."""
    runs: list[_SeedRun] = []
    try:
        group_seeds = tuple(c.run.seed for c in configs)
        for config, start in zip(configs, starts):
            runs.append(_SeedRun(config, spec, start, program.algorithm.metric_names, group_seeds, started))
        compile_seconds = program.compile(runs)
        # After every check that can refuse the run, so that a refusal stays one line.
        if (note := budget_rounding_note(configs[0])) is not None:
            print(f"canter: note: {note}", file=sys.stderr)
        for run in runs:
            run.compile_seconds = compile_seconds
    except BaseException:
        for run in runs:
            run.close()
        raise
    return runs


def _take_share(program: _GroupProgram, i: int, run: _SeedRun, chunk: _Chunk) -> int:
    """Seed i's share of an iteration: its metrics.csv row (with an evaluation when one is due), then a checkpoint and
    a video when due; a non-finite iteration stops the seed instead. Returns the env steps it adds to the group's
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
    if run.checkpoint_due():
        run.save_periodic(program.pick(chunk.state, i), program.env_carry(chunk.carry, i))
    # Seed i's part of the group's state is picked out only when a video is due.
    run.videos.maybe_record(run.global_step, lambda path: run.save_snapshot(path, program.pick(chunk.state, i)))
    return int(metrics["steps"])


def _group_stop_reason(deadline: float | None, stop: StopFlag) -> str | None:
    """What stops every seed after this iteration: the wall-minute limit, else a signal."""
    if deadline is not None and time.perf_counter() >= deadline:
        return "max_minutes"
    if stop.signal is not None:
        return "signal"
    return None


def _stop_seeds(program: _GroupProgram, runs: list[_SeedRun], group_reason: str | None) -> None:
    """Finish, with a final checkpoint and summary, each seed still training that is done after this iteration."""
    for i, run in enumerate(runs):
        if run.stop_reason is None and (reason := run.stop_reason_after(group_reason)) is not None:
            run.finish(program.pick(program.state, i), reason, program.env_carry(program.carry, i))


def _show_progress(progress: Progress, runs: list[_SeedRun], sps: float) -> None:
    """The bar follows the seed furthest behind among those still training."""
    active = [run for run in runs if run.stop_reason is None] or runs
    recents = [run.recent_mean for run in runs if run.recent_mean is not None]
    progress.update(min(run.global_step for run in active), sps, float(np.mean(recents)) if recents else None)


def _results(runs: list[_SeedRun]) -> list[RunResult]:
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


@contextmanager
def _fewer_envs_when_out_of_device_memory(envs: int) -> Iterator[None]:
    """The device running out of memory, reported as what the user can change: env.num_envs."""
    try:
        yield
    except Exception as exc:
        if device_memory.is_out_of_memory(exc):
            raise device_memory.too_many_envs(envs) from None
        raise


@dataclass(frozen=True)
class _Chunk:
    """One call of the group's program: the state and env carry it returned, its metrics on the host, and its wall
    seconds."""

    state: Any
    carry: Any
    metrics: Any
    iterations: np.ndarray  # each seed's iteration count after the call
    elapsed: float


class _GroupProgram:
    """The group's jitted iteration (one seed's alone, or every seed's vmapped on a leading axis), and the train state
    and env carry it steps from one call to the next."""

    def __init__(self, config: Config, algorithm: Any, spec: Any, env: Any, states: list[Any], carry: Any) -> None:
        import jax

        self.algorithm = algorithm
        self.group = len(states)
        self.total = config.run.total_steps
        self.envs = config.env.num_envs
        donate = (0,) if algorithm.donate_state else ()
        self.pick: Callable[[Any, int], Any]  # seed i's part of a tree the group computed
        if self.group == 1:
            state = states[0]
            self.iteration = jax.jit(algorithm.make_iteration(config, spec, env.jax_step), donate_argnums=donate)
            self.pick = lambda tree, i: tree
        else:
            from canter.training import seedgroup

            state = seedgroup.stack(states)
            # A JAX env vmaps like the learner, each seed stepping its own envs; EnvPool's step goes through group_step.
            vmaps = getattr(env, "vmappable", False)
            env_step = env.jax_step if vmaps else seedgroup.group_step(env.jax_step, self.group)
            self.iteration = jax.jit(jax.vmap(algorithm.make_iteration(config, spec, env_step)), donate_argnums=donate)
            self.pick = seedgroup.unstack
        self.keeps_carry = getattr(env, "resumes_exactly", False)
        if algorithm.donate_state:
            state = jax.device_put(state)  # donation needs device buffers (a resumed state holds numpy arrays)
        self.state = state
        self.carry = carry
        self.compiled: Any = None

    def env_carry(self, tree: Any, i: int) -> Any:
        """Seed i's episodes in flight, for a backend that can resume them exactly (else None)."""
        return self.pick(tree, i) if self.keeps_carry else None

    def lr_fractions(self, runs: list[_SeedRun]) -> Any:
        """Each seed's fraction of its budget still to train, which its learning-rate schedule follows."""
        import jax.numpy as jnp

        values = [max(1.0 - run.global_step / self.total, 0.0) for run in runs]
        return jnp.float32(values[0]) if self.group == 1 else jnp.asarray(values, jnp.float32)

    def compile(self, runs: list[_SeedRun]) -> float:
        """Compile the iteration, refusing a program the device cannot hold; returns the seconds this took."""
        start = time.perf_counter()
        with _fewer_envs_when_out_of_device_memory(self.envs):
            self.compiled = self.iteration.lower(self.state, self.carry, self.lr_fractions(runs)).compile()
        device_memory.check_fits(self.compiled, self.envs)
        return time.perf_counter() - start

    def call(self, runs: list[_SeedRun]) -> _Chunk:
        """One call of the compiled iteration, from the state and carry that the last one left."""
        import jax

        t0 = time.perf_counter()
        with _fewer_envs_when_out_of_device_memory(self.envs):
            state, carry, metrics = self.compiled(self.state, self.carry, self.lr_fractions(runs))
        metrics = jax.device_get(metrics)
        iterations = np.asarray(jax.device_get(state.iteration))
        return _Chunk(state, carry, metrics, iterations, time.perf_counter() - t0)

    def advance(self, chunk: _Chunk) -> None:
        """The next call goes on from this chunk. Until then `state` and `carry` are those from before it, which a
        seed whose chunk was non-finite keeps."""
        self.state, self.carry = chunk.state, chunk.carry


class _SeedRun:
    """One seed's host side: its run folder, metrics, checkpoints, recent returns and stop reason."""

    def __init__(
        self,
        config: Config,
        spec: Any,
        start: _SeedStart,
        metric_names: tuple[str, ...],
        trained_with: tuple[int, ...],
        started: float,
    ) -> None:
        """`started`: when this session started, on time.perf_counter's clock. (A resume may start at step 0: a run
        whose first iteration was non-finite.)"""
        resumed = start.resumed
        out = start.out
        self.config = config
        self.out = out
        self.metric_names = metric_names
        self.global_step = start.step
        self.started = started
        earlier = start.earlier or {}
        self.earlier_wall = float(earlier.get("wall_seconds", 0.0))
        self.episodes = int(earlier.get("episodes", 0))
        # Carried over a resume, so that stop_at_return and recent_return mean what an uncut run's would.
        self.recent: deque[float] = deque(map(float, earlier.get("recent_returns", ())), maxlen=RECENT_EPISODES)
        self.run_seconds = float(earlier.get("train_seconds", 0.0))
        self.compile_seconds = 0.0  # this session's, once compiled
        self.trained_with = trained_with  # the seeds of this process's group, its own included
        every = config.run.checkpoint_every
        self.next_checkpoint = (start.step // every + 1) * every if every else None
        self.header_base = {"config": to_toml(config), "env": _env_header(spec), "algo": config.run.algo}
        self.logger = MetricsLogger(
            out,
            metric_names,
            spec.info_keys,
            config.run.tensorboard,
            resume_step=start.step if resumed else None,
            evaluates=config.run.eval_every > 0,
        )
        self.evaluation = (
            TrainingEvaluation(config, spec, start.step, _best_return(out) if resumed else None)
            if config.run.eval_every
            else None
        )
        self.videos = TrainingVideos(out, config.run.video_every, start.step, resumed=resumed)
        self.trackers = trackers.open_for_run(config, out, resumed=resumed)  # `canter train --track`
        self.closed = False
        self.stop_reason: str | None = None  # set once the seed is done; the group may still run
        self.error: str | None = None
        self.result: RunResult | None = None

    @property
    def recent_mean(self) -> float | None:
        return float(np.mean(self.recent)) if self.recent else None

    def totals(self) -> dict[str, Any]:
        return {
            "wall_seconds": self.earlier_wall + time.perf_counter() - self.started,
            "train_seconds": self.run_seconds,
            "episodes": self.episodes,
            "recent_returns": list(self.recent),
            "compile_seconds": self.compile_seconds,
        }

    def _header(self) -> dict[str, Any]:
        return dict(
            self.header_base,
            global_step=self.global_step,
            saved_at=datetime.now().isoformat(timespec="seconds"),
            totals=self.totals(),
        )

    def save(self, train_state: Any, env_carry: Any = None) -> None:
        """`env_carry`: the episodes in flight, for a backend that can resume them exactly (else None)."""
        checkpoint.save(
            checkpoint.checkpoint_path(self.out, self.global_step),
            train_state,
            self._header(),
            compress=self.config.run.compress_checkpoints,
            env_carry=env_carry,
        )
        checkpoint.prune(self.out, self.config.run.keep_checkpoints)

    def evaluation_due(self) -> bool:
        return self.evaluation is not None and self.evaluation.due(self.global_step)

    def evaluate(self, train_state: Any) -> dict[str, float]:
        """Evaluate the state after this iteration; a new best score saves it as checkpoints/best.npz. Returns
        the eval/* columns of this iteration's row."""
        from canter.algos import get_algorithm

        assert self.evaluation is not None
        result = self.evaluation.evaluate(train_state, self.global_step)
        if self.evaluation.improves(result):
            evaluation = dict(result.summary(), seed=DURING_TRAINING_SEED)
            header = dict(self._header(), evaluation=evaluation)
            checkpoint.save(
                checkpoint.best_path(self.out),
                train_state,
                header,
                compress=self.config.run.compress_checkpoints,
                leave_out=get_algorithm(self.config.run.algo).policy_checkpoint_leaves_out,
            )
        return result.columns()

    def record(self, metrics: dict[str, Any], iteration: int, elapsed: float) -> dict[str, Any]:
        """This iteration's metrics.csv row, which the loop logs once any evaluation has joined it."""
        steps = int(metrics["steps"])
        self.global_step += steps
        self.run_seconds += elapsed
        finished = np.asarray(metrics["finished"], bool)
        returns = np.asarray(metrics["episode_return"])[finished]
        lengths = np.asarray(metrics["episode_length"])[finished]
        self.episodes += int(finished.sum())
        self.recent.extend(float(r) for r in returns)
        row: dict[str, Any] = {
            "global_step": self.global_step,
            "iteration": iteration,
            "wall_time": round(self.earlier_wall + time.perf_counter() - self.started, 3),
            "sps": round(steps / elapsed, 1),
            "episodes": int(finished.sum()),
            "episodic_return": logged(returns.mean()) if returns.size else math.nan,
            "episodic_length": logged(lengths.mean()) if lengths.size else math.nan,
        }
        for key in self.metric_names:
            row[key] = logged(metrics[key])
        for key, values in metrics["episode_info"].items():
            chosen = np.asarray(values)[finished]
            row[f"info/{key}"] = logged(chosen.mean()) if chosen.size else math.nan
        return row

    def checkpoint_due(self) -> bool:
        return (
            self.next_checkpoint is not None
            and self.global_step >= self.next_checkpoint
            and self.global_step < self.config.run.total_steps
        )

    def save_periodic(self, train_state: Any, env_carry: Any = None) -> None:
        """The checkpoint that run.checkpoint_every asks for at this step."""
        self.save(train_state, env_carry)
        every = self.config.run.checkpoint_every
        self.next_checkpoint = (self.global_step // every + 1) * every

    def save_snapshot(self, path: Path, train_state: Any) -> None:
        """The policy state that a video of this step is rendered from (`canter.training.videos`)."""
        from canter.algos import get_algorithm

        checkpoint.save(
            path,
            train_state,
            dict(self.header_base, global_step=self.global_step),
            leave_out=get_algorithm(self.config.run.algo).policy_checkpoint_leaves_out,
        )

    def stop_reason_after(self, group_reason: str | None) -> str | None:
        """Why the seed stops after this iteration, if it does: its return target, its budget, else what stops the
        group (max_minutes, a signal). A seed whose budget is spent is complete even when the deadline or a signal
        comes in the same iteration: marked stopped early, a resume would find nothing left to train."""
        run = self.config.run
        if (
            run.stop_at_return is not None
            and len(self.recent) >= RECENT_EPISODES
            and (mean := self.recent_mean) is not None
            and mean >= run.stop_at_return
        ):
            return "stop_at_return"
        if self.global_step >= run.total_steps:
            return "budget"
        return group_reason

    def finish(self, train_state: Any, reason: str, env_carry: Any = None) -> None:
        self.stop_reason = reason
        self.save(train_state, env_carry)
        self.close()
        self.result = RunResult(
            run_dir=self.out,
            global_step=self.global_step,
            recent_return=self.recent_mean,
            episodes=self.episodes,
            wall_seconds=self.earlier_wall + time.perf_counter() - self.started,
            compile_seconds=self.compile_seconds,
            sps=self.global_step / self.run_seconds if self.run_seconds > 0 else 0.0,
            stop_reason=reason,
            trained_with=self.trained_with,
        )
        self.trackers.finish(self.out, _write_summary(self.result))

    def close(self) -> None:
        if not self.closed:
            self.logger.close()
            self.videos.close()
            self.closed = True
        if self.stop_reason is None or self.error is not None:  # failed or interrupted: `finish` ends them itself
            self.trackers.close()

    def fail(self, last_good_state: Any, env_carry: Any = None) -> None:
        """A non-finite iteration: keep the state before it and stop this seed; no summary is written."""
        self.stop_reason = "non_finite"
        # A checkpoint of this step, written before the failed iteration, is exact; the state handed back may not be
        # (an off-policy buffer keeps the finite transitions of the failed call).
        if not checkpoint.checkpoint_path(self.out, self.global_step).is_file():
            self.save(last_good_state, env_carry)
        self.close()
        self.error = (
            f"non-finite observation, reward or parameter during the iteration after step "
            f"{self.global_step}; stopped, last good state saved in {self.out / 'checkpoints'}"
        )


def _best_return(run_dir: Path) -> float | None:
    """The score of the run's best.npz, so that a resumed run keeps its best state until a better one comes."""
    path = checkpoint.best_path(run_dir)
    if not path.is_file():
        return None
    try:
        return float(checkpoint.read_header(path)["evaluation"]["return_mean"])
    except (KeyError, TypeError, ValueError):
        raise CanterError(
            f"{path} holds no evaluation score, so it is not a best checkpoint of this run; move it out of the "
            f"folder, then resume"
        ) from None


def resume_config(
    run_dir: Path,
    total_steps: int | None,
    max_minutes: float | None = None,
    stop_at_return: float | None | Saved = Saved.KEEP,
) -> Config:
    """The saved config of a run, with only its budget changed: the step budget, the wall-minute limit of the
    resuming process (a saved run.max_minutes otherwise applies again to each process that resumes the run), and
    the return target (a bench re-run gives its own; None: no target)."""
    from canter.training.run_folder import read_config

    if not Path(run_dir).is_dir():
        raise CanterError(f"run folder not found: {run_dir}")
    config = read_config(Path(run_dir))
    if total_steps is not None:
        config = replace(config, run=replace(config.run, total_steps=int(total_steps)))
    if max_minutes is not None:  # inf lifts a saved limit: the config holds no limit as None, which TOML can omit
        lifted = math.isinf(max_minutes) and max_minutes > 0
        config = replace(config, run=replace(config.run, max_minutes=None if lifted else float(max_minutes)))
    if not isinstance(stop_at_return, Saved):
        config = replace(config, run=replace(config.run, stop_at_return=stop_at_return))
    return config
