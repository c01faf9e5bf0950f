"""One seed's host side of training: its run folder, metrics.csv, checkpoints, evaluations during training, recent
returns and stop reason, and what it hands back when it ends (`RunResult`, summary.json)."""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from canter import run_layout
from canter.config.schema import Config
from canter.config.serialize import to_toml
from canter.core.seeding import RESUME, TRAIN, env_seeds
from canter.errors import CanterError
from canter.files import atomic_write_bytes
from canter.run_layout import StopReason
from canter.training import checkpoint, run_folder, trackers
from canter.training.cadence import Cadence
from canter.training.evaluation import DURING_TRAINING_SEED, TrainingEvaluation
from canter.training.logger import MetricsLogger, Totals, logged
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
    stop_reason: str  # a StopReason
    # The seeds of the process that trained its last session (itself alone, or its vmapped group); None unknown.
    trained_with: tuple[int, ...] | None = None


def env_header(spec: Any) -> dict[str, Any]:
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


def read_result(run_dir: Path) -> RunResult | None:
    """What the run's summary.json records, as a RunResult of a session that trained nothing; None where the file
    is missing, damaged, or holds a value of another type."""
    summary = run_layout.read_summary(run_dir)
    if summary is None:
        return None
    recent = summary.get("recent_return")
    try:
        return RunResult(
            run_dir=Path(run_dir),
            global_step=int(summary["global_step"]),
            recent_return=None if recent is None else float(recent),
            episodes=int(summary.get("episodes", 0)),
            wall_seconds=float(summary.get("wall_seconds", 0.0)),
            compile_seconds=0.0,
            sps=float(summary.get("sps", 0.0)),
            stop_reason=StopReason(summary["stop_reason"]),
        )
    except (KeyError, TypeError, ValueError):
        return None


def write_summary(result: RunResult) -> dict[str, Any]:
    """Write the run's summary.json, whose run_dir is absolute (resolved) whether the run was started or resumed
    from a relative path; returns the summary."""
    summary = {k: (str(v) if isinstance(v, Path) else v) for k, v in result.__dict__.items()}
    summary["run_dir"] = str(Path(result.run_dir).resolve())
    atomic_write_bytes(
        result.run_dir / run_layout.SUMMARY_FILE, lambda f: f.write(json.dumps(summary, indent=2).encode())
    )
    return summary


def reached_target(recent: Sequence[float], target: float | None) -> bool:
    """Whether the mean of a run's last RECENT_EPISODES training episodes has reached its return target (never
    before it has that many)."""
    return target is not None and len(recent) >= RECENT_EPISODES and float(np.mean(recent[-RECENT_EPISODES:])) >= target


@dataclass(frozen=True)
class Best:
    """A run's checkpoints/best.npz: its evaluation's score and the step it was saved at."""

    path: Path
    score: float
    step: int


@dataclass(frozen=True)
class SeedStart:
    """Where one seed of a group starts: its run folder and, for a resume, what its newest checkpoint holds."""

    run_dir: Path
    state: Any = None  # None: the algorithm's initial state
    step: int = 0
    earlier: Totals = field(default_factory=Totals)  # what the sessions before a resume add up to
    resumed_from: Path | None = None  # the checkpoint
    untrained: bool = False  # the checkpoint was written before the run's first iteration (a stop during setup)
    restarted: bool = False  # a resume of a run with no checkpoint, which trains again from step 0 in its folder
    best: Best | None = None  # a resumed run's best.npz, read before anything is written to its folder
    kept_best: Best | None = None  # and the best.npz its checkpoint's training had, where a newer one replaced it

    @property
    def resumed(self) -> bool:
        return self.resumed_from is not None

    def env_seeds(self, config: Config) -> list[int]:
        """Exactly the seeds its single-seed run would give its envs, wherever it sits in the group."""
        # A run stopped before its first iteration resumes exactly as it would have started.
        purpose, salt = (RESUME, self.step) if self.resumed and not self.untrained else (TRAIN, 0)
        return env_seeds(config.run.seed, config.env.num_envs, purpose, salt)


