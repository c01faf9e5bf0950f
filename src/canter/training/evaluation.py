"""The evaluation protocol of `canter eval`, which training also runs every `run.eval_every` env steps.

An evaluation plays exactly `episodes` full-length episodes on fresh envs, with the observation normalizer frozen
at the evaluated state's statistics. The envs' seeds come from (seed, purpose) (`canter.core.seeding`), a stream
apart from the training envs'. Each env plays a fixed quota of episodes, so short episodes are not
over-represented.

An evaluation during training is the deterministic `canter eval --episodes K --seed 0` of the train state at that
step (`DURING_TRAINING_SEED`), on run.eval_backend's backend where set (`--backend`): the same eval envs at every
evaluation and in every run, so evaluations compare across steps, seeds and trials, and any of them can be repeated
from a checkpoint of that step.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from canter.core.seeding import EVAL, env_seeds
from canter.envs.base import JaxVecEnv
from canter.errors import CanterError
from canter.training.cadence import Cadence

MAX_EVAL_ENVS = 32  # envs stepped from the host
# JAX-native envs: one env per episode, so the program steps one episode's length, not several one after another
# (on a GPU each step is a few ms of latency whatever the batch).
MAX_JAX_EVAL_ENVS = 1024
DURING_TRAINING_SEED = 0
# metrics.csv columns of a run with run.eval_every > 0, empty in rows without an evaluation.
EVAL_COLUMNS = ("eval/return_mean", "eval/return_std", "eval/length_mean", "eval/episodes")


@dataclass(frozen=True)
class EvalResult:
    returns: np.ndarray
    lengths: np.ndarray
    wall_seconds: float
    backend: str  # the env backend that played the episodes
    # The physics settings the envs were made with apart from the model's own (env.solver_*, env.contacts).
    physics: dict[str, Any] = field(default_factory=dict)

    @property
    def mean(self) -> float:
        return float(self.returns.mean())

    def __repr__(self) -> str:
        return (
            f"EvalResult(episodes={self.returns.size}, return {self.mean:.1f} ± {self.std:.1f}, length "
            f"{self.lengths.mean():.1f}, backend={self.backend!r}, wall_seconds={self.wall_seconds:.2f})"
        )

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
            "backend": self.backend,
            "physics": dict(self.physics),
            "returns": [float(r) for r in self.returns],
            "lengths": [int(n) for n in self.lengths],
        }

    def columns(self) -> dict[str, float]:
        """The values of EVAL_COLUMNS."""
        values = (self.mean, self.std, float(self.lengths.mean()), int(self.returns.size))
        return dict(zip(EVAL_COLUMNS, values))


@dataclass(frozen=True)
class TracedAct:
    """A deterministic policy as a pure JAX function `fn(args, obs) -> action`, for envs that play whole episodes
    inside one jitted program. `fn` must be the same object from one evaluation to the next (it keys the compiled
    program); the changing arrays (parameters, normalizer statistics) go in `args`."""

    fn: Callable[[Any, Any], Any]
    args: Any


def _deterministic_act(act: Callable[..., Any], args: Any, obs: Any) -> Any:
    """`act(params, obs_stats, obs, key, deterministic)` of `Algorithm.make_act`, with args = (params, obs_stats,
    key), acting deterministically."""
    params, obs_stats, key = args
    return act(params, obs_stats, obs, key, True)


class CompiledAct:
    """An algorithm's act for one config and env, jitted for calls from the host, and as the pure deterministic
    function that a JAX env traces into the program that plays its episodes (`traced`)."""

    def __init__(self, config: Any, spec: Any) -> None:
        import jax

        from canter.algos import get_algorithm

        pure_act = get_algorithm(config.run.algo).make_act(config, spec)
        self._jitted = jax.jit(pure_act, static_argnums=(4,))
        self._traced = functools.partial(_deterministic_act, pure_act)
        self._key = jax.random.key(0)  # what a deterministic act is given: it draws nothing from it

    def __call__(
        self, params: Any, obs_stats: Any, obs: np.ndarray, key: Any = None, deterministic: bool = True
    ) -> np.ndarray:
        key = self._key if key is None else key
        return np.asarray(self._jitted(params, obs_stats, np.asarray(obs, np.float32), key, deterministic))

    def traced(self, params: Any, obs_stats: Any) -> TracedAct:
        return TracedAct(self._traced, (params, obs_stats, self._key))


def eval_env_count(backend: str, episodes: int) -> int:
    """How many envs play an evaluation of `episodes` episodes on `backend` (a resolved name, not auto)."""
    from canter.envs.registry import get_backend

    return min(episodes, MAX_JAX_EVAL_ENVS if get_backend(backend).jax_native else MAX_EVAL_ENVS)


# How a user gives a Gymnasium env a step limit: canter's config has no key that sets one.
STEP_LIMIT_FIX = "register it with max_episode_steps=N (gymnasium.register(..., max_episode_steps=N))"


def check_episodes_end(env_id: str, backend: str, played: str = "an evaluation episode", instead: str = "") -> None:
    """A one-line error, before any env is made, where env_id's episodes have no step limit on `backend` (or what
    `auto` picks): an evaluation plays whole episodes, and one that never ends would hang it. `played` names what
    would play them; `instead` is another way out, after the registration's (", or ..."). An env or backend that
    cannot play it is left to where its env is made, which says why."""
    from canter.envs.registry import get_backend, resolve_backend

    try:
        resolved = resolve_backend(env_id, backend)
    except CanterError:
        return
    if get_backend(resolved).unlimited_episodes(env_id):
        raise CanterError(f"{env_id} has no episode step limit, so {played} may never end; {STEP_LIMIT_FIX}{instead}")


def run_episodes(
    act: Callable[[np.ndarray], np.ndarray],
    env_id: str,
    backend: str,
    episodes: int,
    seed: int,
    purpose: int = EVAL,
    sizes: tuple[int, int] | None = None,
    env_kwargs: dict[str, Any] | None = None,
    traced_act: TracedAct | None = None,
) -> EvalResult:
    """Play exactly `episodes` episodes with `act(obs_batch) -> actions`. `sizes` (obs_dim, act_dim) are checked
    against the env; `env_kwargs` go to the env backend. Where the env is JAX (`play_episodes`) and `traced_act`
    gives the same policy as a pure function, the episodes run in one jitted program instead of from the host."""
    from canter.envs.registry import MODEL_OWN_PHYSICS, make_vec_env, resolve_backend

    backend = resolve_backend(env_id, backend)
    check_episodes_end(env_id, backend)
    physics = {key: value for key, value in (env_kwargs or {}).items() if key in MODEL_OWN_PHYSICS}
    num_envs = eval_env_count(backend, episodes)
    quota = np.full(num_envs, episodes // num_envs)
    quota[: episodes % num_envs] += 1
    started = time.perf_counter()
    env = make_vec_env(env_id, backend, num_envs, env_seeds(seed, num_envs, purpose), **(env_kwargs or {}))
    try:
        if sizes is not None and (env.spec.obs_dim, env.spec.act_dim) != sizes:
            raise CanterError(
                f"{env_id} has observation/action sizes {env.spec.obs_dim}/{env.spec.act_dim}, the "
                f"policy expects {sizes[0]}/{sizes[1]}; pick a matching --env (env_id= for evaluate)"
            )
        if traced_act is not None and isinstance(env, JaxVecEnv):
            played = env.play_episodes(traced_act.fn, traced_act.args, quota)
            wall = time.perf_counter() - started
            return EvalResult(np.asarray(played[0]), np.asarray(played[1]), wall, env.spec.backend, physics)
        obs = env.reset()
        done_count = np.zeros(num_envs, int)
        running_return = np.zeros(num_envs)
        running_length = np.zeros(num_envs, int)
        prev_done = np.zeros(num_envs, bool)
        returns: list[float] = []
        lengths: list[int] = []
        while (done_count < quota).any():
            out = env.host_step(act(obs))
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
    wall = time.perf_counter() - started
    return EvalResult(np.asarray(returns), np.asarray(lengths), wall, env.spec.backend, physics)


def evaluation_backend(env_id: str, asked: str, own: str) -> str:
    """The backend that plays a run's evaluations during training: `asked` (run.eval_backend) where set, else the
    run's own; a one-line error when the asked backend cannot play env_id."""
    from canter.envs.registry import AUTO, get_backend, resolve_backend

    if not asked:
        return own
    backend = None if asked == AUTO or ":" in env_id else get_backend(asked)
    if backend is not None and not (backend.available() and env_id in backend.supported_ids()):
        why = "has no such env" if backend.available() else "is not installed"
        raise CanterError(
            f"run.eval_backend={asked} cannot play {env_id} ({backend.label} {why}); set it to auto, or leave it "
            "empty for the run's own backend"
        )
    return resolve_backend(env_id, asked)


