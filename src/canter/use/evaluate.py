"""Evaluate a policy on fresh envs with frozen normalizer statistics (the protocol of `canter.training.evaluation`)."""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from canter.core.runtime import setup_jax
from canter.core.seeding import EVAL, HELD_OUT, check_seed
from canter.errors import CanterError
from canter.training.evaluation import EvalResult, check_episodes_end, run_episodes
from canter.training.restore import PolicyFacts
from canter.use.policy import Policy

__all__ = ["EvalResult", "check_eval_env", "eval_physics", "eval_target", "evaluate", "parse_physics", "seed_stream"]


def seed_stream(policy: Policy) -> str:
    """`held-out` for a checkpoint chosen on evaluations during training (best.npz), whose score on the episodes
    that chose it would be biased upward; `eval` otherwise."""
    return "held-out" if policy.chosen_by_evaluation else "eval"


def check_eval_env(facts: PolicyFacts, env_id: str | None, backend: str | None, varied: bool = False) -> None:
    """A policy trained on a backend whose envs observe in their own way (Brax) reads no other backend's
    observations, so it evaluates on the env and backend it trained on only: a one-line error otherwise. So is an
    evaluation that would play a mujoco-py version of a MuJoCo task on Gymnasium, which no longer makes it."""
    from canter.envs.registry import AUTO, get_backend

    trained_on = get_backend(facts.backend)
    if not trained_on.own_observations:
        played_on = get_backend(backend) if backend not in (None, AUTO) else None
        # Where it is not installed, that is said first (resolve_backend), as it is of any backend.
        if played_on is not None and played_on.own_observations and played_on.available():
            raise CanterError(
                f"{played_on.label} observations differ from Gymnasium's, so a run trained on {trained_on.name} "
                f"({facts.env_id}) does not evaluate on {played_on.name}; drop --backend {backend} (backend= for "
                f"evaluate)"
            )
        _refuse_mujoco_py(facts, env_id, backend, varied)
        return
    asked = [
        flag
        for flag, elsewhere in (
            (f"--env {env_id} (env_id=)", env_id not in (None, facts.env_id)),
            (f"--backend {backend} (backend=)", backend not in (None, trained_on.name)),
            ("--vary", varied),
        )
        if elsewhere
    ]
    if asked:
        raise CanterError(
            f"{trained_on.label} observations differ from Gymnasium's, so {trained_on.name} runs evaluate on the "
            f"{trained_on.name} backend only, on the env they trained on ({facts.env_id}); drop {' and '.join(asked)}"
        )


def _refuse_mujoco_py(facts: PolicyFacts, env_id: str | None, backend: str | None, varied: bool) -> None:
    """The one-line error where the env played is a mujoco-py version (Hopper-v3) and the backend that plays it is
    Gymnasium (a sweep's, or the one asked for or picked), which fails to make it; EnvPool runs its own port."""
    from canter.envs.registry import AUTO, mujoco_py_id

    played = env_id or facts.env_id
    if varied:
        refuse_mujoco_py_sweep(played)
        return
    old = mujoco_py_id(played, backend or (facts.backend if played == facts.env_id else AUTO))
    if old is None:
        return
    if old.ports:
        fix = f"pass --backend {old.ports} (backend= for evaluate), which runs its own {played}"
    else:
        fix = f"evaluate it on {old.newer} with --env (env_id= for evaluate)"
    raise CanterError(f"{old.problem}; {fix}")


def refuse_mujoco_py_sweep(env_id: str) -> None:
    """A one-line error where env_id is a mujoco-py version, which the Gymnasium env that a sweep edits cannot make."""
    from canter.envs.registry import refuse_mujoco_py_replay

    refuse_mujoco_py_replay(
        env_id,
        "--vary sweeps its MuJoCo model",
        "vary a run of {newer} instead",
        " (canter eval without --vary scores this one on {ports})",
    )


def check_policy(policy: Any) -> None:
    """A one-line error where something else than a loaded `Policy` is given (a run folder's path, most likely)."""
    if isinstance(policy, str | Path):
        raise CanterError(
            f"evaluate takes a Policy, got the path {str(policy)!r}; load it first: "
            f"canter.evaluate(canter.load({str(policy)!r}))"
        )
    if not isinstance(policy, Policy):
        raise CanterError(f"evaluate takes a Policy (canter.load(RUN)), got {type(policy).__name__}")


def parse_physics(settings: Mapping[str, Any]) -> dict[str, Any]:
    """`{"solver_iterations": "4"}` (or `env.solver_iterations`, as `--set` spells it) as typed physics settings, or
    a one-line error for a key that is not one of the env's physics settings or a value of the wrong type."""
    from canter.config.schema import field_types
    from canter.config.values import coerce
    from canter.envs.registry import MODEL_OWN_PHYSICS

    types = field_types("env")
    physics = {}
    for key, value in settings.items():
        if not isinstance(key, str):
            raise CanterError(f"physics takes setting names such as 'solver_iterations' as its keys, got {key!r}")
        name = key.removeprefix("env.")
        if name not in MODEL_OWN_PHYSICS:
            names = ", ".join(f"env.{known}" for known in MODEL_OWN_PHYSICS)
            raise CanterError(
                f"an evaluation takes the physics settings {names} only, got '{key}'; the rest is the run's own"
            )
        physics[name] = coerce(f"env.{name}", types[name], value)
    return physics


