"""What td3, ddpg and sac declare to the config: one section each (with the keys they share), their checks, search
spaces, preset tables and plot labels. Plain Python: the CLI reads it without importing JAX."""

from __future__ import annotations

import math
from dataclasses import dataclass

from canter.config.algorithms import AlgorithmSpec, register_algorithm
from canter.config.fields import setting
from canter.config.presets import algorithm_preset_tables
from canter.config.schema import Config, register_section
from canter.config.validate import need, need_positive
from canter.core.netconfig import ACTIVATION_CHOICES, check_activation

NOISE_KINDS = ("gaussian", "ou", "none")  # each one of canter.algos.offpolicy.noise.NOISES


@dataclass(frozen=True)
class OffPolicyConfig:
    """Keys shared by td3, ddpg and sac (each section has its own copy, with its own defaults). The networks are
    set here rather than in `net.*`, whose defaults and presets are PPO's."""

    buffer_size: int = setting("Replay buffer capacity in transitions (kept on the JAX device).", default=1_000_000)
    batch_size: int = setting("Transitions per gradient step.", default=256)
    learning_starts: int = setting("Env steps of uniformly random actions before the first update.", default=25_000)
    train_freq: int = setting("Update after every this many vector-env steps.", default=1)
    gradient_steps: int = setting("Gradient steps per update.", default=1)
    policy_delay: int = setting(
        "Update the actor (and the targets, for td3/ddpg) every this many gradient steps.", default=1
    )
    tau: float = setting(
        "Polyak coefficient of the target networks: target <- tau * online + (1 - tau) * target.", default=0.005
    )
    gamma: float = setting("Discount factor.", default=0.99)
    actor_lr: float = setting("Adam learning rate of the actor.", default=3e-4)
    critic_lr: float = setting("Adam learning rate of the critic(s).", default=3e-4)
    hidden: tuple[int, ...] = setting("Hidden layer sizes of the actor and of each critic.", default=(256, 256))
    activation: str = setting(f"Hidden activation: {ACTIVATION_CHOICES}.", default="relu")
    noise: str = setting(
        "Exploration noise: gaussian, ou (Ornstein-Uhlenbeck, per env, reset at episode end) or none. Ignored by sac.",
        default="gaussian",
    )
    noise_std: float = setting(
        "Exploration noise std (OU: sigma), as a fraction of the action half-range.", default=0.1
    )
    ou_theta: float = setting("OU mean-reversion rate theta.", default=0.15)
    ou_dt: float = setting("OU time step dt.", default=0.01)
    steps_per_call: int = setting(
        "Env steps per jitted call of the training loop (the logging/checkpoint unit): steps_per_call // num_envs "
        "vector steps, autoreset steps included, so a metrics.csv row counts fewer where episodes end.",
        default=1000,
    )


@dataclass(frozen=True)
class TD3Config(OffPolicyConfig):
    policy_delay: int = setting("Update the actor and the targets every this many gradient steps.", default=2)
    target_noise: float = setting(
        "Std of the target policy smoothing noise (fraction of the action half-range).", default=0.2
    )
    noise_clip: float = setting("Clip of the target policy smoothing noise.", default=0.5)


@dataclass(frozen=True)
class DDPGConfig(OffPolicyConfig):
    """ddpg: one critic, no target smoothing, actor updated every step by default."""


@dataclass(frozen=True)
class SACConfig(OffPolicyConfig):
    learning_starts: int = setting("Env steps of uniformly random actions before the first update.", default=5_000)
    critic_lr: float = setting("Adam learning rate of the critics.", default=1e-3)
    noise: str = setting("Unused by sac (it explores by sampling its policy); must be none.", default="none")
    autotune: bool = setting("Tune the entropy temperature alpha towards target_entropy.", default=True)
    alpha: float = setting("Initial (or, without autotune, fixed) entropy temperature.", default=1.0)
    alpha_lr: float = setting("Adam learning rate of log alpha.", default=1e-3)
    target_entropy: float | None = setting("Target policy entropy; none means -act_dim.", default=None)
    entropy_box: str = setting(
        "The action coordinates that entropies (the target's, the logged one) are measured in: unit, the [-1, 1] box "
        "the actor acts in (as SB3), or env, the env's own bounds (as CleanRL, whose log-probabilities include the "
        "action scale: on Humanoid, half-range 0.4, -act_dim there is -act_dim + 15.6 in the unit box).",
        default="unit",
    )


def check_offpolicy(s: OffPolicyConfig, name: str) -> None:
    for key in ("buffer_size", "batch_size", "train_freq", "gradient_steps", "policy_delay", "steps_per_call"):
        need(getattr(s, key) >= 1, f"{name}.{key} must be >= 1, got {getattr(s, key)}")
    need(
        s.buffer_size >= s.batch_size,
        f"{name}.buffer_size {s.buffer_size} is smaller than {name}.batch_size "
        f"{s.batch_size}; raise the buffer or lower the batch",
    )
    need(s.learning_starts >= 0, f"{name}.learning_starts must be >= 0, got {s.learning_starts}")
    need(0 < s.tau <= 1, f"{name}.tau must be in (0, 1], got {s.tau}")
    need(0 < s.gamma <= 1, f"{name}.gamma must be in (0, 1], got {s.gamma}")
    for key in ("actor_lr", "critic_lr", "ou_theta", "ou_dt"):
        need_positive(f"{name}.{key}", getattr(s, key))
    need(
        len(s.hidden) >= 1 and all(h > 0 for h in s.hidden),
        f"{name}.hidden must be positive sizes such as 256,256, got {s.hidden}",
    )
    check_activation(f"{name}.activation", s.activation)
    need(s.noise in NOISE_KINDS, f"{name}.noise must be gaussian, ou or none, got '{s.noise}'")
    need(math.isfinite(s.noise_std) and s.noise_std >= 0, f"{name}.noise_std must be >= 0, got {s.noise_std}")