class TrainingEvaluation:
    """Evaluation during training for one run: when it is due, the evaluation itself, and the best score so far.

    Due at the first iteration boundary at or past every multiple of `run.eval_every`, and at the end of the step
    budget; a run stopped early (signal, max_minutes, stop_at_return) ends without one."""

    def __init__(self, config: Any, spec: Any, start_step: int, best_return: float | None) -> None:
        from canter.algos import get_algorithm

        self.episodes = config.run.eval_episodes
        self.total_steps = config.run.total_steps
        from canter.envs.registry import env_options

        self.env_id = spec.id
        self.backend = evaluation_backend(spec.id, config.run.eval_backend, spec.backend)
        self.env_options = env_options(config.env, self.backend)
        self.cadence = Cadence(config.run.eval_every, start_step)
        self.best_return = -math.inf if best_return is None else best_return
        self._policy_params = get_algorithm(config.run.algo).policy_params
        self._act = CompiledAct(config, spec)

    def due(self, step: int) -> bool:
        return self.cadence.due(step) or step >= self.total_steps

    def evaluate(self, train_state: Any, step: int) -> EvalResult:
        """The deterministic evaluation of `train_state` (its policy and frozen normalizer statistics)."""
        self.cadence = self.cadence.advance(step)
        params, obs_stats = self._policy_params(train_state), train_state.obs_stats
        return run_episodes(
            lambda obs: self._act(params, obs_stats, obs),
            self.env_id,
            self.backend,
            self.episodes,
            DURING_TRAINING_SEED,
            env_kwargs=self.env_options,
            traced_act=self._act.traced(params, obs_stats),
        )

    def improves(self, result: EvalResult) -> bool:
        """Whether `result` beats every earlier evaluation of the run (which then becomes the best)."""
        if result.mean > self.best_return:
            self.best_return = result.mean
            return True
        return False
