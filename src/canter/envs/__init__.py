"""Env construction: pick a backend for an id (`canter.envs.registry`) and build a vectorized env behind the
`VecEnv` protocol (`canter.envs.base`)."""

from __future__ import annotations

from canter.envs.base import EnvSpec, StepOutput, VecEnv, is_summed_info
from canter.envs.registry import known_ids, make_vec_env, resolve_backend

__all__ = ["EnvSpec", "StepOutput", "VecEnv", "is_summed_info", "known_ids", "make_vec_env", "resolve_backend"]
