"""The host loop: build env and state, call the jitted iteration, and between calls log, checkpoint, show progress
and handle stop conditions and signals."""

from __future__ import annotations

import json
import math
import platform
import secrets
import signal
import threading
import time
from collections import deque
from dataclasses import dataclass, replace
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from canter import checkpoint
from canter.config import Config, to_toml, validate
from canter.errors import CanterError
from canter.logger import MetricsLogger, Progress
from canter.seeding import RESUME, TRAIN, env_seeds
from canter.video import TrainingVideos

RECENT_EPISODES = 20


@dataclass(frozen=True)
class RunResult:
    run_dir: Path
    global_step: int
    recent_return: float | None      # mean raw return of the last 20 training episodes
    episodes: int
    wall_seconds: float
    compile_seconds: float
    sps: float                        # env steps per second, compile excluded
    stop_reason: str                  # budget | stop_at_return | max_minutes | signal


def _safe(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in text)


def new_run_dir(config: Config) -> Path:
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    name = (f"{_safe(config.env.id)}__{config.run.algo}__{_safe(config.run.preset)}__s{config.run.seed}__"
            f"{stamp}-{secrets.token_hex(2)}")
    return Path(config.run.out_dir) / name


def cpu_name() -> str:
    """The CPU model from /proc/cpuinfo where there is one (benchmark tables need more than 'x86_64')."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def versions() -> dict[str, Any]:
    from importlib import metadata

    def version(name: str) -> str | None:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return None

    import os

    return {"canter": version("canter"), "python": platform.python_version(), "jax": version("jax"),
            "jaxlib": version("jaxlib"), "optax": version("optax"), "envpool": version("envpool"),
            "mujoco": version("mujoco"), "gymnasium": version("gymnasium"), "numpy": version("numpy"),
            "platform": platform.platform(), "cpu": cpu_name(), "cpu_count": os.cpu_count()}


class _StopFlag:
    """SIGINT/SIGTERM set a flag; the loop writes a checkpoint and returns at the next iteration boundary."""

    def __init__(self) -> None:
        self.signal: int | None = None
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> "_StopFlag":
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        if self.signal is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt  # a second Ctrl-C means now
        self.signal = signum

    def __exit__(self, *exc: Any) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def _env_header(spec: Any) -> dict[str, Any]:
    return {"id": spec.id, "backend": spec.backend, "obs_dim": spec.obs_dim, "act_dim": spec.act_dim,
            "action_low": list(spec.action_low), "action_high": list(spec.action_high),
            "max_episode_steps": spec.max_episode_steps, "info_keys": list(spec.info_keys)}


def train(config: Config, *, resume: str | Path | None = None, quiet: bool = True,
          run_dir: str | Path | None = None) -> RunResult:
    """Train a policy. With `resume`, continue the newest checkpoint of that run folder; `config` may then only
    differ in run.total_steps (the learning-rate schedule is stretched to the new total)."""
    from canter.algos import get_algorithm
    from canter.envs import make_vec_env
    from canter.runtime import setup_jax

    setup_jax()
    validate(config)
    started = time.perf_counter()

    state = None
    if resume is not None:
        from canter.policy import load_state

        out = Path(resume)
        _, _, state, header = load_state(out)
        start_step = int(header["global_step"])
    else:
        start_step = 0
        out = Path(run_dir) if run_dir is not None else new_run_dir(config)

    if start_step >= config.run.total_steps:
        raise CanterError(f"the run already has {start_step} of run.total_steps={config.run.total_steps} steps; "
                          f"pass --total-steps larger than {start_step} to extend it")

    purpose, salt = (RESUME, start_step) if resume is not None else (TRAIN, 0)
    seeds = env_seeds(config.run.seed, config.env.num_envs, purpose, salt)
    env = make_vec_env(config.env.id, config.env.backend, config.env.num_envs, seeds, config.env.envpool_shards)
    spec = env.spec
    algorithm = get_algorithm(config.run.algo)
    try:
        algorithm.validate(config, spec)
        if state is None:
            state = algorithm.init_state(config, spec)
        out.mkdir(parents=True, exist_ok=True)
        checkpoint.atomic_write_bytes(out / "config.toml", lambda f: f.write(to_toml(config).encode()))
        if resume is None:
            checkpoint.atomic_write_bytes(out / "versions.json",
                                          lambda f: f.write(json.dumps(versions(), indent=2).encode()))
        return _loop(config, env, state, out, start_step, quiet, started)
    finally:
        env.close()


def _loop(config: Config, env: Any, state: Any, out: Path, start_step: int, quiet: bool,
          started: float) -> RunResult:
    import jax
    import jax.numpy as jnp

    from canter.algos import get_algorithm
    from canter.rollout import init_env_carry

    algorithm = get_algorithm(config.run.algo)
    spec = env.spec
    total = config.run.total_steps
    carry = init_env_carry(env.initial_state(), env.reset(), spec.info_keys)
    iteration = jax.jit(algorithm.make_iteration(config, spec, env.jax_step))
    compile_start = time.perf_counter()
    compiled = iteration.lower(state, carry, jnp.float32(1.0)).compile()
    compile_seconds = time.perf_counter() - compile_start

    header_base = {"config": to_toml(config), "env": _env_header(spec), "algo": config.run.algo}
    logger = MetricsLogger(out, algorithm.metric_names, spec.info_keys, config.run.tensorboard)
    progress = Progress(total, start_step, quiet, f"{spec.id} {config.run.algo}")
    recent: deque[float] = deque(maxlen=RECENT_EPISODES)
    episodes = 0
    global_step = start_step
    next_checkpoint = (global_step // config.run.checkpoint_every + 1) * config.run.checkpoint_every \
        if config.run.checkpoint_every else None
    run_seconds = 0.0
    stop_reason = "budget"
    deadline = started + config.run.max_minutes * 60 if config.run.max_minutes else None
    videos = TrainingVideos(out, config.run.video_every, start_step)

    def save(train_state: Any, step: int) -> None:
        header = dict(header_base, global_step=step, saved_at=datetime.now().isoformat(timespec="seconds"))
        checkpoint.save(checkpoint.checkpoint_path(out, step), train_state, header)
        checkpoint.prune(out, config.run.keep_checkpoints)

    try:
        with _StopFlag() as stop:
            while global_step < total:
                fraction = jnp.float32(max(1.0 - global_step / total, 0.0))
                t0 = time.perf_counter()
                new_state, carry, metrics = compiled(state, carry, fraction)
                metrics = jax.device_get(metrics)
                elapsed = time.perf_counter() - t0
                run_seconds += elapsed
                steps = int(metrics["steps"])
                if not bool(metrics["finite"]):
                    save(state, global_step)
                    raise CanterError(f"non-finite observation, reward or parameter during the iteration after step "
                                      f"{global_step}; stopped, last good state saved in {out / 'checkpoints'}")
                state = new_state
                global_step += steps
                finished = np.asarray(metrics["finished"], bool)
                returns = np.asarray(metrics["episode_return"])[finished]
                lengths = np.asarray(metrics["episode_length"])[finished]
                episodes += int(finished.sum())
                recent.extend(float(r) for r in returns)
                row: dict[str, Any] = {
                    "global_step": global_step, "iteration": int(state.iteration),
                    "wall_time": round(time.perf_counter() - started, 3), "sps": round(steps / elapsed, 1),
                    "episodes": int(finished.sum()),
                    "episodic_return": float(returns.mean()) if returns.size else math.nan,
                    "episodic_length": float(lengths.mean()) if lengths.size else math.nan,
                }
                for key in algorithm.metric_names:
                    row[key] = float(metrics[key])
                for key, values in metrics["episode_info"].items():
                    chosen = np.asarray(values)[finished]
                    row[f"info/{key}"] = float(chosen.mean()) if chosen.size else math.nan
                logger.log(row)
                recent_mean = float(np.mean(recent)) if recent else None
                progress.update(global_step, steps / elapsed, recent_mean)

                if next_checkpoint is not None and global_step >= next_checkpoint and global_step < total:
                    save(state, global_step)
                    next_checkpoint = (global_step // config.run.checkpoint_every + 1) * config.run.checkpoint_every
                videos.maybe_record(global_step, lambda path: checkpoint.save(
                    path, state, dict(header_base, global_step=global_step)))
                if (config.run.stop_at_return is not None and len(recent) >= RECENT_EPISODES
                        and recent_mean >= config.run.stop_at_return):
                    stop_reason = "stop_at_return"
                    break
                if deadline is not None and time.perf_counter() >= deadline:
                    stop_reason = "max_minutes"
                    break
                if stop.signal is not None:
                    stop_reason = "signal"
                    break
            save(state, global_step)
    finally:
        progress.close()
        logger.close()
        videos.close()

    wall = time.perf_counter() - started
    result = RunResult(run_dir=out, global_step=global_step,
                       recent_return=float(np.mean(recent)) if recent else None, episodes=episodes,
                       wall_seconds=wall, compile_seconds=compile_seconds,
                       sps=(global_step - start_step) / run_seconds if run_seconds > 0 else 0.0,
                       stop_reason=stop_reason)
    summary = {k: (str(v) if isinstance(v, Path) else v) for k, v in result.__dict__.items()}
    checkpoint.atomic_write_bytes(out / "summary.json", lambda f: f.write(json.dumps(summary, indent=2).encode()))
    return result


def resume_config(run_dir: Path, total_steps: int | None) -> Config:
    """The saved config of a run, with only the step budget changed."""
    from canter.policy import read_run_config

    if not Path(run_dir).is_dir():
        raise CanterError(f"run folder not found: {run_dir}")
    config = read_run_config(Path(run_dir))
    if total_steps is not None:
        config = replace(config, run=replace(config.run, total_steps=int(total_steps)))
    return config