def check_td3(s: TD3Config, name: str) -> None:
    check_offpolicy(s, name)
    need(s.target_noise >= 0, f"{name}.target_noise must be >= 0, got {s.target_noise}")
    need(s.noise_clip >= 0, f"{name}.noise_clip must be >= 0, got {s.noise_clip}")


def check_sac(s: SACConfig, name: str) -> None:
    check_offpolicy(s, name)
    need(s.noise == "none", f"{name}.noise must be none (sac explores by sampling its policy), got '{s.noise}'")
    for key in ("alpha", "alpha_lr"):
        need_positive(f"{name}.{key}", getattr(s, key))
    if s.target_entropy is not None:
        need(math.isfinite(s.target_entropy), f"{name}.target_entropy must be finite or none, got {s.target_entropy}")
    need(s.entropy_box in ("unit", "env"), f"{name}.entropy_box must be unit or env, got '{s.entropy_box}'")


def _check_buffer_holds_one_step(config: Config) -> None:
    """One vector step inserts num_envs rows at once; more than the buffer holds would write some slots twice in
    one scatter, whose winner XLA leaves undefined on a GPU."""
    name = config.run.algo
    buffer_size, num_envs = config.section(name).buffer_size, config.env.num_envs
    need(
        buffer_size >= num_envs,
        f"{name}.buffer_size {buffer_size} is smaller than env.num_envs {num_envs}, the rows one step inserts; "
        f"raise {name}.buffer_size or lower env.num_envs",
    )


PACKAGE = "canter.algos.offpolicy"
UPDATE_LABELS = {
    "actor_loss": ("Actor loss", "loss (−Q units)"),
    "critic_loss": ("Critic loss", "loss (squared return units)"),
    "q_mean": ("Mean Q value", "return units"),
    "learning_rate": ("Learning rate", "Adam step size"),
    "gradient_steps": ("Gradient steps", "updates per logged row"),
    "buffer_size": ("Replay buffer", "stored transitions"),
}

register_section("td3", TD3Config, check_td3)
register_section("ddpg", DDPGConfig, check_offpolicy)
register_section("sac", SACConfig, check_sac)


def vector_steps(steps_per_call: int, num_envs: int) -> int:
    """The vector steps of one jitted call: steps_per_call rounded down to whole vector steps, at least one."""
    return max(1, steps_per_call // num_envs)


def _iteration_steps(config: Config) -> int:
    num_envs = config.env.num_envs
    return vector_steps(getattr(config, config.run.algo).steps_per_call, num_envs) * num_envs


def _spec(
    name: str, summary: str, labels: dict[str, tuple[str, str]], ignores: dict[str, str] | None = None
) -> AlgorithmSpec:
    return AlgorithmSpec(
        name=name,
        summary=summary,
        runtime=f"{PACKAGE}.algorithms",
        reads=(name,),
        validate=_check_buffer_holds_one_step,
        search_space=(PACKAGE, f"search_space_{name}.toml"),
        iteration_steps=_iteration_steps,
        iteration_keys=(f"{name}.steps_per_call",),  # in whole vector steps of env.num_envs each
        preset_overrides=algorithm_preset_tables(PACKAGE, name),
        plot_labels=labels,
        seeds_train_apart=True,
        ignores=ignores or {},
        warm_up_key=f"{name}.learning_starts",
        call_memory_keys=("env.num_envs", f"{name}.batch_size"),
    )


# Seeds train one per process: under the vmap the step's `lax.cond`s (warm-up, td3's delayed actor step) see a
# per-seed predicate and become selects that compute both branches, and stacking seeds' 256-wide products gains
# nothing on a CPU core: two td3 seeds in one group trained at 0.67x the steps per second of one seed alone on the
# same core (docs/multiseed.md).
for spec in (
    _spec("td3", "Twin Delayed DDPG (off-policy, replay buffer)", UPDATE_LABELS),
    _spec("ddpg", "Deep Deterministic Policy Gradient (off-policy, replay buffer)", UPDATE_LABELS),
    _spec(
        "sac",
        "Soft Actor-Critic with automatic entropy tuning (off-policy)",
        {**UPDATE_LABELS, "alpha": ("Entropy temperature α", "dimensionless"), "entropy": ("Policy entropy", "nats")},
        # Its section inherits the exploration-noise keys; a changed one would only split its runs into experiments.
        {f"sac.{key}": "it explores by sampling its policy" for key in ("noise_std", "ou_theta", "ou_dt")},
    ),
):
    register_algorithm(spec)