class SeedRun:
    """One seed's host side: its run folder, metrics, checkpoints, recent returns and stop reason."""

    def __init__(
        self,
        config: Config,
        spec: Any,
        start: SeedStart,
        metric_names: tuple[str, ...],
        trained_with: tuple[int, ...],
        started: float,
    ) -> None:
        """`started`: when this session started, on time.perf_counter's clock. (A resume may start at step 0: a run
        whose first iteration was non-finite.)"""
        resumed = start.resumed
        run_dir = start.run_dir
        self.config = config
        self.run_dir = run_dir
        self.metric_names = metric_names
        self.global_step = start.step
        self.started = started
        earlier = start.earlier
        self.earlier_wall = earlier.wall_seconds
        self.episodes = earlier.episodes
        # Carried over a resume, so that stop_at_return and recent_return mean what an uncut run's would.
        self.recent: deque[float] = deque(earlier.recent_returns, maxlen=RECENT_EPISODES)
        self.run_seconds = earlier.train_seconds
        self.compile_seconds = 0.0  # this session's, once compiled
        self.trained_with = trained_with  # the seeds of this process's group, its own included
        self.checkpoints = Cadence(config.run.checkpoint_every, start.step)
        self.header_base = {
            "config": to_toml(config),
            "env": env_header(spec),
            "algo": config.run.algo,
            "trained_with": list(trained_with),  # for a summary written from the checkpoint alone
        }
        self.logger = MetricsLogger(
            run_dir,
            metric_names,
            spec.info_keys,
            config.run.tensorboard,
            resume_step=start.step if resumed else None,
            evaluates=config.run.eval_every > 0,
        )
        best = resumed_best(start.best, start.kept_best, start.step, run_dir) if resumed else None
        # The newest checkpoint's step, and the step of best.npz: a best.npz that the checkpoint covers is kept when a
        # better one replaces it, until the next checkpoint covers that one.
        self.checkpointed_step = start.step if resumed else None
        self.best_step = best.step if best is not None else None
        self.evaluation = (
            TrainingEvaluation(config, spec, start.step, best.score if best is not None else None)
            if config.run.eval_every
            else None
        )
        self.videos = TrainingVideos(run_dir, config.run.video_every, start.step, resumed=resumed)
        self.trackers = trackers.open_for_run(config, run_dir, resumed=resumed)  # `canter train --track`
        self.closed = False
        self.stop_reason: str | None = None  # set once the seed is done; the group may still run
        self.error: str | None = None
        self.result: RunResult | None = None

    @property
    def recent_mean(self) -> float | None:
        return float(np.mean(self.recent)) if self.recent else None

    def totals(self) -> Totals:
        return Totals(
            wall_seconds=self.earlier_wall + time.perf_counter() - self.started,
            train_seconds=self.run_seconds,
            episodes=self.episodes,
            recent_returns=tuple(self.recent),
            compile_seconds=self.compile_seconds,
        )

    def _header(self) -> dict[str, Any]:
        return dict(
            self.header_base,
            global_step=self.global_step,
            saved_at=datetime.now().isoformat(timespec="seconds"),
            totals=self.totals().header(),
        )

    def save(self, train_state: Any, env_carry: Any = None, *, untrained_but: tuple[str, ...] | None = None) -> None:
        """`env_carry`: the episodes in flight, for a backend that can resume them exactly (else None).
        `untrained_but`: for a state that has not trained yet, the fields only training fills (a replay buffer), all
        zeros still, as reading them back gives them; the header marks the checkpoint `untrained`, so that a resume
        starts the run as it would have started."""
        header = self._header() if untrained_but is None else dict(self._header(), untrained=True)
        self.logger.sync()
        checkpoint.save(
            run_folder.checkpoint_path(self.run_dir, self.global_step),
            train_state,
            header,
            compress=self.config.run.compress_checkpoints,
            env_carry=env_carry,
            leave_out=untrained_but or (),
        )
        self.checkpointed_step = self.global_step
        checkpoint.kept_best_path(self.run_dir).unlink(missing_ok=True)  # best.npz is this checkpoint's now
        checkpoint.prune(self.run_dir, self.config.run.keep_checkpoints)

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
            if self._best_is_checkpointed():
                keep_best(self.run_dir)
            checkpoint.save(
                checkpoint.best_path(self.run_dir),
                train_state,
                header,
                compress=self.config.run.compress_checkpoints,
                leave_out=get_algorithm(self.config.run.algo).policy_checkpoint_leaves_out,
            )
            self.best_step = self.global_step
        return result.columns()

    def _best_is_checkpointed(self) -> bool:
        """Whether best.npz is the best of the newest checkpoint's training (a resume from it keeps that best)."""
        return (
            self.best_step is not None
            and self.checkpointed_step is not None
            and self.best_step <= self.checkpointed_step
        )

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
        return self.checkpoints.due(self.global_step) and self.global_step < self.config.run.total_steps

    def save_periodic(self, train_state: Any, env_carry: Any = None) -> None:
        """The checkpoint that run.checkpoint_every asks for at this step."""
        self.save(train_state, env_carry)
        self.checkpoints = self.checkpoints.advance(self.global_step)

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
        if reached_target(tuple(self.recent), run.stop_at_return):
            return StopReason.TARGET
        if self.global_step >= run.total_steps:
            return StopReason.BUDGET
        return group_reason

    def finish(
        self, train_state: Any, reason: str, env_carry: Any = None, untrained_but: tuple[str, ...] | None = None
    ) -> None:
        """The seed's last checkpoint, then its summary.json and its tracker runs' end. `untrained_but`: as for
        `save`, for a new seed stopped before its first iteration."""
        self.stop_reason = reason
        self.save(train_state, env_carry, untrained_but=untrained_but)
        self._end(self._result(reason))

    def finish_untrained(self, reason: str) -> None:
        """End a resumed seed that this session stopped before it trained a step. Its newest checkpoint already
        holds its state, and a rewrite would record a budget it did not train toward, so only summary.json is
        written, with the totals of the sessions that trained it."""
        self.stop_reason = reason
        trained_with = _summary_trained_with(self.run_dir) or self.trained_with
        self._end(replace(self._result(reason), wall_seconds=self.earlier_wall, trained_with=trained_with))

    def _end(self, result: RunResult) -> None:
        self.close()
        self.result = result
        self.trackers.finish(self.run_dir, write_summary(result))

    def _result(self, reason: str) -> RunResult:
        return RunResult(
            run_dir=self.run_dir,
            global_step=self.global_step,
            recent_return=self.recent_mean,
            episodes=self.episodes,
            wall_seconds=self.earlier_wall + time.perf_counter() - self.started,
            compile_seconds=self.compile_seconds,
            sps=self.global_step / self.run_seconds if self.run_seconds > 0 else 0.0,
            stop_reason=reason,
            trained_with=self.trained_with,
        )

    def close(self) -> None:
        if not self.closed:
            self.logger.close()
            self.videos.close()
            self.closed = True
        if self.stop_reason is None or self.error is not None:  # failed or interrupted: `finish` ends them itself
            self.trackers.close()

    def fail(self, last_good_state: Any, env_carry: Any = None) -> None:
        """A non-finite iteration: keep the state before it and stop this seed; no summary is written."""
        self.stop_reason = StopReason.NON_FINITE
        # A checkpoint of this step, written before the failed iteration, is exact; the state handed back may not be
        # (an off-policy buffer keeps the finite transitions of the failed call).
        if not run_folder.checkpoint_path(self.run_dir, self.global_step).is_file():
            self.save(last_good_state, env_carry)
        self.close()
        self.error = (
            f"non-finite observation, reward or parameter during the iteration after step "
            f"{self.global_step}; stopped, last good state saved in {self.run_dir / 'checkpoints'}; "
            f"{divergence_hint(self.config)}"
        )


