"""What ppo and rpo declare to the config: the `net`, `ppo`, `rpo` and `sym` sections, their checks, search
spaces, preset tables and plot labels. Plain Python: the CLI reads it without importing JAX."""

from __future__ import annotations

import math
from dataclasses import dataclass

from canter.algos.ppo.symmetry import parse_groups
from canter.config.algorithms import AlgorithmSpec, register_algorithm
from canter.config.fields import setting
from canter.config.presets import algorithm_preset_tables
from canter.config.schema import Config, register_section
from canter.config.validate import need, need_positive
from canter.core.netconfig import NetConfig, check_net


@dataclass(frozen=True)
class PPOConfig:
    n_steps: int = setting("Rollout steps per environment per iteration (batch = n_steps * num_envs).", default=2048)
    minibatch_size: int = setting("Samples per minibatch; must divide the batch.", default=64)
    epochs: int = setting("Passes over the batch per iteration.", default=10)
    lr: float = setting("Adam learning rate (actor, and critic unless critic_lr is set).", default=3e-4)
    critic_lr: float | None = setting("Separate critic learning rate; `none` uses lr.", default=None)
    anneal_lr: bool = setting("Anneal learning rates linearly to 0 over the run, once per iteration.", default=True)
    adam_eps: float = setting("Adam epsilon.", default=1e-5)
    gamma: float = setting("Discount factor.", default=0.99)
    gae_lambda: float = setting("GAE lambda.", default=0.95)
    clip: float = setting("Clipping range of the probability ratio.", default=0.2)
    clip_vloss: bool = setting("Clip the value loss around the old values, with the same range.", default=True)
    norm_adv: bool = setting("Normalize advantages per minibatch.", default=True)
    ent_coef: float = setting("Entropy bonus coefficient.", default=0.0)
    vf_coef: float = setting("Value loss coefficient.", default=0.5)
    max_grad_norm: float = setting("Global gradient-norm clip (actor and critic together).", default=0.5)
    target_kl: float | None = setting(
        "Stop the epochs of an iteration once approx KL exceeds this; `none` is off.", default=None
    )
    objective: str = setting(
        "Policy objective: `clip` (clipped surrogate) or `kl_penalty` (surrogate - beta * KL, "
        "with beta adapted after each iteration, PPO paper sec. 4).",
        default="clip",
    )
    kl_penalty_target: float = setting(
        "kl_penalty only: KL target d; beta halves when the iteration's mean KL < d/1.5 "
        "and doubles when it is > 1.5 d.",
        default=0.01,
    )
    kl_penalty_beta: float = setting(
        "kl_penalty only: initial beta (the current beta is part of the train state).", default=1.0
    )


@dataclass(frozen=True)
class RPOConfig:
    """rpo: PPO whose update re-evaluates stored actions under a randomly shifted mean (Rahman & Xue 2023)."""

    alpha: float = setting(
        "Half-width of the per-dimension shift z ~ U(-alpha, alpha) added to the policy mean when "
        "the update re-evaluates stored actions (rollouts sample from the unshifted policy).",
        default=0.5,
    )


@dataclass(frozen=True)
class SymConfig:
    """Symmetric action loss for ppo and rpo (report 000)."""

    coef: float = setting("Weight of the symmetric action loss; 0 turns it off.", default=0.0)
    groups: str = setting(
        "Mirrored action groups as `a:b=c:d` pairs of half-open index ranges of equal length, comma "
        "separated (a single index `i` means `i:i+1`), e.g. `3:7=7:11,11:14=14:17`.",
        default="",
    )
    negate: tuple[int, ...] = setting(
        "Indices on the right-hand side of a pair whose sign is flipped before comparing "
        "means (joints whose axis is mirrored, so mirrored motion is -a).",
        default=(),
    )
    compare: str = setting(
        "What is compared across a pair: `mean` (the policy means) or `log_prob` (per-dimension "
        "log-probabilities of the stored actions, as report 000 does).",
        default="mean",
    )


def check_ppo(ppo: PPOConfig, name: str) -> None:
    need(ppo.n_steps >= 1, f"{name}.n_steps must be >= 1, got {ppo.n_steps}")
    need(ppo.minibatch_size >= 1, f"{name}.minibatch_size must be >= 1, got {ppo.minibatch_size}")
    need(ppo.epochs >= 1, f"{name}.epochs must be >= 1, got {ppo.epochs}")
    for key in ("lr", "adam_eps", "clip", "max_grad_norm"):
        need_positive(f"{name}.{key}", getattr(ppo, key))
    if ppo.critic_lr is not None:
        need_positive(f"{name}.critic_lr", ppo.critic_lr)
    if ppo.target_kl is not None:
        need(ppo.target_kl > 0, f"{name}.target_kl must be > 0 or none, got {ppo.target_kl}")
    need(0 < ppo.gamma <= 1, f"{name}.gamma must be in (0, 1], got {ppo.gamma}")
    need(0 <= ppo.gae_lambda <= 1, f"{name}.gae_lambda must be in [0, 1], got {ppo.gae_lambda}")
    for key in ("ent_coef", "vf_coef"):
        need(getattr(ppo, key) >= 0, f"{name}.{key} must be >= 0, got {getattr(ppo, key)}")
    need(ppo.objective in ("clip", "kl_penalty"), f"{name}.objective must be clip or kl_penalty, got '{ppo.objective}'")
    for key in ("kl_penalty_target", "kl_penalty_beta"):
        need_positive(f"{name}.{key}", getattr(ppo, key))


