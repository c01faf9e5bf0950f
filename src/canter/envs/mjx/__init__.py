"""MJX backend: Gymnasium's v5 MuJoCo locomotion tasks with MJX physics, so that the env step is JAX and runs on the
GPU inside the same jitted program as the learner (on the CPU where there is no GPU: correct, but slow).

The tasks are ports (`canter.envs.mjx.tasks`), checked against the Gymnasium backend step by step. Runs on it
resume exactly, episodes in flight included (`canter.envs.functional`).
"""

from __future__ import annotations

from typing import Any

from canter.envs.base import Backend, VecEnv, loads
from canter.errors import CanterError

NAME = "mjx"


class MjxBackend(Backend):
    name = NAME
    label = "MJX"
    install = "pip install 'canter[mjx]'"
    jax_native = True
    solver_options = True

    def available(self) -> bool:
        from canter.envs.mjx.library import import_mjx

        return loads(import_mjx)

    def supported_ids(self) -> list[str]:
        if not self.available():
            return []
        from canter.envs.mjx.tasks import TASKS

        return list(TASKS)

    def make(self, env_id: str, num_envs: int, seeds: list[int], shards: int = 0, **kwargs: Any) -> VecEnv:
        """`shards` does not apply: all envs step in one vmapped program."""
        from canter.envs.functional import FunctionalVecEnv
        from canter.envs.mjx.env import functional_env
        from canter.envs.registry import MODEL_OWN_PHYSICS

        unknown = set(kwargs) - set(MODEL_OWN_PHYSICS)
        if unknown:
            raise CanterError(f"the mjx backend takes no env option {', '.join(sorted(unknown))}")
        return FunctionalVecEnv(functional_env(env_id, **kwargs), env_id, NAME, num_envs, seeds)


BACKEND = MjxBackend()
