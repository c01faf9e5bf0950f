"""Evaluate a policy on fresh envs with frozen normalizer statistics."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from canter.errors import CanterError
from canter.policy import Policy
from canter.seeding import EVAL, env_seeds

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


def evaluate(policy: Policy, episodes: int = 10, deterministic: bool = True, seed: int = 0,
             env_id: str | None = None, backend: str | None = None) -> EvalResult:
    """Run exactly `episodes` episodes. Each env gets a fixed quota, so short episodes are not over-represented."""
    from canter.envs import make_vec_env

    if episodes < 1:
        raise CanterError(f"--episodes must be >= 1, got {episodes}")
    env_id = env_id or policy.facts.env_id
    backend = backend or (policy.facts.backend if env_id == policy.facts.env_id else "auto")
    num_envs = min(episodes, MAX_EVAL_ENVS)
    quota = np.full(num_envs, episodes // num_envs)
    quota[: episodes % num_envs] += 1
    started = time.perf_counter()
    env = make_vec_env(env_id, backend, num_envs, env_seeds(seed, num_envs, EVAL))
    try:
        if env.spec.obs_dim != policy.obs_dim or env.spec.act_dim != policy.act_dim:
            raise CanterError(f"{env_id} has observation/action sizes {env.spec.obs_dim}/{env.spec.act_dim}, the "
                              f"policy expects {policy.obs_dim}/{policy.act_dim}; pick a matching --env")
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
