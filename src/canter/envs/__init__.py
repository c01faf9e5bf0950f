"""Env construction: pick a backend for an id (`canter.envs.registry`) and build a vectorized env behind the
`VecEnv` protocol (`canter.envs.base`)."""

from __future__ import annotations

from canter.envs.registry import make_vec_env, resolve_backend

__all__ = ["make_vec_env", "resolve_backend"]