def check_rpo(rpo: RPOConfig, name: str) -> None:
    need(math.isfinite(rpo.alpha) and rpo.alpha >= 0, f"{name}.alpha must be >= 0, got {rpo.alpha}")


def check_sym(sym: SymConfig, name: str) -> None:
    need(math.isfinite(sym.coef) and sym.coef >= 0, f"{name}.coef must be >= 0 (0 is off), got {sym.coef}")
    need(sym.compare in ("mean", "log_prob"), f"{name}.compare must be mean or log_prob, got '{sym.compare}'")
    pairs = parse_groups(sym.groups, sym.negate)
    need(sym.coef == 0 or bool(pairs), f"{name}.coef > 0 needs {name}.groups, e.g. {name}.groups=3:7=7:11")
    # A dimension compared with itself adds nothing to the loss, unless its mean is compared with its own negation
    # (a joint on the plane of symmetry, which the loss then pushes towards 0). With the loss off, groups are unread.
    for pair in pairs if sym.coef > 0 else ():
        for index, mirror, sign in zip(pair.first, pair.mirror, pair.signs):
            need(
                index != mirror or (sign < 0 and sym.compare == "mean"),
                f"{name}.groups pairs dimension {index} with itself, which adds nothing to the loss; drop it, or "
                f"(with {name}.compare=mean) list it in {name}.negate to push that dimension's mean towards 0",
            )


ROLLOUT_KEYS = ("env.num_envs", "ppo.n_steps")


def rollout_batch(config: Config) -> int:
    """Samples per on-policy iteration: ppo.n_steps x env.num_envs (ppo, rpo and trpo)."""
    return int(config.ppo.n_steps * config.env.num_envs)


def largest_divisor(batch: int, at_most: int) -> int:
    """The largest minibatch size up to `at_most` that divides `batch`: what a refusal offers. Divisors come in pairs
    (d, batch // d) with d <= sqrt(batch), so a batch of 1e9 takes 3e4 trials, not 1e9."""
    pairs = (d for d in range(1, math.isqrt(batch) + 1) if batch % d == 0)
    return max(x for d in pairs for x in (d, batch // d) if x <= at_most)


def _check_minibatch(config: Config) -> None:
    ppo, batch = config.ppo, rollout_batch(config)
    need(
        batch % ppo.minibatch_size == 0,
        f"ppo.minibatch_size {ppo.minibatch_size} does not divide the batch {batch} "
        f"(ppo.n_steps {ppo.n_steps} x env.num_envs {config.env.num_envs}); pick a divisor, e.g. "
        f"--set ppo.minibatch_size={largest_divisor(batch, ppo.minibatch_size)}",
    )


PPO_LABELS = {
    "policy_loss": ("Policy loss", "loss (dimensionless)"),
    "value_loss": ("Value loss", "loss (squared return units)"),
    "entropy": ("Policy entropy", "nats"),
    "approx_kl": ("Approx. KL (old ‖ new)", "nats"),
    "clip_frac": ("Clip fraction", "fraction of samples clipped"),
    "grad_norm": ("Gradient norm before clipping (mean)", "global L2 norm, actor and critic"),
    "grad_norm_max": ("Gradient norm before clipping (largest)", "global L2 norm, actor and critic"),
    "explained_variance": ("Explained variance", "1 − Var[R − V] / Var[R]"),
    "learning_rate": ("Learning rate", "Adam step size"),
    "epochs_run": ("Epochs run", "epochs per iteration"),
    "policy_kl": ("Policy KL (old ‖ new)", "nats"),
    "kl_beta": ("KL penalty coefficient β", "dimensionless"),
    "sym_loss": ("Symmetry loss", "mean squared difference"),
}


def unused_metrics(config: Config) -> tuple[str, ...]:
    """The symmetry loss without sym.coef, and the KL penalty's β with the clipped objective."""
    return tuple(
        name
        for name, unused in (("sym_loss", config.sym.coef == 0), ("kl_beta", config.ppo.objective != "kl_penalty"))
        if unused
    )


PACKAGE = "canter.algos.ppo"

register_section("net", NetConfig, check_net)
register_section("ppo", PPOConfig, check_ppo)
register_section("rpo", RPOConfig, check_rpo)
register_section("sym", SymConfig, check_sym)

PPO = AlgorithmSpec(
    name="ppo",
    summary="Proximal Policy Optimization (clipped, or adaptive KL penalty)",
    runtime=PACKAGE,
    reads=("net", "ppo", "sym"),
    validate=_check_minibatch,
    search_space=(PACKAGE, "search_space_ppo.toml"),
    iteration_steps=rollout_batch,
    iteration_keys=ROLLOUT_KEYS,
    preset_overrides=algorithm_preset_tables(PACKAGE, "ppo"),
    plot_labels=PPO_LABELS,
    rollout_batch=rollout_batch,
    batch_divisors=("ppo.minibatch_size",),
    unused_metrics=unused_metrics,
)
RPO = AlgorithmSpec(
    name="rpo",
    summary="Robust Policy Optimization: PPO with a uniformly shifted mean in the update",
    runtime=PACKAGE,
    reads=("net", "ppo", "rpo", "sym"),
    validate=_check_minibatch,
    search_space=(PACKAGE, "search_space_rpo.toml"),
    iteration_steps=rollout_batch,
    iteration_keys=ROLLOUT_KEYS,
    preset_overrides=algorithm_preset_tables(PACKAGE, "rpo"),
    plot_labels=PPO_LABELS,
    rollout_batch=rollout_batch,
    batch_divisors=("ppo.minibatch_size",),
    unused_metrics=unused_metrics,
)
register_algorithm(PPO)
register_algorithm(RPO)