def eval_target(policy: Policy, env_id: str | None, backend: str | None) -> tuple[str, str]:
    """The env and backend an evaluation plays: the ones asked for, else the run's own env, on the run's own backend
    for its own env and on `auto` for another."""
    env_id = env_id or policy.facts.env_id
    return env_id, backend or (policy.facts.backend if env_id == policy.facts.env_id else "auto")


def check_eval_ends(policy: Policy, env_id: str | None, backend: str | None) -> None:
    """`check_episodes_end` for the env that an evaluation of `policy` plays (`eval_target`), before any is played:
    `canter eval` refuses all its runs at once."""
    check_episodes_end(*eval_target(policy, env_id, backend))


def eval_physics(policy: Policy, env_id: str, backend: str, changes: Mapping[str, Any]) -> dict[str, Any]:
    """The physics settings to make the eval envs with, as `make`'s keyword arguments: the run's own where the env is
    its env and the backend takes them (mjx's solver iterations, contacts), with `changes` (typed, `parse_physics`)
    over them. A change the backend cannot make is a one-line error, as it is in a config."""
    from canter.config.schema import EnvConfig
    from canter.config.validate import check_physics
    from canter.envs.registry import env_options, get_backend

    trained_on = get_backend(policy.facts.backend)
    if changes and trained_on.own_observations and not trained_on.solver_options:
        raise CanterError(
            f"{trained_on.name} runs evaluate on the {trained_on.name} backend only, which takes no physics "
            f"settings; drop --set (physics= from Python)"
        )
    check_physics(dataclasses.replace(EnvConfig(), id=env_id, backend=backend, **changes))
    own = policy.config.env if env_id == policy.facts.env_id else EnvConfig()
    return env_options(dataclasses.replace(own, **changes), backend)


def evaluate(
    policy: Policy,
    episodes: int = 10,
    deterministic: bool = True,
    seed: int = 0,
    env_id: str | None = None,
    backend: str | None = None,
    prepare_env: Callable[[Any], None] | None = None,
    physics: Mapping[str, Any] | None = None,
) -> EvalResult:
    """Run exactly `episodes` episodes. Each env gets a fixed quota, so short episodes are not over-represented.

    The env seeds come from `seed` and the eval stream, or, for a best checkpoint, the held-out stream, which the
    evaluations that chose it never played (`seed_stream`).

    `prepare_env(env)` is called on every Gymnasium env right after it is made and before its first reset (the
    robustness sweeps edit the MuJoCo model there); it forces the backend that builds single envs (Gymnasium).

    `physics` changes the physics settings of the eval envs, e.g. `{"solver_iterations": 4}` (`parse_physics`);
    without it they are the run's own on its env where the backend takes them, else the model's own."""
    from canter.envs.registry import note_replay, resolve_backend, single_env_backend

    check_policy(policy)
    if not isinstance(deterministic, bool | np.bool_):  # a string such as "no" would read as true
        raise CanterError(f"deterministic must be True or False, got {deterministic!r}")
    if isinstance(episodes, bool) or not isinstance(episodes, int | np.integer) or episodes < 1:
        raise CanterError(f"episodes must be a whole number >= 1, got {episodes!r}")
    seed = check_seed(seed)
    for name, value in (("env_id", env_id), ("backend", backend)):
        if value is not None and not isinstance(value, str):
            raise CanterError(f"{name} must be a name (a string) or None for the run's own, got {value!r}")
        if value == "":  # it would read as not given
            raise CanterError(f"{name} is empty; give one, or leave it out (None) for the run's own")
    if physics is not None and not isinstance(physics, Mapping):
        raise CanterError(f"physics must be a mapping of settings to values, got {type(physics).__name__}")
    check_eval_env(policy.facts, env_id, backend, varied=prepare_env is not None)
    env_id, backend = eval_target(policy, env_id, backend)
    changes = parse_physics(physics or {})
    if prepare_env is not None and changes:
        raise CanterError("a robustness sweep plays the Gymnasium env, which takes no physics settings; drop them")
    if prepare_env is not None:
        backend, extra = single_env_backend().name, {"on_make": prepare_env}
    else:
        extra = eval_physics(policy, env_id, backend, changes)
    if env_id == policy.facts.env_id:
        note_replay(env_id, policy.facts.backend, backend)
    first_call = [not deterministic]
    sampler = copy.copy(policy)  # a sampling stream of its own: evaluating leaves the caller's policy as it was

    def act(obs: np.ndarray) -> np.ndarray:
        if first_call[0]:
            sampler(obs[:1], deterministic=False, seed=seed)  # seed the sampling stream
            first_call[0] = False
        return sampler(obs, deterministic=deterministic)

    # The precision of the backend it plays on, not the one it loaded for: MJX in float32 for an EnvPool policy.
    setup_jax(resolve_backend(env_id, backend))
    purpose = HELD_OUT if policy.chosen_by_evaluation else EVAL
    traced = policy.traced() if deterministic and prepare_env is None else None
    sizes = (policy.obs_dim, policy.act_dim)
    return run_episodes(act, env_id, backend, episodes, seed, purpose, sizes, extra, traced_act=traced)