# Settings that change where or how the envs are stepped, never the updates: no suspects of a divergence.
NOT_SUSPECTS = frozenset({"env.backend", "env.envpool_shards"})


def _suspicion(key: str, value: Any) -> int:
    """Learning rates come first among the suspects: the most common cause, and what the fix lowers. They are the
    float settings named lr or *_lr (ppo.anneal_lr, a switch, is none)."""
    name = key.partition(".")[2]
    return 0 if isinstance(value, float) and (name == "lr" or name.endswith("_lr")) else 1


# A resume refuses --set, and an edited config.toml no longer matches its checkpoints: the fix is a new run.
_ANEW = (
    "a resume keeps the run's settings and would diverge again: train anew from its config.toml (canter train "
    "--config, canter.build_config(None, config_file=...) from Python)"
)


def divergence_hint(config: Config) -> str:
    """What to change in a diverged run: a resume keeps its settings (it refuses --set) and would diverge again from
    its last good state, so the fix is a new run from its config.toml with settings changed; the settings it changed
    from its preset are the first suspects, learning rates first."""
    from canter.config.build import preset_config
    from canter.config.experiment import flat_config
    from canter.config.values import set_text

    built = preset_config(config)
    if built is None:
        return (
            f"{_ANEW} with a lower learning rate or without the settings it changed (preset {config.run.preset} could "
            f"not be built to compare with)"
        )
    preset = flat_config(built)
    suspects = sorted(
        (
            (key, value)
            for key, value in flat_config(config).items()
            if key in preset and preset[key] != value and not key.startswith("run.") and key not in NOT_SUSPECTS
        ),
        key=lambda item: _suspicion(*item),
    )
    changed = [
        f"{key}={value:g}" if isinstance(value, float) else f"{key}={set_text(value)}" for key, value in suspects
    ]
    if not changed:
        return f"it diverged with its preset's own settings; {_ANEW} with a lower learning rate"
    more = f" and {len(changed) - 4} more" if len(changed) > 4 else ""
    return (
        f"{_ANEW} with settings changed; first suspects, the settings changed from preset {config.run.preset}: "
        f"{', '.join(changed[:4])}{more}"
    )


