"""The env protocol the learner sees. It is expressed in JAX types only: the learner never imports an env library.

A backend provides:
- `spec`: shapes, action bounds and the info keys it reports;
- `reset()`: a host call that starts every env and returns the first float32 observations;
- `jax_step(state, action)`: a jittable step, usable inside `lax.scan`, with EnvPool's episode semantics;
- `host_step(action)`: the same step from plain numpy, for evaluation loops;
- `close()`.

Episode semantics (both backends): the step that ends an episode returns the true final observation and its flags.
The next step of that env is an autoreset step: it ignores its action and returns the reset observation, reward 0
and both flags false.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np


@dataclass(frozen=True)
class EnvSpec:
    id: str
    backend: str
    num_envs: int
    obs_dim: int
    act_dim: int
    action_low: tuple[float, ...]
    action_high: tuple[float, ...]
    max_episode_steps: int | None
    info_keys: tuple[str, ...]


class StepOutput(NamedTuple):
    obs: Any          # [N, obs_dim] float32
    reward: Any       # [N] float32, raw env reward
    terminated: Any   # [N] bool
    truncated: Any    # [N] bool
    info: Any         # dict key -> [N] float32, the reward terms and similar scalars the env reports


class VecEnv(Protocol):
    spec: EnvSpec

    def reset(self) -> np.ndarray: ...

    def jax_step(self, state: Any, action: Any) -> tuple[Any, StepOutput]: ...

    def initial_state(self) -> Any: ...

    def host_step(self, action: np.ndarray) -> StepOutput: ...

    def close(self) -> None: ...


# Info entries that are bookkeeping, not measurements.
IGNORED_INFO_KEYS = frozenset({"env_id", "players", "elapsed_step", "TimeLimit.truncated", "episode", "_episode",
                               "final_observation", "final_info", "terminal_observation"})


def is_summed_info(key: str) -> bool:
    """Reward terms add up over an episode; other scalars (velocities, positions) are averaged per step."""
    return "reward" in key or "cost" in key
