"""The `Algorithm` record of an off-policy algorithm, built around its `OffPolicyLearner`, with the acting, export
and checks that td3, ddpg and sac share."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from canter.algos.offpolicy.iteration import init_train_state, make_iteration
from canter.algos.offpolicy.learner import LOOP_METRICS, OffPolicyLearner
from canter.algos.offpolicy.sections import OffPolicyConfig
from canter.algos.protocol import Algorithm, ExportedActor, export_mlp_actor
from canter.config.algorithms import algorithm_spec
from canter.config.schema import Config
from canter.envs.base import EnvSpec
from canter.errors import CanterError


def offpolicy_algorithm(
    name: str, make_learner: Callable[[Config, Any], OffPolicyLearner], update_metrics: tuple[str, ...]
) -> Algorithm:
    """The `Algorithm` record of the algorithm whose learner `make_learner(config, spec)` builds."""

    def init_state(config: Config, spec: Any, seed: Any) -> Any:
        return init_train_state(config, make_learner(config, spec), spec.obs_dim, spec.act_dim, seed)

    def iteration(config: Config, spec: Any, env_step: Any) -> Callable[..., Any]:
        return make_iteration(config, make_learner(config, spec), spec, env_step)

    def make_act(config: Config, spec: Any) -> Callable[..., Any]:
        return _make_act(config, make_learner(config, spec), spec)

    def export_actor(config: Config, state: Any, spec: Any) -> ExportedActor:
        return _export_tanh_actor(config, make_learner(config, spec).cfg, state, spec)

    def validate(config: Config, spec: EnvSpec) -> None:
        _validate_bounded_actions(name, spec)

    def filled_rows(config: Config) -> dict[str, int]:
        # One buffer row per env step the run counts, and the run ends with the iteration that reaches its budget:
        # at most one iteration's steps past the last step below it.
        reached = config.run.total_steps - 1 + algorithm_spec(name).iteration_steps(config)
        return {"buffer": min(config.section(name).buffer_size, reached)}

    return Algorithm(
        name=name,
        init_state=init_state,
        make_iteration=iteration,
        metric_names=update_metrics + LOOP_METRICS,
        make_act=make_act,
        policy_params=_policy_params,
        export_actor=export_actor,
        validate=validate,
        donate_state=True,
        policy_checkpoint_leaves_out=("buffer",),
        size_keys=(("buffer", f"{name}.buffer_size"), ("learner", f"{name}.hidden"), ("ou_state", "env.num_envs")),
        filled_rows=filled_rows,
    )


def _make_act(config: Config, learner: OffPolicyLearner, spec: Any) -> Callable[..., Any]:
    """`act(actor, obs_stats, raw_obs, key, deterministic)`: the learner's action mapped onto the action bounds."""
    import jax.numpy as jnp

    from canter.core.normalize import normalize_obs

    low = jnp.asarray(spec.action_low, jnp.float32)
    high = jnp.asarray(spec.action_high, jnp.float32)
    center, half = (high + low) / 2.0, (high - low) / 2.0

    def act(actor: Any, obs_stats: Any, obs: Any, key: Any, deterministic: bool) -> Any:
        action = learner.act(actor, normalize_obs(config, obs_stats, obs), key, deterministic)
        return jnp.clip(center + half * action, low, high)

    return act


def _policy_params(state: Any) -> Any:
    return state.learner.actor


def _export_tanh_actor(config: Config, section: OffPolicyConfig, state: Any, spec: Any) -> ExportedActor:
    """Every off-policy actor is a tanh-squashed MLP whose first `act_dim` outputs are the deterministic action."""
    import jax

    actor, stats = jax.device_get((state.learner.actor, state.obs_stats))
    return export_mlp_actor(config, actor, stats, spec, section.activation, squash=True)


def _validate_bounded_actions(name: str, spec: EnvSpec) -> None:
    """Bounded actions are required: the actors map tanh outputs onto [low, high]."""
    low, high = np.asarray(spec.action_low), np.asarray(spec.action_high)
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(high > low)):
        raise CanterError(
            f"{name} needs finite action bounds (it squashes actions with tanh); "
            f"{spec.id} has low={low.tolist()} high={high.tolist()}; give the env a finite action box with high > "
            f"low, or train it with --algo ppo, rpo or trpo, whose Gaussian policies need no bounds"
        )
