"""One Gymnasium env, checked and flattened into the shapes canter trains on."""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Iterator
from typing import Any

from canter.errors import CanterError, DiscreteActionsError


def _space_error(env_id: str, space: Any) -> CanterError:
    return CanterError(
        f"{env_id}: observation space {space} is not supported; canter needs a Box or a Dict of "
        f"Boxes (wrap the env to produce one)"
    )


def raised(exc: BaseException) -> str:
    """`Type: message` on one line, as a one-line error quotes an exception from the user's own code."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def custom_env_failure(env_id: str, stage: str, exc: BaseException) -> str:
    """The one line for a custom env (`module:EnvId`) whose own code raised while `stage`."""
    command = (
        f"import gymnasium as gym; env = gym.make('{env_id}'); env.reset(seed=0); env.step(env.action_space.sample())"
    )
    return f'{env_id}: {stage} raised {raised(exc)}; see the full traceback with: python -c "{command}"'


@contextlib.contextmanager
def user_code(env_id: str, stage: str) -> Iterator[None]:
    """Turn what a custom env's own code raises while `stage` into one line. A registered Gymnasium env raising is
    a bug (in it or here) and keeps its traceback."""
    try:
        yield
    except CanterError:
        raise
    except Exception as exc:
        if ":" not in env_id:
            raise
        raise CanterError(custom_env_failure(env_id, stage, exc)) from None


def check_spaces(env_id: str, observation_space: Any, action_space: Any) -> None:
    """Spaces that the networks cannot take: no action to choose, or nothing to observe."""
    import numpy as np

    for what, space in (("action", action_space), ("observation", observation_space)):
        if int(np.prod(space.shape)) < 1:
            raise CanterError(
                f"{env_id}: the {what} space {space} has no dimensions; canter needs at least one {what} value "
                f"(fix the env's {what}_space)"
            )


def check_observation(env_id: str, observation_space: Any, obs: Any, source: str) -> None:
    """An observation (from `source`, such as reset) whose size is not its space's: the networks are built for the
    space, and it would fail inside jit with no word of the env."""
    import numpy as np

    if np.size(obs) != int(np.prod(observation_space.shape)):
        raise CanterError(
            f"{env_id}: {source} returned an observation of shape {np.shape(obs)}, but its observation space has "
            f"shape {observation_space.shape}; make the env's observations match its observation_space"
        )


def make_single(env_id: str, **kwargs: Any) -> Any:
    """gym.make with a flattened Dict observation, checked to be continuous-control."""
    import gymnasium as gym

    with warnings.catch_warnings(), user_code(env_id, "making the env"):
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
    check_spaces(env_id, env.observation_space, env.action_space)
    return env
