"""Gymnasium backend: any registered or custom env, one Python env object per slot.

It runs everywhere and takes envs from the user's own modules (`module:EnvId`). It builds single envs too, so
robustness sweeps edit their MuJoCo model and videos render them.
"""

from __future__ import annotations

import importlib
from typing import Any

from canter.envs.base import Backend, VecEnv, loads
from canter.errors import CanterError

NAME = "gymnasium"


class GymnasiumBackend(Backend):
    name = NAME
    label = "Gymnasium"
    custom_ids = True
    single_envs = True

    def available(self) -> bool:
        return loads(lambda: importlib.import_module("gymnasium"))

    def supported_ids(self) -> list[str]:
        if not self.available():
            return []
        import gymnasium as gym

        return list(gym.registry.keys())

    def load_custom(self, env_id: str) -> None:
        module, _, name = env_id.partition(":")
        if not module or module.startswith(".") or not name:
            raise CanterError(
                f"custom env '{env_id}' needs a module and an id, as in my_package.envs:MyEnv-v0 (an absolute "
                f"module path)"
            )
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:
            missing = exc.name or ""
            # The module itself, or a package above it: it is not installed. Anything else is what it imports.
            if missing and not (module == missing or module.startswith(f"{missing}.")):
                raise CanterError(
                    f"module '{module}' for env '{env_id}' imports '{missing}', which is missing ({exc}); install "
                    f'it, or see the full traceback with: python -c "import {module}"'
                ) from None
            raise CanterError(
                f"cannot import module '{module}' for env '{env_id}' ({exc}); check that it is "
                f"installed or on PYTHONPATH"
            ) from None
        except Exception as exc:  # the module's own code: a syntax error, or anything it raises as it runs
            from canter.envs.gymnasium.single import raised

            raise CanterError(
                f"importing module '{module}' for env '{env_id}' raised {raised(exc)}; see the full traceback "
                f'with: python -c "import {module}"'
            ) from None
        if name not in self.supported_ids():
            raise CanterError(
                f"module '{module}' did not register '{name}' with gymnasium; "
                f"call gymnasium.register(id='{name}', ...) in it"
            )

    def unlimited_episodes(self, env_id: str) -> bool:
        """From the registered spec, without making an env (a `module:EnvId` id once its module is imported)."""
        import gymnasium as gym

        try:
            spec = gym.spec(env_id.partition(":")[2] or env_id)
        except gym.error.Error:  # not registered: making the env says so
            return False
        return spec.max_episode_steps is None

    def make(self, env_id: str, num_envs: int, seeds: list[int], shards: int = 0, **kwargs: Any) -> VecEnv:
        """`shards` does not apply: every env is its own Python object. `on_make(env)`, if given in kwargs, is called
        on each env before its first reset."""
        from canter.envs.gymnasium.vec_env import GymnasiumVecEnv

        try:
            return GymnasiumVecEnv(env_id, num_envs, seeds, **kwargs)
        except CanterError:
            raise
        except ImportError as exc:
            raise CanterError(f"{env_id}: a dependency is missing ({exc}); install it and retry") from None

    def make_single(self, env_id: str, **kwargs: Any) -> Any:
        from canter.envs.gymnasium.single import make_single

        return make_single(env_id, **kwargs)


BACKEND = GymnasiumBackend()
