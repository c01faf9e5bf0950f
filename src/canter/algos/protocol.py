"""The runtime record of an algorithm, which the trainer, run folders and `canter.load` use.

Every algorithm plugs into the same trainer, run folder, checkpoints, logging and `canter.load` through one
`Algorithm` record. The trainer knows nothing else about an algorithm:

- `init_state(config, spec, seed)` builds the train state of run seed `seed`: a NamedTuple pytree that a checkpoint
  holds in full. It must have the fields `obs_stats` (a `RunningStats`, used by the policy), `iteration` and
  `global_step`. The trainer jits it with `seed` a traced uint32 scalar (the seeds of a group share one compile), so
  it must stay pure JAX, build the same state from a Python int, and not read `config.run.seed`.
- `make_iteration(config, spec, env_step)` returns `iteration(state, carry, lr_fraction) -> (state, carry, metrics)`,
  a pure function the trainer jits. One call is the unit between which the host logs, checkpoints and checks for
  signals. `metrics` holds `steps` (env steps taken, autoreset steps excluded), `finite` (bool), `finished`,
  `episode_return`, `episode_length` (arrays [T, N]) and `episode_info` (dict of [T, N]), plus one scalar per name
  in `metric_names`. Several seeds train together by `jax.vmap` over this function (canter.training.seedgroup), so it
  must stay pure JAX and must not read `config.run.seed` either.
- `make_parts(config, spec, env_step)`, where the iteration is a rollout and then an update that never steps the
  env (ppo, rpo, trpo), returns them as `rollout(state, carry) -> (state, carry, collected)` and
  `learn(state, collected, lr_fraction) -> (state, metrics)`, the iteration being `learn` after `rollout`. The
  trainer compiles them as two programs for an env whose step is not JAX (EnvPool, Gymnasium): a program holding
  that step embeds the env's address, so it is compiled again by every process, while `learn` alone can be kept in
  the compile cache and found again by a resume, a rerun or another seed's process. None where the update is
  interleaved with the env steps (td3, sac, ddpg).
- `metric_names`: the algorithm's diagnostics, written as metrics.csv columns in this order.
- `make_act(config, spec)` returns `act(policy_params, obs_stats, raw_obs, key, deterministic) -> action`, clipped
  to the action bounds; `policy_params(state)` picks what it needs out of the train state.
- `export_actor(config, state, spec)` describes the deterministic actor as plain arrays (`ExportedActor`), for ONNX and
  npz export.
- `donate_state`, `policy_checkpoint_leaves_out`, `size_keys`, `filled_rows`: see the fields' comments.
- `validate(config, spec)` refuses a config that makes no sense for this algorithm or env, before any work starts;
  the trainer passes the env's `EnvSpec`.

Elsewhere, where a `spec` is passed, only `obs_dim`, `act_dim`, `action_low` and `action_high` may be read: a loaded
policy passes its `PolicyFacts` instead of an `EnvSpec`.

What an algorithm declares without JAX (its config sections, the keys it reads, checks, search space, preset tables,
plot labels) is its `AlgorithmSpec` (`canter.config.algorithms`), built in its folder's `sections.py`.
`canter.algos.registry` lists those modules, one line per algorithm folder.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from canter.config.schema import Config
from canter.envs.base import EnvSpec


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
    output_slice: int  # keep only the first `output_slice` outputs (a head may also predict the log std)


@dataclass(frozen=True)
class Algorithm:
    name: str
    init_state: Callable[..., Any]
    make_iteration: Callable[..., Any]
    metric_names: tuple[str, ...]
    make_act: Callable[..., Any]
    policy_params: Callable[[Any], Any]
    export_actor: Callable[..., ExportedActor]
    validate: Callable[[Config, EnvSpec], None]
    make_parts: Callable[..., Any] | None = None  # see the module's docstring
    # Donate the train state to jit so large arrays (a replay buffer) are updated in place, not copied per call.
    # The input state is then invalid after the call, so an iteration reporting `finite` False must return the
    # last good state itself: the trainer checkpoints the returned state in that case.
    donate_state: bool = False
    # Fields of the train state that only further training reads (a replay buffer): the checkpoints that are only
    # ever read for their policy (best.npz, a video's snapshot) leave them out, which for td3 at a 1M buffer on
    # Walker2d-v5 keeps 160 MiB from being written at every better evaluation.
    policy_checkpoint_leaves_out: tuple[str, ...] = ()
    # The config key that sets the size of each large field of the train state (("buffer", "td3.buffer_size"), ...):
    # a train state too large for the memory is refused naming the key behind most of it (canter.algos.state_size).
    size_keys: tuple[tuple[str, str], ...] = ()
    # The most leading rows that each field filling one row per env step from the front (a replay buffer) holds when
    # the run ends, from its config: {"buffer": rows}. A checkpoint writes only the filled rows of such a field, so a
    # run whose run.total_steps stays below the capacity never writes it whole, and the disk warning counts these.
    filled_rows: Callable[[Config], dict[str, int]] | None = None


def export_mlp_actor(
    config: Any, actor: Any, obs_stats: Any, spec: Any, activation: str, squash: bool
) -> ExportedActor:
    """An MLP actor (a list of {"w", "b"} layers) and its observation statistics, on the host, as plain arrays; its
    first `act_dim` outputs are the deterministic action."""
    from canter.core.normalize import EPSILON

    return ExportedActor(
        weights=[np.asarray(layer["w"], np.float32) for layer in actor],
        biases=[np.asarray(layer["b"], np.float32) for layer in actor],
        activation=activation,
        squash=squash,
        normalize=config.env.normalize_obs,
        obs_mean=np.asarray(obs_stats.mean, np.float32),
        obs_var=np.asarray(obs_stats.var, np.float32),
        obs_eps=EPSILON,
        clip_obs=config.env.clip_obs,
        action_low=np.asarray(spec.action_low, np.float32),
        action_high=np.asarray(spec.action_high, np.float32),
        output_slice=spec.act_dim,
    )
