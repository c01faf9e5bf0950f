"""Env construction: pick a backend for an id and build a vectorized env behind the `VecEnv` protocol."""

from __future__ import annotations

import difflib
import importlib
from typing import Any

from canter.envs import envpool_backend
from canter.envs.base import EnvSpec, StepOutput, VecEnv, is_summed_info
from canter.errors import CanterError

__all__ = ["EnvSpec", "StepOutput", "VecEnv", "is_summed_info", "make_vec_env", "resolve_backend", "known_ids"]


def _gymnasium_ids() -> list[str]:
    import gymnasium as gym

    return list(gym.registry.keys())


def known_ids() -> list[str]:
    return sorted(set(envpool_backend.supported_ids()) | set(_gymnasium_ids()))


def _import_custom_module(env_id: str) -> None:
    module, _, _ = env_id.partition(":")
    try:
        importlib.import_module(module)
    except ImportError as exc:
        raise CanterError(f"cannot import module '{module}' for env '{env_id}' ({exc}); check that it is "
                          f"installed or on PYTHONPATH") from None


def resolve_backend(env_id: str, backend: str) -> str:
    """The backend that will run env_id, or a one-line error naming the nearest known ids."""
    if ":" in env_id:
        if backend == "envpool":
            raise CanterError(f"custom env '{env_id}' needs the gymnasium backend; drop --backend envpool")
        _import_custom_module(env_id)
        name = env_id.partition(":")[2]
        if name not in _gymnasium_ids():
            raise CanterError(f"module '{env_id.partition(':')[0]}' did not register '{name}' with gymnasium; "
                              f"call gymnasium.register(id='{name}', ...) in it")
        return "gymnasium"
    envpool_ids = set(envpool_backend.supported_ids())
    gym_ids = set(_gymnasium_ids())
    if backend == "envpool":
        if not envpool_backend.available():
            raise CanterError("EnvPool is not installed on this platform; use --backend gymnasium")
        if env_id not in envpool_ids:
            raise _unknown(env_id, sorted(envpool_ids), "EnvPool")
        return "envpool"
    if backend == "gymnasium":
        if env_id not in gym_ids:
            raise _unknown(env_id, sorted(gym_ids), "Gymnasium")
        return "gymnasium"
    if env_id in envpool_ids:
        return "envpool"
    if env_id in gym_ids:
        return "gymnasium"
    raise _unknown(env_id, known_ids(), "canter")


def _unknown(env_id: str, candidates: list[str], where: str) -> CanterError:
    close = difflib.get_close_matches(env_id, candidates, n=3, cutoff=0.6)
    hint = f"; did you mean {', '.join(close)}?" if close else "; for a custom env pass module:EnvId"
    return CanterError(f"unknown env id '{env_id}' for {where}{hint}")


def make_vec_env(env_id: str, backend: str, num_envs: int, seeds: list[int], shards: int = 0,
                 **kwargs: Any) -> VecEnv:
    """`shards` applies to EnvPool only (0: one single-threaded pool per core); kwargs go to the env."""
    chosen = resolve_backend(env_id, backend)
    if chosen == "envpool":
        if not 0 <= shards <= num_envs:
            raise CanterError(f"env.envpool_shards {shards} cannot split {num_envs} envs; use 0 (auto) to {num_envs}")
        try:
            return envpool_backend.EnvPoolVecEnv(env_id, num_envs, seeds, shards=shards, **kwargs)
        except ValueError as exc:
            raise CanterError(f"{env_id}: {exc}; canter trains continuous-action envs") from None
    from canter.envs.gymnasium_backend import GymnasiumVecEnv

    try:
        return GymnasiumVecEnv(env_id, num_envs, seeds, **kwargs)
    except CanterError:
        raise
    except (ImportError, ModuleNotFoundError) as exc:
        raise CanterError(f"{env_id}: a dependency is missing ({exc}); install it and retry") from None
