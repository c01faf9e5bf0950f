"""Validation of a resolved config, in one place: the env and run sections, every section's own checks, and the
checks its algorithm declares across the keys it reads. Each failure is a one-line CanterError."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from canter.config.algorithms import algorithm_spec
from canter.config.schema import Config, check_section, section_names
from canter.config.values import SEED_LIMIT
from canter.errors import CanterError


def need(ok: bool, message: str) -> None:
    if not ok:
        raise CanterError(message)


def need_positive(key: str, value: float) -> None:
    need(math.isfinite(value) and value > 0, f"{key} must be > 0, got {value}")


# The learners and the JAX env steps compute in float32: a finite setting past its largest value becomes infinite there,
# and a nonzero one below its smallest normal value becomes 0 (XLA flushes the rest), so either is refused by name.
FLOAT32_MAX = 3.4028234663852886e38
FLOAT32_TINY = 1.1754943508222875e-38


def check_float32_range(section_name: str, section: Any) -> None:
    for field in dataclasses.fields(section):
        value = getattr(section, field.name)
        if isinstance(value, float) and math.isfinite(value) and value != 0:
            need(
                FLOAT32_TINY <= abs(value) <= FLOAT32_MAX,
                f"{section_name}.{field.name} {value:g} is beyond float32's range ({FLOAT32_TINY:.3g} to "
                f"{FLOAT32_MAX:.3g} in size), which the learner computes in; choose a value within it",
            )


CONTACTS = ("all", "floor")


def check_physics(env: Any) -> None:
    """The env section's physics settings (env.solver_*, env.contacts): in range, and only on a backend that takes
    them."""
    from canter.envs.registry import AUTO, get_backend, solver_backends

    takes = env.backend != AUTO and get_backend(env.backend).solver_options

    def only_there(key: str, default: bool) -> None:
        if not (default or takes):
            where = " and ".join(solver_backends())
            raise CanterError(f"env.{key} applies to the {where} backend only; {_physics_fix(env.id, key)}")

    for key in ("solver_iterations", "solver_ls_iterations"):
        value = getattr(env, key)
        need(value >= 0, f"env.{key} must be >= 0 (0: the model's own), got {value}")
        only_there(key, value == 0)
    need(env.contacts in CONTACTS, f"env.contacts must be {' or '.join(CONTACTS)}, got '{env.contacts}'")
    only_there("contacts", env.contacts == "all")


def _physics_fix(env_id: str, key: str) -> str:
    """What to do about a physics key on a backend that does not take it: name a backend that takes it and runs the
    env. An env that none of them ports (Pendulum has no MJX version) is told so, since --backend would fail next;
    an id no backend knows, or one asked of a backend that is not installed, gets the plain advice."""
    from canter.envs.registry import get_backend, known_ids, solver_backends

    names = solver_backends()
    installed = [name for name in names if get_backend(name).available()]
    if env_id and installed and env_id in known_ids():
        ports = [name for name in installed if env_id in get_backend(name).supported_ids()]
        if not ports:
            return f"{env_id} has no {' or '.join(installed)} version: drop env.{key} (physics= for evaluate)"
        names = ports
    # canter.evaluate reaches this check too, with its backend= and physics= for --backend and --set.
    return f"add --backend {names[0]} or drop env.{key} (env.backend from Python; backend= and physics= for evaluate)"


def _check_eval_backend(backend: str, eval_backend: str) -> None:
    from canter.envs.registry import AUTO, backend_choices, describe_backend_choices, get_backend

    need(
        eval_backend in ("", *backend_choices()),
        f"run.eval_backend must be empty (the run's own) or {describe_backend_choices()}, got '{eval_backend}'",
    )
    if eval_backend in ("", backend) or backend == AUTO:
        return
    trained_on = get_backend(backend)
    need(
        not trained_on.own_observations,
        f"{trained_on.label} observations differ from Gymnasium's, so {trained_on.name} runs evaluate on the "
        f"{trained_on.name} backend only; drop run.eval_backend",
    )


def _is_utf8(text: str) -> bool:
    """False for a path given in bytes that are not UTF-8, which Python keeps as lone surrogates."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def validate(config: Config) -> None:
    from canter.envs.registry import (
        AUTO,
        backend_choices,
        describe_backend_choices,
        get_backend,
        pooled_backends,
        refuse_mujoco_py,
        refuse_video_of_own_envs,
    )

    env, run = config.env, config.run
    need(bool(env.id), "env.id is empty; pass an env id such as Hopper-v5")
    need(
        env.backend in backend_choices(),
        f"env.backend must be {describe_backend_choices()}, got '{env.backend}'",
    )
    need(env.num_envs >= 1, f"env.num_envs must be >= 1, got {env.num_envs}")
    need(
        0 <= env.envpool_shards <= env.num_envs,
        f"env.envpool_shards must be 0 (auto) to env.num_envs {env.num_envs}, got {env.envpool_shards}",
    )
    need(
        env.envpool_shards == 0 or env.backend == AUTO or get_backend(env.backend).pools,
        f"env.envpool_shards applies to the {' and '.join(pooled_backends())} backend only, and this run steps on "
        f"{env.backend}; drop it",
    )
    check_physics(env)
    refuse_mujoco_py(env.id, env.backend)  # else Gymnasium's own error asks for a package that no longer has them
    need(env.clip_obs > 0, f"env.clip_obs must be > 0, got {env.clip_obs}")
    need(env.clip_reward > 0, f"env.clip_reward must be > 0, got {env.clip_reward}")
    need(
        math.isfinite(env.reward_scale) and env.reward_scale > 0,
        f"env.reward_scale must be a positive number, got {env.reward_scale}",
    )
    need(
        env.reward_scale == 1.0 or not env.normalize_reward,
        f"env.reward_scale {env.reward_scale} and env.normalize_reward both set the rewards' scale; "
        "set env.normalize_reward=false or env.reward_scale=1",
    )
    spec = algorithm_spec(run.algo)
    check_float32_range("env", env)
    for name in section_names():
        check_section(name, config.section(name))
        check_float32_range(name, config.section(name))
    spec.validate(config)
    need(run.total_steps >= 1, f"run.total_steps must be >= 1, got {run.total_steps}")
    need(bool(run.out_dir.strip()), "run.out_dir is empty; give a folder for the run folders (the default is runs)")
    need(
        _is_utf8(run.out_dir),
        f"run.out_dir {run.out_dir.encode('utf-8', 'backslashreplace').decode()} is not valid UTF-8, which the run's "
        "files record it in; choose a folder name of UTF-8 characters",
    )
    need(0 <= run.seed < SEED_LIMIT, f"run.seed must be from 0 to {SEED_LIMIT - 1}, got {run.seed}")
    need(run.checkpoint_every >= 0, f"run.checkpoint_every must be >= 0, got {run.checkpoint_every}")
    need(run.keep_checkpoints >= 1, f"run.keep_checkpoints must be >= 1, got {run.keep_checkpoints}")
    need(run.video_every >= 0, f"run.video_every must be >= 0, got {run.video_every}")
    if run.video_every:
        refuse_video_of_own_envs(env.backend, env.id, "drop --video-every (run.video_every)")
    need(run.eval_every >= 0, f"run.eval_every must be >= 0, got {run.eval_every}")
    need(run.eval_episodes >= 1, f"run.eval_episodes must be >= 1, got {run.eval_episodes}")
    _check_eval_backend(env.backend, run.eval_backend)
    if run.max_minutes is not None:
        need(run.max_minutes > 0, f"run.max_minutes must be > 0, got {run.max_minutes}")
    if run.stop_at_return is not None:
        need(math.isfinite(run.stop_at_return), f"run.stop_at_return must be a finite number, got {run.stop_at_return}")
