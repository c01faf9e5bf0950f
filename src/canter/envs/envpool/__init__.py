"""EnvPool backend: native MuJoCo, Box2D and DM Control envs stepped in C++.

Training steps the pool inside the jitted rollout through EnvPool's XLA custom call. The pool always uses one
worker thread: with two threads the XLA path corrupted MuJoCo's memory here (the process dies with no Python
exception), and a crash no handler can catch must not be reachable from the CLI.
"""

from __future__ import annotations

import importlib
import re
from typing import Any

from canter.envs.base import Backend, VecEnv, loads
from canter.envs.dm_control_tasks import observation_keys
from canter.errors import CanterError

NAME = "envpool"

# Ids whose EnvPool env is not Gymnasium's, measured with the same actions from the same state (EnvPool 1.2.5,
# Gymnasium 1.x, MuJoCo 3.6.0); the v5 ids and the other MuJoCo ids step alike (tests/test_envs.py).
_DIFFERS_FROM_GYMNASIUM = {
    "Humanoid-v4": "its observation's 84 contact-force entries stay 0 (Gymnasium's reach thousands)",
    "HumanoidStandup-v4": (
        "its observation's 84 contact-force entries stay 0 (Gymnasium's reach hundreds) and its reward leaves out "
        "the impact cost"
    ),
}

# EnvPool families with continuous actions that canter trains on.
_CONTINUOUS_MODULES = ("envpool.mujoco.gym", "envpool.mujoco.dmc")
_CONTINUOUS_IDS = (
    "BipedalWalker-v3",
    "BipedalWalkerHardcore-v3",
    "LunarLanderContinuous-v2",
    "LunarLanderContinuous-v3",
    "Pendulum-v1",
    "MountainCarContinuous-v0",
)


class EnvPoolBackend(Backend):
    name = NAME
    label = "EnvPool"
    install = "EnvPool has wheels for Linux only"
    pools = True

    def available(self) -> bool:
        return loads(lambda: importlib.import_module("envpool"))

    def supported_ids(self) -> list[str]:
        if not self.available():
            return []
        from envpool.registration import registry

        ids = []
        for env_id, spec in registry.specs.items():
            module = spec[0] if isinstance(spec, tuple) else ""
            if module in _CONTINUOUS_MODULES or env_id in _CONTINUOUS_IDS:
                ids.append(env_id)
        return ids

    def make(self, env_id: str, num_envs: int, seeds: list[int], shards: int = 0, **kwargs: Any) -> VecEnv:
        from canter.envs.envpool.vec_env import EnvPoolVecEnv

        if not 0 <= shards <= num_envs:
            raise CanterError(f"env.envpool_shards {shards} cannot split {num_envs} envs; use 0 (auto) to {num_envs}")
        task = self.dm_control_task(env_id)
        keys = observation_keys(*task) if task else None  # a DM Control task's own observation, as dm_control's
        try:
            return EnvPoolVecEnv(env_id, num_envs, seeds, shards=shards, observation_keys=keys, **kwargs)
        except ValueError as exc:
            raise CanterError(f"{env_id}: {exc}; canter trains continuous-action envs") from None

    def dm_control_task(self, env_id: str) -> tuple[str, str] | None:
        """Read from EnvPool's registry: the spec class names the domain (DmcWalkerEnvSpec), the config the task."""
        try:
            from envpool.registration import registry
        except ImportError:
            return None
        entry = registry.specs.get(env_id)
        if entry is None or not entry[0].endswith(".dmc"):
            return None
        domain = re.sub(r"^Dmc|EnvSpec$", "", entry[1])
        domain = re.sub(r"(?<=[a-z])(?=[A-Z])", "_", domain).lower()
        return domain, entry[2]["task_name"]

    def differs_from_single_envs(self, env_id: str) -> str | None:
        return _DIFFERS_FROM_GYMNASIUM.get(env_id)


BACKEND = EnvPoolBackend()
