"""The host loop: build env and state, call the jitted iteration, and between calls log, checkpoint, show progress
and handle stop conditions and signals."""

from __future__ import annotations

import json
import math
import sys
import time
from collections import deque
from collections.abc import Callable, Sequence
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
    from canter.envs import make_vec_env, resolve_backend
    from canter.envs.registry import env_options, get_backend, note_replay

    backend = resolve_backend(configs[0].env.id, configs[0].env.backend)
    setup_jax(backend)
    for config in configs:
        validate(config)
    played = evaluation_backend(configs[0].env.id, configs[0].run.eval_backend, backend)  # before a folder is made
    note_replay(configs[0].env.id, backend, played)
    started = time.perf_counter()

    states, outs, start_steps, seeds, earlier = [], [], [], [], []
    resumed_from: list[Path | None] = []
    for config, resume, run_dir in zip(configs, resumes, run_dirs):
        state = None
        if resume is not None:
            from canter.training.restore import load_state

            out = Path(resume)
            locks.take(out)  # before its newest checkpoint is read: another writer may be finishing it
            latest = checkpoint.latest(out)
            resumed_from.append(latest)
            saved, _, state, header = load_state(out, latest)
            _check_only_the_budget_differs(saved, config, out)
            start_step = int(header["global_step"])
            _note_a_changed_backend(out, header["env"]["backend"], backend, start_step)
            earlier.append(header.get("totals") or totals_until(run_folder.metrics_file(out), start_step))
        else:
            start_step = 0
            out = Path(run_dir) if run_dir is not None else run_folder.new_run_dir(config)
            earlier.append(None)
            resumed_from.append(None)
        if start_step >= config.run.total_steps:
            raise CanterError(
                f"{out} already has {start_step} of run.total_steps={config.run.total_steps} "
                f"steps; pass --total-steps larger than {start_step} to extend it"
            )
        purpose, salt = (RESUME, start_step) if resume is not None else (TRAIN, 0)
        # A seed's envs get exactly the seeds its single-seed run would give them, wherever it sits in the group.
        seeds += env_seeds(config.run.seed, config.env.num_envs, purpose, salt)
        states.append(state)
        outs.append(out)
        start_steps.append(start_step)
        if resume is None:
            locks.take(out)  # before anything is written to it

    config = configs[0]
    options = env_options(config.env, backend)
    try:
        if not get_backend(backend).jax_native:  # JAX envs are checked on the compiled program instead
            host_memory.check_envs_fit(config.env.id, backend, options, len(seeds))
        env = make_vec_env(config.env.id, backend, len(seeds), seeds, config.env.envpool_shards, **options)
    except DiscreteActionsError as exc:
        raise CanterError(
            f"{config.run.algo} is continuous-only, but {exc.env_id} has discrete actions "
            f"({exc.space}); choose an env with Box actions"
        ) from None
    spec = replace(env.spec, num_envs=config.env.num_envs)  # what one seed sees
    algorithm = get_algorithm(config.run.algo)
    try:
        algorithm.validate(config, spec)
        for i, (config, out) in enumerate(zip(configs, outs)):
            if states[i] is None:
                states[i] = algorithm.init_state(config, spec)
            out.mkdir(parents=True, exist_ok=True)
            if resumes[i] is None:
                run_folder.create(out, config)
            else:
                run_folder.migrate(out)
                run_folder.write_config(out, config)
            disk_room.warn_if_checkpoints_will_not_fit(out, states[i], config, algorithm.policy_checkpoint_leaves_out)
        carry = _initial_carry(env, spec, resumed_from)
        return _loop(configs, env, spec, states, carry, outs, start_steps, earlier, quiet, started)
    except (CanterError, OSError) as exc:  # a full disk or unwritable folder: one line, and how to go on
        error = training_write_error(exc, outs)
        if error is None:
            raise
        raise error from None
    finally:
        env.close()


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


