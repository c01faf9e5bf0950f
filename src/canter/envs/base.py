"""The env protocol the learner sees, and the protocol an env backend implements to provide it.

The learner's side is expressed in JAX types only: the learner never imports an env library. A vectorized env provides:
- `spec`: shapes, action bounds and the info keys it reports;
- `reset()`: a host call that starts every env and returns the first float32 observations;
- `jax_step(state, action)`: a jittable step, usable inside `lax.scan`, with EnvPool's episode semantics;
- `host_step(action)`: the same step from plain numpy, for evaluation loops;
- `close()`.

An env whose state is itself JAX arrays (`canter.envs.functional`) is also a `JaxVecEnv`, which training checks for
by type: its runs resume their episodes exactly, seed groups vmap it, and evaluations play inside one program.

Episode semantics (every backend): the step that ends an episode returns the true final observation and its flags.
The next step of that env is an autoreset step: it ignores its action and returns the reset observation and both
flags false. Its reward means nothing (0 for EnvPool's gym-style envs, the previous step's again for its DM Control
ones), so every consumer masks autoreset steps out (`canter.envs.episodes`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol, runtime_checkable

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
    obs: Any  # [N, obs_dim] float32
    reward: Any  # [N] float32, raw env reward
    terminated: Any  # [N] bool
    truncated: Any  # [N] bool
    info: Any  # dict key -> [N] float32, the reward terms and similar scalars the env reports


class VecEnv(Protocol):
    spec: EnvSpec

    def reset(self) -> np.ndarray: ...

    def jax_step(self, state: Any, action: Any) -> tuple[Any, StepOutput]: ...

    def initial_state(self) -> Any: ...

    def host_step(self, action: np.ndarray) -> StepOutput: ...

    def close(self) -> None: ...


@runtime_checkable
class JaxVecEnv(VecEnv, Protocol):
    """A `VecEnv` whose whole env state is a pytree of arrays with the envs on the leading axis, stepped by pure JAX
    functions (`canter.envs.functional`). So, unlike a handle on envs outside JAX (EnvPool's, Gymnasium's):
    - a checkpoint holds its episodes in flight, and a resumed run continues them exactly;
    - a seed group vmaps its step as it vmaps the learner, each seed stepping its own slice of the envs;
    - an evaluation plays its episodes inside one jitted program (`play_episodes`)."""

    def play_episodes(self, act: Callable[[Any, Any], Any], args: Any, quota: np.ndarray) -> tuple: ...

    def state_shapes(self) -> Any:
        """The shapes and dtypes of its envs' state, known before the envs are reset."""
        ...

    def state_bytes(self) -> int:
        """The memory its envs' state takes, from `state_shapes`."""
        ...


# Info entries that are bookkeeping, not measurements.
IGNORED_INFO_KEYS = frozenset(
    {
        "env_id",
        "players",
        "elapsed_step",
        "TimeLimit.truncated",
        "episode",
        "_episode",
        "final_observation",
        "final_info",
        "terminal_observation",
    }
)


def loads(load: Callable[[], object]) -> bool:
    """Whether `load()`, the import of a backend's env library, succeeds on this machine (`Backend.available`)."""
    try:
        load()
    except Exception:
        return False
    return True


def is_summed_info(key: str) -> bool:
    """Reward terms (rewards, costs, penalties) add up over an episode; other scalars (velocities, positions) are
    averaged per step."""
    return any(term in key for term in ("reward", "cost", "penalty"))


class Backend(Protocol):
    """One env backend: a package under `canter.envs` whose `BACKEND` implements this, listed once in
    `canter.envs.registry`. Importing the package must not import its env library (the config reference imports every
    backend to read its label); only calling its methods may.

    The optional capabilities default to absent; a backend that has one sets its flag and overrides its method."""

    name: str  # the value of env.backend and --backend
    label: str  # how messages and docs name it: a short proper noun (Brax), also used as a possessive
    # Accepts `module:EnvId`: ids that a user's module registers when imported (`load_custom`).
    custom_ids: bool = False
    # Builds one Gymnasium-API env object at a time (`make_single`, and `on_make(env)` in `make`): robustness sweeps
    # edit its MuJoCo model through env.unwrapped.model, and videos render it.
    single_envs: bool = False
    # Its step is JAX (`canter.envs.functional`): it runs in float32 on the GPU where one exists, `auto` never picks
    # it, and its env state is checkpointed, so runs resume exactly.
    jax_native: bool = False
    # Takes env.solver_iterations, env.solver_ls_iterations and env.contacts (`make` gets them as keyword arguments).
    solver_options: bool = False
    # Splits its envs over concurrent pools, as many as env.envpool_shards asks (`make` gets it as `shards`).
    pools: bool = False
    # Its envs observe differently from every other backend's (Brax's own models): a policy trained on it evaluates
    # on it and on the env it trained on only.
    own_observations: bool = False
    # How a user gets its env library where it is missing (an extra to install), or "" where canter always has it.
    install: str = ""
    # The ids it runs that no other backend has, known without its env library (Brax's env names), so that where
    # the library is missing an id of them names `install` rather than being called unknown.
    installable_ids: tuple[str, ...] = ()

    def available(self) -> bool:
        """Whether its env library imports on this machine."""
        ...

    def supported_ids(self) -> list[str]:
        """The continuous-control ids it can make; empty when it is not available."""
        ...

    def make(self, env_id: str, num_envs: int, seeds: list[int], shards: int = 0, **kwargs: Any) -> VecEnv:
        """`num_envs` envs seeded with `seeds`. `shards` splits them over concurrent pools where the backend has pools
        (0: its default); kwargs go to the env. Raises a one-line CanterError for envs canter cannot train on."""
        ...

    def load_custom(self, env_id: str) -> None:
        """Import the module of a `module:EnvId` id and check that it registered EnvId (custom_ids backends)."""
        raise TypeError(f"the {self.name} backend takes no module:EnvId ids (check custom_ids first)")

    def make_single(self, env_id: str, **kwargs: Any) -> Any:
        """One Gymnasium-API env with a flat Box observation and Box actions (single_envs backends)."""
        raise TypeError(f"the {self.name} backend builds no single envs (check single_envs first)")

    def dm_control_task(self, env_id: str) -> tuple[str, str] | None:
        """(domain, task) of dm_control's suite that env_id runs, or None when it is not a DM Control env."""
        return None

    def unlimited_episodes(self, env_id: str) -> bool:
        """Whether env_id's episodes have no step limit (its spec's max_episode_steps is None), so that one may never
        end; False where every env of the backend has one."""
        return False

    def differs_from_single_envs(self, env_id: str) -> str | None:
        """How its env of `env_id` differs from the single-env backend's of the same id, which replays its runs
        (videos, robustness sweeps), or None where they step alike."""
        return None