def _summary_trained_with(run_dir: Path) -> tuple[int, ...] | None:
    """The seeds that summary.json says trained with this one in its last session; None where it says nothing."""
    return recorded_seeds((run_layout.read_summary(run_dir) or {}).get("trained_with"))


def recorded_seeds(value: Any) -> tuple[int, ...] | None:
    """`trained_with` as summary.json or a checkpoint header records it; None where it is absent (a checkpoint
    written before canter recorded it) or damaged."""
    try:
        return tuple(int(seed) for seed in value) if isinstance(value, list) else None
    except (ValueError, TypeError):
        return None


def read_best(run_dir: Path, path: Path | None = None) -> Best | None:
    """The run's best.npz (or `path`, its kept one), which a resume that evaluates reads before it writes anything: a
    damaged one is refused in one line with the run folder as it was. None where the run has none."""
    path = checkpoint.best_path(run_dir) if path is None else path
    if not (path.exists() or path.is_symlink()):
        return None
    header = checkpoint.read_header(path)  # a folder, or a file that is no checkpoint, is refused here
    try:
        score = float(header["evaluation"]["return_mean"])
        step = int(header.get("global_step", 0))
    except (KeyError, TypeError, ValueError):
        raise CanterError(
            f"{path} holds no evaluation score, so it is not a best checkpoint of this run; move it out of the "
            f"folder, then resume"
        ) from None
    return Best(path, score, step)


def readable_best(run_dir: Path, path: Path | None = None) -> Best | None:
    """`read_best`, with a damaged file as none: where nothing will be evaluated against it, or for the kept best,
    which a resume either puts back or removes."""
    try:
        return read_best(run_dir, path)
    except CanterError:
        return None


def keep_best(run_dir: Path) -> None:
    """Keep best.npz, which the newest checkpoint covers, as the kept best, before a better one replaces it: linked,
    so that best.npz is there throughout for its readers (copied where the file system has no links). One moved away
    while the run trained leaves nothing to keep."""
    best, kept = checkpoint.best_path(run_dir), checkpoint.kept_best_path(run_dir)
    kept.unlink(missing_ok=True)
    try:
        os.link(best, kept)
    except FileNotFoundError:
        return
    except OSError:
        with contextlib.suppress(FileNotFoundError):
            data = best.read_bytes()
            atomic_write_bytes(kept, lambda f: f.write(data))


def resumed_best(best: Best | None, kept: Best | None, resume_step: int, run_dir: Path) -> Best | None:
    """The best.npz that a run resumed at `resume_step` keeps until a better one comes. One saved after that
    checkpoint (an evaluation comes before its iteration's checkpoint) is of training that the resume does again,
    whose rows it drops: it is removed, and the best.npz it replaced, which the run kept, is put back."""
    if best is not None and best.step <= resume_step:
        checkpoint.kept_best_path(run_dir).unlink(missing_ok=True)  # left by a kill after the checkpoint
        return best
    back = kept if kept is not None and kept.step <= resume_step else None
    if back is not None:
        os.replace(back.path, checkpoint.best_path(run_dir))
    else:
        checkpoint.kept_best_path(run_dir).unlink(missing_ok=True)
    if best is not None:
        if back is None:
            best.path.unlink(missing_ok=True)
        again = (
            f"the best.npz it had replaced (step {back.step:,}, return {back.score:.1f}) is back"
            if back is not None
            else "the next evaluation saves a new one"
        )
        print(
            f"canter: note: removed {best.path} (step {best.step:,}, return {best.score:.1f}): it was saved after "
            f"the checkpoint this resume starts from (step {resume_step:,}), by training the resume does again; "
            f"{again}",
            file=sys.stderr,
        )
    return None if back is None else replace(back, path=checkpoint.best_path(run_dir))