class _SeedRun:
    """One seed's host side: its run folder, metrics, checkpoints, recent returns and stop reason."""

    def __init__(
        self,
        config: Config,
        spec: Any,
        out: Path,
        start_step: int,
        metric_names: tuple[str, ...],
        earlier: dict[str, Any] | None,
        trained_with: tuple[int, ...],
    ) -> None:
        """`earlier`: wall seconds, training seconds, episodes and the recent episode returns of the sessions before
        a resume; None for a new run. (A resume may start at step 0: a run whose first iteration was non-finite.)"""
        resumed = earlier is not None
        self.config = config
        self.out = out
        self.metric_names = metric_names
        self.start_step = start_step
        self.global_step = start_step
        earlier = earlier or {}
        self.earlier_wall = float(earlier.get("wall_seconds", 0.0))
        self.episodes = int(earlier.get("episodes", 0))
        # Carried over a resume, so that stop_at_return and recent_return mean what an uncut run's would.
        self.recent: deque[float] = deque(map(float, earlier.get("recent_returns", ())), maxlen=RECENT_EPISODES)
        self.run_seconds = float(earlier.get("train_seconds", 0.0))
        self.compile_seconds = 0.0  # this session's, once compiled
        self.trained_with = trained_with  # the seeds of this process's group, its own included
        every = config.run.checkpoint_every
        self.next_checkpoint = (start_step // every + 1) * every if every else None
        self.header_base = {"config": to_toml(config), "env": _env_header(spec), "algo": config.run.algo}
        self.logger = MetricsLogger(
            out,
            metric_names,
            spec.info_keys,
            config.run.tensorboard,
            resume_step=start_step if resumed else None,
            evaluates=config.run.eval_every > 0,
        )
        self.evaluation = (
            TrainingEvaluation(config, spec, start_step, _best_return(out) if resumed else None)
            if config.run.eval_every
            else None
        )
        self.videos = TrainingVideos(out, config.run.video_every, start_step, resumed=resumed)
        self.trackers = trackers.open_for_run(config, out, resumed=resumed)  # `canter train --track`
        self.closed = False
        self.stop_reason: str | None = None  # set once the seed is done; the group may still run
        self.error: str | None = None
        self.result: RunResult | None = None

    @property
    def recent_mean(self) -> float | None:
        return float(np.mean(self.recent)) if self.recent else None

    def totals(self, started: float) -> dict[str, Any]:
        return {
            "wall_seconds": self.earlier_wall + time.perf_counter() - started,
            "train_seconds": self.run_seconds,
            "episodes": self.episodes,
            "recent_returns": list(self.recent),
            "compile_seconds": self.compile_seconds,
        }

    def _header(self, step: int, started: float) -> dict[str, Any]:
        return dict(
            self.header_base,
            global_step=step,
            saved_at=datetime.now().isoformat(timespec="seconds"),
            totals=self.totals(started),
        )

    def save(self, train_state: Any, step: int, started: float, env_carry: Any = None) -> None:
        """`env_carry`: the episodes in flight, for a backend that can resume them exactly (else None)."""
        checkpoint.save(
            checkpoint.checkpoint_path(self.out, step),
            train_state,
            self._header(step, started),
            compress=self.config.run.compress_checkpoints,
            env_carry=env_carry,
        )
        checkpoint.prune(self.out, self.config.run.keep_checkpoints)

    def evaluation_due(self) -> bool:
        return self.evaluation is not None and self.evaluation.due(self.global_step)

    def evaluate(self, train_state: Any, started: float) -> dict[str, float]:
        """Evaluate the state after this iteration; a new best score saves it as checkpoints/best.npz. Returns
        the eval/* columns of this iteration's row."""
        from canter.algos import get_algorithm

        assert self.evaluation is not None
        result = self.evaluation.evaluate(train_state, self.global_step)
        if self.evaluation.improves(result):
            evaluation = dict(result.summary(), seed=DURING_TRAINING_SEED)
            header = dict(self._header(self.global_step, started), evaluation=evaluation)
            checkpoint.save(
                checkpoint.best_path(self.out),
                train_state,
                header,
                compress=self.config.run.compress_checkpoints,
                leave_out=get_algorithm(self.config.run.algo).policy_checkpoint_leaves_out,
            )
        return result.columns()

    def record(self, metrics: dict[str, Any], iteration: int, elapsed: float, started: float) -> dict[str, Any]:
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
            "wall_time": round(self.earlier_wall + time.perf_counter() - started, 3),
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

    def own_stop_reason(self) -> str | None:
        run = self.config.run
        if (
            run.stop_at_return is not None
            and len(self.recent) >= RECENT_EPISODES
            and (mean := self.recent_mean) is not None
            and mean >= run.stop_at_return
        ):
            return "stop_at_return"
        return None

    def finish(
        self, train_state: Any, reason: str, compile_seconds: float, started: float, env_carry: Any = None
    ) -> None:
        self.stop_reason = reason
        self.save(train_state, self.global_step, started, env_carry)
        self.close()
        self.result = RunResult(
            run_dir=self.out,
            global_step=self.global_step,
            recent_return=self.recent_mean,
            episodes=self.episodes,
            wall_seconds=self.earlier_wall + time.perf_counter() - started,
            compile_seconds=compile_seconds,
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

    def fail(self, last_good_state: Any, started: float, env_carry: Any = None) -> None:
        """A non-finite iteration: keep the state before it and stop this seed; no summary is written."""
        self.stop_reason = "non_finite"
        # A checkpoint of this step, written before the failed iteration, is exact; the state handed back may not be
        # (an off-policy buffer keeps the finite transitions of the failed call).
        if not checkpoint.checkpoint_path(self.out, self.global_step).is_file():
            self.save(last_good_state, self.global_step, started, env_carry)
        self.close()
        self.error = (
            f"non-finite observation, reward or parameter during the iteration after step "
            f"{self.global_step}; stopped, last good state saved in {self.out / 'checkpoints'}"
        )


def _loop(
    configs: list[Config],
    env: Any,
    spec: Any,
    states: list[Any],
    carry: Any,
    outs: list[Path],
    start_steps: list[int],
    earlier: list[dict[str, Any] | None],
    quiet: bool,
    started: float,
) -> list[RunResult]:
    """The host loop of a group. Every seed logs, checkpoints and stops on its own (budget, stop_at_return, a
    non-finite iteration); max_minutes and signals stop the whole group. A seed that is done keeps being computed
    inside the vmapped program until the last seed is done, but nothing of it is kept."""
    import jax
    import jax.numpy as jnp

    from canter.algos import get_algorithm

    config = configs[0]
    group = len(configs)
    algorithm = get_algorithm(config.run.algo)
    total = config.run.total_steps
    donate = (0,) if algorithm.donate_state else ()
    pick: Callable[[Any, int], Any]  # seed i's part of a tree the group computed
    if group == 1:
        state = states[0]
        iteration = jax.jit(algorithm.make_iteration(config, spec, env.jax_step), donate_argnums=donate)
        pick = lambda tree, i: tree  # noqa: E731
    else:
        from canter.training import seedgroup

        state = seedgroup.stack(states)
        # A JAX env vmaps like the learner, each seed stepping its own envs; EnvPool's step goes through group_step.
        env_step = env.jax_step if getattr(env, "vmappable", False) else seedgroup.group_step(env.jax_step, group)
        iteration = jax.jit(jax.vmap(algorithm.make_iteration(config, spec, env_step)), donate_argnums=donate)
        pick = seedgroup.unstack
    keeps_carry = getattr(env, "resumes_exactly", False)

    def env_carry(tree: Any, i: int) -> Any:
        return pick(tree, i) if keeps_carry else None

    if algorithm.donate_state:
        state = jax.device_put(state)  # donation needs device buffers (a resumed state holds numpy arrays)

    def fractions(runs: list[_SeedRun]) -> jnp.ndarray:
        values = [max(1.0 - run.global_step / total, 0.0) for run in runs]
        return jnp.float32(values[0]) if group == 1 else jnp.asarray(values, jnp.float32)

    envs = config.env.num_envs
    runs: list[_SeedRun] = []
    try:  # a seed's setup or the compile failing still closes what the seeds before it opened (tracker runs)
        group_seeds = tuple(c.run.seed for c in configs)
        for c, out, start, before in zip(configs, outs, start_steps, earlier):
            runs.append(_SeedRun(c, spec, out, start, algorithm.metric_names, before, group_seeds))
        compile_start = time.perf_counter()
        try:
            compiled = iteration.lower(state, carry, fractions(runs)).compile()
        except Exception as exc:
            if device_memory.is_out_of_memory(exc):
                raise device_memory.too_many_envs(envs) from None
            raise
        device_memory.check_fits(compiled, envs)
        compile_seconds = time.perf_counter() - compile_start
        # After every check that can refuse the run, so that a refusal stays one line.
        if (note := budget_rounding_note(config)) is not None:
            print(f"canter: note: {note}", file=sys.stderr)
        for run in runs:
            run.compile_seconds = compile_seconds
    except BaseException:
        for run in runs:
            run.close()
        raise

    label = f"{spec.id} {config.run.algo}" + (f" x{group} seeds" if group > 1 else "")
    progress = Progress(total, min(start_steps), quiet, label)
    deadline = started + config.run.max_minutes * 60 if config.run.max_minutes else None
    try:
        # SIGINT and SIGTERM stop the run at the next iteration boundary, with a checkpoint written.
        with StopFlag() as stop:
            while any(run.stop_reason is None for run in runs):
                t0 = time.perf_counter()
                try:
                    new_state, new_carry, metrics = compiled(state, carry, fractions(runs))
                except Exception as exc:
                    if device_memory.is_out_of_memory(exc):
                        raise device_memory.too_many_envs(envs) from None
                    raise
                metrics = jax.device_get(metrics)
                iterations = np.asarray(jax.device_get(new_state.iteration))
                elapsed = time.perf_counter() - t0
                steps = 0
                for i, run in enumerate(runs):
                    if run.stop_reason is not None:
                        continue
                    seed_metrics = pick(metrics, i)
                    if not bool(seed_metrics["finite"]):
                        # A donated state is gone; such an algorithm returns the last good state itself.
                        run.fail(pick(new_state if algorithm.donate_state else state, i), started, env_carry(carry, i))
                        continue
                    row = run.record(seed_metrics, int(pick(iterations, i)), elapsed, started)
                    if run.evaluation_due():
                        row.update(run.evaluate(pick(new_state, i), started))
                    run.logger.log(row)
                    run.trackers.log(row)
                    steps += int(seed_metrics["steps"])
                    if run.checkpoint_due():
                        run.save(pick(new_state, i), run.global_step, started, env_carry(new_carry, i))
                        every = run.config.run.checkpoint_every
                        run.next_checkpoint = (run.global_step // every + 1) * every

                    def save_snapshot(
                        path: Path, i: int = i, run: _SeedRun = run, group_state: Any = new_state
                    ) -> None:
                        checkpoint.save(
                            path,
                            pick(group_state, i),
                            dict(run.header_base, global_step=run.global_step),
                            leave_out=algorithm.policy_checkpoint_leaves_out,
                        )

                    run.videos.maybe_record(run.global_step, save_snapshot)
                state, carry = new_state, new_carry

                group_reason = None
                if deadline is not None and time.perf_counter() >= deadline:
                    group_reason = "max_minutes"
                elif stop.signal is not None:
                    group_reason = "signal"
                for i, run in enumerate(runs):
                    if run.stop_reason is not None:
                        continue
                    # A seed whose budget is spent is complete even when the deadline or a signal comes in the
                    # same iteration: marked stopped early, a resume would find nothing left to train.
                    budget = "budget" if run.global_step >= total else None
                    reason = run.own_stop_reason() or budget or group_reason
                    if reason is not None:
                        run.finish(pick(state, i), reason, compile_seconds, started, env_carry(carry, i))
                active = [run for run in runs if run.stop_reason is None] or runs
                recents = [run.recent_mean for run in runs if run.recent_mean is not None]
                progress.update(
                    min(run.global_step for run in active),
                    steps / elapsed,
                    float(np.mean(recents)) if recents else None,
                )
    finally:
        progress.close()
        for run in runs:
            run.close()

    failed = [run for run in runs if run.error is not None]
    if failed:
        if group == 1:
            raise CanterError(failed[0].error)
        others = [run for run in runs if run.error is None]
        tail = "; ".join(f"seed {run.config.run.seed} stopped: {run.stop_reason}" for run in others)
        raise CanterError(
            "; ".join(f"seed {run.config.run.seed}: {run.error}" for run in failed) + (f"; {tail}" if tail else "")
        )
    results = [run.result for run in runs if run.result is not None]
    assert len(results) == len(runs), "a seed that did not fail has finished"
    return results


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
