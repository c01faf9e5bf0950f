"""The algorithm registry.

Every algorithm plugs into the same trainer, run folder, checkpoints, logging and `canter.load` through one
`Algorithm` record. The trainer knows nothing else about an algorithm:

- `init_state(config, spec)` builds the train state: a NamedTuple pytree that a checkpoint holds in full. It must
  have the fields `obs_stats` (a `RunningStats`, used by the policy), `iteration` and `global_step`.
- `make_iteration(config, spec, env_step)` returns `iteration(state, carry, lr_fraction) -> (state, carry, metrics)`,
  a pure function the trainer jits. One call is the unit between which the host logs, checkpoints and checks for
  signals. `metrics` holds `steps` (env steps taken, autoreset steps excluded), `finite` (bool), `finished`,
  `episode_return`, `episode_length` (arrays [T, N]) and `episode_info` (dict of [T, N]), plus one scalar per name
  in `metric_names`. Several seeds train together by `jax.vmap` over this function (canter.training.seedgroup), so it
  must stay pure JAX and must not read `config.run.seed` (the seed belongs in `init_state`).
- `metric_names`: the algorithm's diagnostics, written as metrics.csv columns in this order.
- `make_act(config, spec)` returns `act(policy_params, obs_stats, raw_obs, key, deterministic) -> action`, clipped
  to the action bounds; `policy_params(state)` picks what it needs out of the train state.
- `export_actor(config, state, spec)` describes the deterministic actor as plain arrays (`ExportedActor`), for ONNX and
  npz export.
- `donate_state`: see the field's comment.
- `validate(config, spec)` refuses a config that makes no sense for this algorithm or env, before any work starts.
  `spec` is None when only the config is known.

Where a `spec` is passed, only `obs_dim`, `act_dim`, `action_low` and `action_high` may be read: a loaded policy
passes its `PolicyFacts` instead of an `EnvSpec`.

The names and module paths are listed here so that an unknown `--algo` can be refused without importing JAX.
"""

from __future__ import annotations

import difflib
import importlib
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from canter.errors import CanterError

# name -> (module that defines ALGORITHMS, one-line summary)
REGISTRY: dict[str, tuple[str, str]] = {
    "ppo": ("canter.algos.ppo", "Proximal Policy Optimization (clipped, or adaptive KL penalty)"),
    "rpo": ("canter.algos.ppo", "Robust Policy Optimization: PPO with a uniformly shifted mean in the update"),
    "trpo": ("canter.algos.trpo", "Trust Region Policy Optimization (conjugate gradient, line search)"),
    "td3": ("canter.algos.offpolicy", "Twin Delayed DDPG (off-policy, replay buffer)"),
    "ddpg": ("canter.algos.offpolicy", "Deep Deterministic Policy Gradient (off-policy, replay buffer)"),
    "sac": ("canter.algos.offpolicy", "Soft Actor-Critic with automatic entropy tuning (off-policy)"),
}

# Algorithms whose seeds `canter bench` trains as separate jobs instead of one vmapped group. Under the vmap the
# off-policy step's `lax.cond`s (warm-up, td3's delayed actor step) see a per-seed predicate and become selects that
# compute both branches, and stacking seeds' 256-wide products gains nothing on a CPU core: two td3 seeds in one
# group trained at 0.67x the steps per second of one seed alone on the same core (docs/multiseed.md).
SEEDS_TRAIN_APART = frozenset({"td3", "ddpg", "sac"})


def seeds_train_apart(name: str) -> bool:
    return name in SEEDS_TRAIN_APART


# What each algorithm reads of the config, beyond env.* and run.*, which all read: whole sections, or single keys.
# The off-policy algorithms take their networks from their own section, not from net.* (PPO's defaults). A --set
# of anything else is refused, since it would change nothing (canter.config.schema.reads_key).
READS: dict[str, tuple[str, ...]] = {
    "ppo": ("net", "ppo", "sym"),
    "rpo": ("net", "ppo", "rpo", "sym"),
    "trpo": ("net", "trpo", "ppo.n_steps", "ppo.gamma", "ppo.gae_lambda", "ppo.norm_adv"),
    "td3": ("td3",),
    "ddpg": ("ddpg",),
    "sac": ("sac",),
}


@dataclass(frozen=True)
class ExportedActor:
    """A deterministic actor as plain arrays: `x = clip((obs - mean) / sqrt(var + eps), -clip_obs, clip_obs)` when
    `normalize` is set, then dense layers with `activation` between them, then `tanh` and an affine map onto
    [low, high] when `squash` is set, and finally a clip to [low, high]."""
    weights: list[np.ndarray]
    biases: list[np.ndarray]
    activation: str
    squash: bool
    normalize: bool
    obs_mean: np.ndarray
    obs_var: np.ndarray
    obs_eps: float
    clip_obs: float
    action_low: np.ndarray
    action_high: np.ndarray
    output_slice: int   # keep only the first `output_slice` outputs (a head may also predict the log std)


@dataclass(frozen=True)
class Algorithm:
    name: str
    on_policy: bool
    init_state: Callable[..., Any]
    make_iteration: Callable[..., Any]
    metric_names: tuple[str, ...]
    make_act: Callable[..., Any]
    policy_params: Callable[[Any], Any]
    export_actor: Callable[..., ExportedActor]
    validate: Callable[..., None]
    # Donate the train state to jit so large arrays (a replay buffer) are updated in place, not copied per call.
    # The input state is then invalid after the call, so an iteration reporting `finite` False must return the
    # last good state itself: the trainer checkpoints the returned state in that case.
    donate_state: bool = False


def algorithm_names() -> list[str]:
    return list(REGISTRY)


def check_algorithm_name(name: str) -> None:
    if name not in REGISTRY:
        close = difflib.get_close_matches(name, list(REGISTRY), n=1, cutoff=0.5)
        hint = f"did you mean {close[0]}? " if close else ""
        raise CanterError(f"unknown algorithm '{name}'; {hint}choose one of: {', '.join(REGISTRY)}")


def get_algorithm(name: str) -> Algorithm:
    check_algorithm_name(name)
    module = importlib.import_module(REGISTRY[name][0])
    return module.ALGORITHMS[name]
