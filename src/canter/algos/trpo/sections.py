"""What trpo declares to the config: the `trpo` section, its checks, search space and plot labels. It reads the
`net` section and four `ppo.*` keys (rollout length, discount, GAE lambda, advantage normalization) of ppo's
sections. Plain Python: the CLI reads it without importing JAX."""

from __future__ import annotations

import math
from dataclasses import dataclass

from canter.algos.ppo.sections import ROLLOUT_KEYS, largest_divisor, rollout_batch
from canter.config.algorithms import AlgorithmSpec, register_algorithm
from canter.config.fields import setting
from canter.config.schema import Config, register_section
from canter.config.validate import need, need_positive


@dataclass(frozen=True)
class TRPOConfig:
    """trpo: natural gradient by conjugate gradient, backtracking line search, Adam critic. Rollout and GAE use
    ppo.n_steps, ppo.gamma, ppo.gae_lambda and ppo.norm_adv."""

    max_kl: float = setting(
        "Trust region: a step is accepted only if the mean KL(old || new) is at most this.", default=0.01
    )
    cg_iters: int = setting("Maximum conjugate-gradient iterations for the natural gradient.", default=10)
    cg_damping: float = setting("Damping added to the Fisher-vector product (F + damping I).", default=0.1)
    line_search_iters: int = setting("Backtracking line-search steps before the update is rejected.", default=10)
    line_search_shrink: float = setting("Step-size factor per backtracking step.", default=0.8)
    critic_lr: float = setting("Adam learning rate of the critic's regression on the GAE returns.", default=1e-3)
    critic_epochs: int = setting("Passes over the batch for the critic per iteration.", default=10)
    critic_minibatch_size: int = setting("Samples per critic minibatch; must divide the batch.", default=128)


def check_trpo(trpo: TRPOConfig, name: str) -> None:
    need_positive(f"{name}.max_kl", trpo.max_kl)
    need(trpo.cg_iters >= 1, f"{name}.cg_iters must be >= 1, got {trpo.cg_iters}")
    need(
        math.isfinite(trpo.cg_damping) and trpo.cg_damping >= 0,
        f"{name}.cg_damping must be >= 0, got {trpo.cg_damping}",
    )
    need(trpo.line_search_iters >= 1, f"{name}.line_search_iters must be >= 1, got {trpo.line_search_iters}")
    need(0 < trpo.line_search_shrink < 1, f"{name}.line_search_shrink must be in (0, 1), got {trpo.line_search_shrink}")
    need_positive(f"{name}.critic_lr", trpo.critic_lr)
    need(trpo.critic_epochs >= 1, f"{name}.critic_epochs must be >= 1, got {trpo.critic_epochs}")
    need(
        trpo.critic_minibatch_size >= 1, f"{name}.critic_minibatch_size must be >= 1, got {trpo.critic_minibatch_size}"
    )


def _check_critic_minibatch(config: Config) -> None:
    trpo, batch = config.trpo, rollout_batch(config)
    need(
        batch % trpo.critic_minibatch_size == 0,
        f"trpo.critic_minibatch_size {trpo.critic_minibatch_size} does not divide the batch {batch} "
        f"(ppo.n_steps {config.ppo.n_steps} x env.num_envs {config.env.num_envs}); pick a divisor, e.g. "
        f"--set trpo.critic_minibatch_size={largest_divisor(batch, trpo.critic_minibatch_size)}",
    )


register_section("trpo", TRPOConfig, check_trpo)

TRPO = AlgorithmSpec(
    name="trpo",
    summary="Trust Region Policy Optimization (conjugate gradient, line search)",
    runtime="canter.algos.trpo",
    reads=("net", "trpo", "ppo.n_steps", "ppo.gamma", "ppo.gae_lambda", "ppo.norm_adv"),
    validate=_check_critic_minibatch,
    search_space=("canter.algos.trpo", "search_space.toml"),
    iteration_steps=rollout_batch,
    iteration_keys=ROLLOUT_KEYS,
    plot_labels={
        "surrogate_gain": ("Surrogate gain", "advantage units"),
        "policy_kl": ("Policy KL (old ‖ new)", "nats"),
        "value_loss": ("Value loss", "loss (squared return units)"),
        "entropy": ("Policy entropy", "nats"),
        "explained_variance": ("Explained variance", "1 − Var[R − V] / Var[R]"),
    },
    rollout_batch=rollout_batch,
    batch_divisors=("trpo.critic_minibatch_size",),
)
register_algorithm(TRPO)
