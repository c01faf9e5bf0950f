"""Evaluate a policy on fresh envs with frozen normalizer statistics."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from canter.core.seeding import EVAL, env_seeds
from canter.errors import CanterError
from canter.use.policy import Policy

MAX_EVAL_ENVS = 32


@dataclass(frozen=True)
class EvalResult:
    returns: np.ndarray
    lengths: np.ndarray
    wall_seconds: float

    @property
    def mean(self) -> float:
        return float(self.returns.mean())

    @property
    def std(self) -> float:
        return float(self.returns.std())

    def summary(self) -> dict[str, Any]:
        return {
            "episodes": int(self.returns.size),
            "return_mean": self.mean,
            "return_std": self.std,
            "length_mean": float(self.lengths.mean()),
            "length_std": float(self.lengths.std()),
            "eval_seconds": self.wall_seconds,
            "returns": [float(r) for r in self.returns],
            "lengths": [int(n) for n in self.lengths],
        }


def evaluate(
    policy: Policy,
    episodes: int = 10,
    deterministic: bool = True,
    seed: int = 0,
    env_id: str | None = None,
    backend: str | None = None,
    prepare_env: Callable[[Any], None] | None = None,
) -> EvalResult:
    """Run exactly `episodes` episodes. Each env gets a fixed quota, so short episodes are not over-represented.

    `prepare_env(env)` is called on every Gymnasium env right after it is made and before its first reset (the
    robustness sweeps edit the MuJoCo model there); it forces the backend that builds single envs (Gymnasium)."""
    from canter.envs.registry import make_vec_env, single_env_backend

    if episodes < 1:
        raise CanterError(f"--episodes must be >= 1, got {episodes}")
    env_id = env_id or policy.facts.env_id
    backend = backend or (policy.facts.backend if env_id == policy.facts.env_id else "auto")
    extra: dict[str, Any] = {}
    if prepare_env is not None:
        backend, extra = single_env_backend().name, {"on_make": prepare_env}
    num_envs = min(episodes, MAX_EVAL_ENVS)
    quota = np.full(num_envs, episodes // num_envs)
    quota[: episodes % num_envs] += 1
    started = time.perf_counter()
    env = make_vec_env(env_id, backend, num_envs, env_seeds(seed, num_envs, EVAL), **extra)
    try:
        if env.spec.obs_dim != policy.obs_dim or env.spec.act_dim != policy.act_dim:
            raise CanterError(
                f"{env_id} has observation/action sizes {env.spec.obs_dim}/{env.spec.act_dim}, the "
                f"policy expects {policy.obs_dim}/{policy.act_dim}; pick a matching --env"
            )
        obs = env.reset()
        if not deterministic:
            policy(obs[:1], deterministic=False, seed=seed)  # seed the sampling stream
        done_count = np.zeros(num_envs, int)
        running_return = np.zeros(num_envs)
        running_length = np.zeros(num_envs, int)
        prev_done = np.zeros(num_envs, bool)
        returns: list[float] = []
        lengths: list[int] = []
        while (done_count < quota).any():
            out = env.host_step(policy(obs, deterministic=deterministic))
            valid = ~prev_done
            running_return += out.reward * valid
            running_length += valid
            done = (out.terminated | out.truncated) & valid
            for i in np.flatnonzero(done):
                if done_count[i] < quota[i]:
                    returns.append(float(running_return[i]))
                    lengths.append(int(running_length[i]))
                done_count[i] += 1
            running_return[done] = 0.0
            running_length[done] = 0
            prev_done = done
            obs = out.obs
    finally:
        env.close()
    return EvalResult(np.asarray(returns), np.asarray(lengths), time.perf_counter() - started)
