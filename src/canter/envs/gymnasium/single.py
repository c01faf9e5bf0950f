"""One Gymnasium env, checked and flattened into the shapes canter trains on."""

from __future__ import annotations

import warnings
from typing import Any

from canter.errors import CanterError, DiscreteActionsError


def _space_error(env_id: str, space: Any) -> CanterError:
    return CanterError(
        f"{env_id}: observation space {space} is not supported; canter needs a Box or a Dict of "
        f"Boxes (wrap the env to produce one)"
    )


def make_single(env_id: str, **kwargs: Any) -> Any:
    """gym.make with a flattened Dict observation, checked to be continuous-control."""
    import gymnasium as gym

    with warnings.catch_warnings():
        # A v4 id (the seed reports' tasks) is asked for on purpose; Gymnasium's advice to move to v5 is noise here.
        warnings.filterwarnings("ignore", message=r".*is out of date", category=DeprecationWarning)
        env = gym.make(env_id, **kwargs)
    obs_space = env.observation_space
    if isinstance(obs_space, gym.spaces.Dict):
        if not all(isinstance(s, gym.spaces.Box) for s in obs_space.spaces.values()):
            raise _space_error(env_id, obs_space)
        env = gym.wrappers.FlattenObservation(env)
    elif not isinstance(obs_space, gym.spaces.Box):
        raise _space_error(env_id, obs_space)
    if not isinstance(env.action_space, gym.spaces.Box):
        raise DiscreteActionsError(env_id, env.action_space)
    return env
