"""Brax backend: Brax's own envs (`ant`, `humanoid`, ...), named as Brax names them and stepped by MJX, so that canter's
learners train on exactly what Brax's speed and return figures are measured on.

These envs use Brax's simplified models and their own observations and rewards, unlike the mjx backend's ports of
Gymnasium's tasks: a policy trained here evaluates here only (`own_observations`). Runs resume exactly, episodes
in flight included (`canter.envs.functional`).
"""

from __future__ import annotations

from typing import Any

from canter.envs.base import Backend, VecEnv, loads
from canter.errors import CanterError

NAME = "brax"
# Brax's env names that canter offers (`env.env_names()` of the pinned brax), for the error where brax is missing.
IDS = (
    "ant",
    "halfcheetah",
    "hopper",
    "humanoid",
    "humanoidstandup",
    "inverted_double_pendulum",
    "inverted_pendulum",
    "pusher",
    "reacher",
    "walker2d",
)


class BraxBackend(Backend):
    name = NAME
    label = "Brax"
    install = "pip install 'canter[brax]'"
    jax_native = True
    own_observations = True
    installable_ids = IDS

    def available(self) -> bool:
        from canter.envs.brax.env import brax_envs

        return loads(brax_envs)

    def supported_ids(self) -> list[str]:
        if not self.available():
            return []
        from canter.envs.brax.env import env_names

        return env_names()

    def make(self, env_id: str, num_envs: int, seeds: list[int], shards: int = 0, **kwargs: Any) -> VecEnv:
        """`shards` does not apply: all envs step in one vmapped program."""
        from canter.envs.brax.env import functional_env
        from canter.envs.functional import FunctionalVecEnv

        if kwargs:
            raise CanterError(f"the {NAME} backend takes no env options, got {', '.join(sorted(kwargs))}")
        return FunctionalVecEnv(functional_env(env_id), env_id, NAME, num_envs, seeds)


BACKEND = BraxBackend()
