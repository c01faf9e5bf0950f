"""Trust Region Policy Optimization (Schulman et al. 2015) with GAE and an Adam-trained critic.

The actor is the same diagonal Gaussian as ppo's, so acting, export and `canter.load` are shared with it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from canter.algos import Algorithm
from canter.algos.ppo import (
    export_gaussian_actor,
    gaussian_policy_params,
    make_gaussian_act,
)
from canter.config.schema import Config

TRPO_METRICS = (
    "surrogate_gain",
    "policy_kl",
    "step_accepted",
    "step_fraction",
    "line_search_steps",
    "cg_iterations",
    "cg_residual",
    "value_loss",
    "entropy",
    "explained_variance",
)


def _init_state(config: Config, spec: Any, seed: Any) -> Any:
    from canter.algos.trpo.iteration import init_train_state

    return init_train_state(config, spec.obs_dim, spec.act_dim, seed)


def _nothing_to_check(config: Config, spec: Any) -> None:
    """trpo reads no key that depends on the env (sym, which does, is ppo's and rpo's alone)."""


def _make_iteration(config: Config, spec: Any, env_step: Any) -> Callable[..., Any]:
    from canter.algos.trpo.iteration import make_iteration

    return make_iteration(config, spec, env_step)


def _make_parts(config: Config, spec: Any, env_step: Any) -> tuple[Callable[..., Any], Callable[..., Any]]:
    from canter.algos.trpo.iteration import make_parts

    return make_parts(config, spec, env_step)


ALGORITHMS = {
    "trpo": Algorithm(
        name="trpo",
        init_state=_init_state,
        make_iteration=_make_iteration,
        make_parts=_make_parts,
        metric_names=TRPO_METRICS,
        make_act=make_gaussian_act,
        policy_params=gaussian_policy_params,
        export_actor=export_gaussian_actor,
        validate=_nothing_to_check,
        size_keys=(("params", "net.hidden"), ("critic_opt_state", "net.hidden")),
    ),
}
