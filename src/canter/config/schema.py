"""One typed, frozen configuration tree.

Every key is addressable as `section.key`, both from `--set section.key=value` and from TOML files. Layers are
applied in this order: built-in defaults < preset < `--config file.toml` < `--set`. Validation lives here, in one
place, and raises `CanterError` with a one-line message.
"""

from __future__ import annotations

import difflib
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any

from canter.errors import CanterError


def _doc(text: str, **kwargs: Any) -> Any:
    return field(metadata={"doc": text}, **kwargs)


@dataclass(frozen=True)
class EnvConfig:
    id: str = _doc("Environment id, e.g. Hopper-v5, or `module:EnvId` for a custom Gymnasium env.", default="")
    backend: str = _doc("`auto` (EnvPool where it has the id, else Gymnasium), `envpool` or `gymnasium`.",
                        default="auto")
    num_envs: int = _doc("Parallel environments stepped per rollout step.", default=1)
    envpool_shards: int = _doc("EnvPool only: split the envs over this many single-threaded pools that step "
                               "concurrently, as evenly as the count allows; 0 means one per CPU core.", default=0)
    normalize_obs: bool = _doc("Running observation normalization (stats saved with the policy).", default=True)
    clip_obs: float = _doc("Clip normalized observations to +-clip_obs.", default=10.0)
    normalize_reward: bool = _doc("Divide rewards by the running std of the discounted return.", default=True)
    clip_reward: float = _doc("Clip scaled rewards to +-clip_reward.", default=10.0)


@dataclass(frozen=True)
class NetConfig:
    hidden: tuple[int, ...] = _doc("Hidden layer sizes of the actor (and of the critic unless critic_hidden is set).",
                                   default=(64, 64))
    critic_hidden: tuple[int, ...] = _doc("Hidden sizes of the critic; empty means the same as `hidden`.",
                                          default=())
    activation: str = _doc("Hidden activation: tanh, relu or elu.", default="tanh")
    log_std_init: float = _doc("Initial log standard deviation of the Gaussian policy.", default=0.0)
    state_dependent_std: bool = _doc("Predict log std from the observation instead of a learned vector.",
                                     default=False)
    ortho_init: bool = _doc("Orthogonal initialization (gain sqrt 2 hidden, 0.01 policy head, 1 value head).",
                            default=True)


@dataclass(frozen=True)
class PPOConfig:
    n_steps: int = _doc("Rollout steps per environment per iteration (batch = n_steps * num_envs).", default=2048)
    minibatch_size: int = _doc("Samples per minibatch; must divide the batch.", default=64)
    epochs: int = _doc("Passes over the batch per iteration.", default=10)
    lr: float = _doc("Adam learning rate (actor, and critic unless critic_lr is set).", default=3e-4)
    critic_lr: float | None = _doc("Separate critic learning rate; `none` uses lr.", default=None)
    anneal_lr: bool = _doc("Anneal learning rates linearly to 0 over the run, once per iteration.", default=True)
    adam_eps: float = _doc("Adam epsilon.", default=1e-5)
    gamma: float = _doc("Discount factor.", default=0.99)
    gae_lambda: float = _doc("GAE lambda.", default=0.95)
    clip: float = _doc("Clipping range of the probability ratio.", default=0.2)
    clip_vloss: bool = _doc("Clip the value loss around the old values, with the same range.", default=True)
    norm_adv: bool = _doc("Normalize advantages per minibatch.", default=True)
    ent_coef: float = _doc("Entropy bonus coefficient.", default=0.0)
    vf_coef: float = _doc("Value loss coefficient.", default=0.5)
    max_grad_norm: float = _doc("Global gradient-norm clip (actor and critic together).", default=0.5)
    target_kl: float | None = _doc("Stop the epochs of an iteration once approx KL exceeds this; `none` is off.",
                                   default=None)
    objective: str = _doc("Policy objective: `clip` (clipped surrogate) or `kl_penalty` (surrogate - beta * KL, "
                          "with beta adapted after each iteration, PPO paper sec. 4).", default="clip")
    kl_penalty_target: float = _doc("kl_penalty only: KL target d; beta halves when the iteration's mean KL < d/1.5 "
                                    "and doubles when it is > 1.5 d.", default=0.01)
    kl_penalty_beta: float = _doc("kl_penalty only: initial beta (the current beta is part of the train state).",
                                  default=1.0)


# Sections of the other algorithms. Each is owned by its algorithm module's author; keep them in this order.

@dataclass(frozen=True)
class RPOConfig:
    """rpo: PPO whose update re-evaluates stored actions under a randomly shifted mean (Rahman & Xue 2023)."""
    alpha: float = _doc("Half-width of the per-dimension shift z ~ U(-alpha, alpha) added to the policy mean when "
                        "the update re-evaluates stored actions (rollouts sample from the unshifted policy).",
                        default=0.5)


@dataclass(frozen=True)
class SymConfig:
    """Symmetric action loss for ppo and rpo (seed 000)."""
    coef: float = _doc("Weight of the symmetric action loss; 0 turns it off.", default=0.0)
    groups: str = _doc("Mirrored action groups as `a:b=c:d` pairs of half-open index ranges of equal length, comma "
                       "separated (a single index `i` means `i:i+1`), e.g. `3:7=7:11,11:14=14:17`.", default="")
    negate: tuple[int, ...] = _doc("Indices on the right-hand side of a pair whose sign is flipped before comparing "
                                   "means (joints whose axis is mirrored, so mirrored motion is -a).", default=())
    compare: str = _doc("What is compared across a pair: `mean` (the policy means) or `log_prob` (per-dimension "
                        "log-probabilities of the stored actions, as seed 000 does).", default="mean")


@dataclass(frozen=True)
class TRPOConfig:
    """trpo: natural gradient by conjugate gradient, backtracking line search, Adam critic. Rollout and GAE use
    ppo.n_steps, ppo.gamma, ppo.gae_lambda and ppo.norm_adv."""
    max_kl: float = _doc("Trust region: a step is accepted only if the mean KL(old || new) is at most this.",
                         default=0.01)
    cg_iters: int = _doc("Maximum conjugate-gradient iterations for the natural gradient.", default=10)
    cg_damping: float = _doc("Damping added to the Fisher-vector product (F + damping I).", default=0.1)
    line_search_iters: int = _doc("Backtracking line-search steps before the update is rejected.", default=10)
    line_search_shrink: float = _doc("Step-size factor per backtracking step.", default=0.8)
    critic_lr: float = _doc("Adam learning rate of the critic's regression on the GAE returns.", default=1e-3)
    critic_epochs: int = _doc("Passes over the batch for the critic per iteration.", default=10)
    critic_minibatch_size: int = _doc("Samples per critic minibatch; must divide the batch.", default=128)


@dataclass(frozen=True)
class OffPolicyConfig:
    """Keys shared by td3, ddpg and sac (each section has its own copy, with its own defaults). The networks are
    set here rather than in `net.*`, whose defaults and presets are PPO's."""
    buffer_size: int = _doc("Replay buffer capacity in transitions (kept on the JAX device).", default=1_000_000)
    batch_size: int = _doc("Transitions per gradient step.", default=256)
    learning_starts: int = _doc("Env steps of uniformly random actions before the first update.", default=25_000)
    train_freq: int = _doc("Update after every this many vector-env steps.", default=1)
    gradient_steps: int = _doc("Gradient steps per update.", default=1)
    policy_delay: int = _doc("Update the actor (and the targets, for td3/ddpg) every this many gradient steps.",
                             default=1)
    tau: float = _doc("Polyak coefficient of the target networks: target <- tau * online + (1 - tau) * target.",
                      default=0.005)
    gamma: float = _doc("Discount factor.", default=0.99)
    actor_lr: float = _doc("Adam learning rate of the actor.", default=3e-4)
    critic_lr: float = _doc("Adam learning rate of the critic(s).", default=3e-4)
    hidden: tuple[int, ...] = _doc("Hidden layer sizes of the actor and of each critic.", default=(256, 256))
    activation: str = _doc("Hidden activation: relu, tanh or elu.", default="relu")
    noise: str = _doc("Exploration noise: gaussian, ou (Ornstein-Uhlenbeck, per env, reset at episode end) or "
                      "none. Ignored by sac.", default="gaussian")
    noise_std: float = _doc("Exploration noise std (OU: sigma), as a fraction of the action half-range.",
                            default=0.1)
    ou_theta: float = _doc("OU mean-reversion rate theta.", default=0.15)
    ou_dt: float = _doc("OU time step dt.", default=0.01)
    steps_per_call: int = _doc("Env steps per jitted call of the training loop (the logging/checkpoint unit).",
                               default=1000)


@dataclass(frozen=True)
class TD3Config(OffPolicyConfig):
    policy_delay: int = _doc("Update the actor and the targets every this many gradient steps.", default=2)
    target_noise: float = _doc("Std of the target policy smoothing noise (fraction of the action half-range).",
                               default=0.2)
    noise_clip: float = _doc("Clip of the target policy smoothing noise.", default=0.5)


@dataclass(frozen=True)
class DDPGConfig(OffPolicyConfig):
    """ddpg: one critic, no target smoothing, actor updated every step by default."""


@dataclass(frozen=True)
class SACConfig(OffPolicyConfig):
    learning_starts: int = _doc("Env steps of uniformly random actions before the first update.", default=5_000)
    critic_lr: float = _doc("Adam learning rate of the critics.", default=1e-3)
    noise: str = _doc("Unused by sac (it explores by sampling its policy); must be none.", default="none")
    autotune: bool = _doc("Tune the entropy temperature alpha towards target_entropy.", default=True)
    alpha: float = _doc("Initial (or, without autotune, fixed) entropy temperature.", default=1.0)
    alpha_lr: float = _doc("Adam learning rate of log alpha.", default=1e-3)
    target_entropy: float | None = _doc("Target policy entropy; none means -act_dim.", default=None)


@dataclass(frozen=True)
class RunConfig:
    algo: str = _doc("Algorithm.", default="ppo")
    preset: str = _doc("Name of the preset this config was built from (recorded, not applied).", default="none")
    seed: int = _doc("Run seed: network init, sampling and the derived per-env seeds.", default=0)
    total_steps: int = _doc("Environment steps to train for (reset steps of EnvPool are not counted).",
                            default=1_000_000)
    out_dir: str = _doc("Folder that receives run folders.", default="runs")
    checkpoint_every: int = _doc("Write a checkpoint every this many env steps (0: only at the end).",
                                 default=200_000)
    keep_checkpoints: int = _doc("Keep the newest K checkpoints.", default=3)
    compress_checkpoints: bool = _doc("Deflate checkpoint arrays (worth it for off-policy replay buffers).",
                                      default=False)
    stop_at_return: float | None = _doc("Stop once the mean return of the last 20 training episodes reaches this.",
                                        default=None)
    max_minutes: float | None = _doc("Stop cleanly, with a checkpoint, after this many wall minutes.", default=None)
    tensorboard: bool = _doc("Write TensorBoard event files.", default=True)
    video_every: int = _doc("Render one episode to videos/step_<step>.mp4 in the run folder every this many env "
                            "steps, in a separate process (0: never).", default=0)


@dataclass(frozen=True)
class Config:
    env: EnvConfig = field(default_factory=EnvConfig)
    net: NetConfig = field(default_factory=NetConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    rpo: RPOConfig = field(default_factory=RPOConfig)
    sym: SymConfig = field(default_factory=SymConfig)
    trpo: TRPOConfig = field(default_factory=TRPOConfig)
    td3: TD3Config = field(default_factory=TD3Config)
    ddpg: DDPGConfig = field(default_factory=DDPGConfig)
    sac: SACConfig = field(default_factory=SACConfig)
    run: RunConfig = field(default_factory=RunConfig)

    @property
    def batch_size(self) -> int:
        return self.ppo.n_steps * self.env.num_envs

    @property
    def num_minibatches(self) -> int:
        return self.batch_size // self.ppo.minibatch_size

    def num_iterations(self, total_steps: int | None = None) -> int:
        total = self.run.total_steps if total_steps is None else total_steps
        return max(1, math.ceil(total / self.batch_size))


SECTIONS = tuple(f.name for f in fields(Config))


# --------------------------------------------------------------------------------------------------- parsing values

def _section_type(name: str) -> type:
    return type(getattr(Config(), name))


def _field_types(section: str) -> dict[str, Any]:
    cls = _section_type(section)
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in fields(cls)}


def _is_optional(tp: Any) -> tuple[bool, Any]:
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(tp)) == 2:
            return True, args[0]
    return False, tp


def _type_name(tp: Any) -> str:
    optional, inner = _is_optional(tp)
    if typing.get_origin(inner) is tuple:
        base = "comma-separated integers"
    else:
        base = {int: "an integer", float: "a number", bool: "true or false", str: "a string"}.get(inner, str(inner))
    return f"{base} or none" if optional else base


def coerce(key: str, tp: Any, value: Any) -> Any:
    """Convert a TOML value or a `--set` string to the field's type, or raise a one-line CanterError."""
    optional, inner = _is_optional(tp)
    bad = CanterError(f"{key}: expected {_type_name(tp)}, got {value!r}")
    if optional and (value is None or (isinstance(value, str) and value.strip().lower() in ("none", "null", ""))):
        return None
    if typing.get_origin(inner) is tuple:
        if isinstance(value, str):
            parts = [p for p in value.replace("-", ",").split(",") if p.strip()] if value.strip() else []
            try:
                return tuple(int(p) for p in parts)
            except ValueError:
                raise bad from None
        if isinstance(value, (list, tuple)) and all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            return tuple(value)
        raise bad
    if inner is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.strip().lower() in ("true", "1", "yes", "on", "false", "0", "no", "off"):
            return value.strip().lower() in ("true", "1", "yes", "on")
        raise bad
    if inner is int:
        if isinstance(value, bool):
            raise bad
        if isinstance(value, int):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        if isinstance(value, str):
            try:
                number = float(value)
            except ValueError:
                raise bad from None
            if number.is_integer():
                return int(number)
        raise bad
    if inner is float:
        if isinstance(value, bool):
            raise bad
        if isinstance(value, (int, float)):
            return float(value)
        if isinstance(value, str):
            try:
                return float(value)
            except ValueError:
                raise bad from None
        raise bad
    if inner is str:
        if isinstance(value, str):
            return value
        raise bad
    raise bad


def _unknown_key_error(key: str, source: str) -> CanterError:
    known = all_keys()
    close = difflib.get_close_matches(key, known, n=3, cutoff=0.5)
    hint = f"; did you mean {', '.join(close)}?" if close else f"; sections are {', '.join(SECTIONS)}"
    return CanterError(f"unknown config key '{key}' in {source}{hint}")


def all_keys() -> list[str]:
    return [f"{s}.{name}" for s in SECTIONS for name in _field_types(s)]


def apply_overrides(config: Config, overrides: dict[str, Any], source: str) -> Config:
    """Apply `{"section.key": value}` overrides, checking names and types."""
    sections: dict[str, dict[str, Any]] = {}
    for key, value in overrides.items():
        section, _, name = key.partition(".")
        if section not in SECTIONS or name not in _field_types(section):
            raise _unknown_key_error(key, source)
        sections.setdefault(section, {})[name] = coerce(key, _field_types(section)[name], value)
    changes = {s: replace(getattr(config, s), **values) for s, values in sections.items()}
    return replace(config, **changes)


def parse_set_args(items: list[str]) -> dict[str, str]:
    overrides: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise CanterError(f"--set expects section.key=value, got {item!r}")
        overrides[key.strip()] = value.strip()
    return overrides


def flatten_toml(data: dict[str, Any], source: str) -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for section, values in data.items():
        if not isinstance(values, dict):
            raise _unknown_key_error(section, source)
        for name, value in values.items():
            if isinstance(value, dict):
                raise _unknown_key_error(f"{section}.{name}", source)
            flat[f"{section}.{name}"] = value
    return flat


def load_toml(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise CanterError(f"config file not found: {path}")
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise CanterError(f"malformed TOML in {path}: {exc}") from None
    except UnicodeDecodeError:
        raise CanterError(f"config file {path} is not UTF-8 text") from None


def apply_toml_file(config: Config, path: str | Path) -> Config:
    return apply_overrides(config, flatten_toml(load_toml(path), str(path)), str(path))


# ---------------------------------------------------------------------------------------------------------- presets

def preset_names() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("canter.presets").iterdir() if p.name.endswith(".toml"))


def _preset_layer(table: dict[str, Any], env_id: str, algo: str, source: str) -> dict[str, Any]:
    """Flatten one preset table: its plain sections, then its `[env_overrides."<glob>"]` tables matching env_id,
    then its `[algo_overrides.<algo>]` table (which may hold env_overrides of its own). Later layers win."""
    import fnmatch

    table = dict(table)
    per_env = table.pop("env_overrides", {})
    per_algo = table.pop("algo_overrides", {})
    flat = flatten_toml(table, source)
    base_id = env_id.split(":")[-1]
    for pattern, tables in per_env.items():
        if fnmatch.fnmatch(base_id, pattern):
            flat.update(flatten_toml(tables, source))
    if algo in per_algo:
        flat.update(_preset_layer(per_algo[algo], env_id, algo, source))
    return flat


def preset_text(name: str) -> str:
    if name not in preset_names():
        raise CanterError(f"unknown preset '{name}'; choose one of: {', '.join(preset_names())}")
    return resources.files("canter.presets").joinpath(f"{name}.toml").read_text()


def _read_preset(name: str) -> tuple[dict[str, Any], list[str] | None]:
    """A preset's tables, and apart from them the algorithms it declares it holds settings for (its top-level
    `algos`, None for all)."""
    table = tomllib.loads(preset_text(name))
    return table, table.pop("algos", None)


def preset_algorithms(name: str) -> list[str] | None:
    """The algorithms a preset declares it holds settings for (its top-level `algos`), or None for all."""
    return _read_preset(name)[1]


def preset_overrides(name: str, env_id: str, algo: str = "ppo") -> dict[str, Any]:
    """A preset's keys for this env and algorithm: base tables < matching `[env_overrides."<glob>"]` tables <
    `[algo_overrides.<algo>]` (fnmatch on the env id without any `module:` prefix). A preset whose top-level
    `algos` list names the algorithms it holds settings for refuses the others, which would otherwise get the bare
    defaults under its name."""
    table, supported = _read_preset(name)
    if supported and algo not in supported:
        raise CanterError(f"preset {name} holds settings for {', '.join(supported)} only, not {algo}; train one "
                          f"of those algorithms with it (e.g. --algo {supported[0]}) or choose another preset")
    return _preset_layer(table, env_id, algo, f"preset {name}")


def build_config(env_id: str | None, preset: str = "fast", config_file: str | None = None,
                 sets: list[str] | None = None, seed: int | None = None, total_steps: int | None = None,
                 algo: str | None = None, check_unread: bool = True) -> Config:
    """Resolve defaults < preset < config file < --set (< explicit flags), then validate. The algorithm is known
    before the preset is applied, so presets can hold per-algorithm tables. A --set key that the algorithm does not
    read is refused (unless `check_unread` is off), since it would change nothing."""
    file_data = flatten_toml(load_toml(config_file), config_file) if config_file else {}
    set_data = parse_set_args(sets or [])
    resolved_id = env_id or set_data.get("env.id") or file_data.get("env.id")
    if not resolved_id:
        raise CanterError("no environment given; pass an env id, e.g. `canter train Hopper-v5`")
    config = Config()
    first = {"env.id": resolved_id, "run.preset": preset}
    resolved_algo = algo or set_data.get("run.algo") or file_data.get("run.algo")
    if resolved_algo:
        from canter.algos import check_algorithm_name

        check_algorithm_name(str(resolved_algo))
        first["run.algo"] = resolved_algo
    config = apply_overrides(config, first, "arguments")
    config = apply_overrides(config, preset_overrides(preset, str(resolved_id), config.run.algo), f"preset {preset}")
    config = apply_overrides(config, file_data, str(config_file))
    config = apply_overrides(config, set_data, "--set")
    if check_unread:
        for key in set_data:
            if not reads_key(config.run.algo, key):
                raise CanterError(unread_key_error(config.run.algo, key))
    flags: dict[str, Any] = {}
    if env_id:
        flags["env.id"] = env_id
    if algo:
        flags["run.algo"] = algo
    if seed is not None:
        flags["run.seed"] = seed
    if total_steps is not None:
        flags["run.total_steps"] = total_steps
    config = apply_overrides(config, flags, "arguments")
    validate(config)
    return config


def reads_key(algo: str, key: str) -> bool:
    from canter.algos import READS

    section = key.partition(".")[0]
    return section in ("env", "run") or section in READS[algo] or key in READS[algo]


def unread_key_error(algo: str, key: str) -> str:
    """The one-line refusal of a key that `algo` would silently ignore, pointing to the key it does read."""
    from canter.algos import READS, REGISTRY

    section, _, name = key.partition(".")
    sections = [s for s in READS[algo] if "." not in s]
    single = [k for k in READS[algo] if "." in k]
    reads = ", ".join([f"{s}.*" for s in sections] + single + ["env.*", "run.*"])
    twins = [f"{s}.{name}" for s in sections if s != section and name in _field_types(s)]
    if twins:
        fix = f"set {twins[0]} instead"
    else:
        fix = f"drop it ({key} is read by {', '.join(a for a in REGISTRY if reads_key(a, key)) or 'no algorithm'})"
    return f"{key} has no effect on {algo}, which reads {reads}; {fix}"


# ------------------------------------------------------------------------------------------------------- validation

def validate(config: Config) -> None:
    env, net, ppo, run = config.env, config.net, config.ppo, config.run

    def need(ok: bool, message: str) -> None:
        if not ok:
            raise CanterError(message)

    need(bool(env.id), "env.id is empty; pass an env id such as Hopper-v5")
    need(env.backend in ("auto", "envpool", "gymnasium"), f"env.backend must be auto, envpool or gymnasium, "
                                                          f"got '{env.backend}'")
    need(env.num_envs >= 1, f"env.num_envs must be >= 1, got {env.num_envs}")
    need(0 <= env.envpool_shards <= env.num_envs,
         f"env.envpool_shards must be 0 (auto) to env.num_envs {env.num_envs}, got {env.envpool_shards}")
    need(env.clip_obs > 0, f"env.clip_obs must be > 0, got {env.clip_obs}")
    need(env.clip_reward > 0, f"env.clip_reward must be > 0, got {env.clip_reward}")
    need(len(net.hidden) >= 1 and all(h > 0 for h in net.hidden),
         f"net.hidden must be positive sizes such as 64,64, got {net.hidden}")
    need(all(h > 0 for h in net.critic_hidden), f"net.critic_hidden must be positive sizes, got {net.critic_hidden}")
    need(net.activation in ("tanh", "relu", "elu"), f"net.activation must be tanh, relu or elu, "
                                                    f"got '{net.activation}'")
    from canter.algos import check_algorithm_name

    check_algorithm_name(run.algo)
    need(ppo.n_steps >= 1, f"ppo.n_steps must be >= 1, got {ppo.n_steps}")
    need(ppo.minibatch_size >= 1, f"ppo.minibatch_size must be >= 1, got {ppo.minibatch_size}")
    from canter.algos import get_algorithm

    # The rollout batch only exists for on-policy algorithms (off-policy presets use 1 env).
    need(not get_algorithm(run.algo).on_policy or config.batch_size % ppo.minibatch_size == 0,
         f"ppo.minibatch_size {ppo.minibatch_size} does not divide the batch {config.batch_size} "
         f"(ppo.n_steps {ppo.n_steps} x env.num_envs {env.num_envs}); pick a divisor")
    need(ppo.epochs >= 1, f"ppo.epochs must be >= 1, got {ppo.epochs}")
    for key in ("lr", "adam_eps", "clip", "max_grad_norm"):
        value = getattr(ppo, key)
        need(math.isfinite(value) and value > 0, f"ppo.{key} must be > 0, got {value}")
    if ppo.critic_lr is not None:
        need(math.isfinite(ppo.critic_lr) and ppo.critic_lr > 0, f"ppo.critic_lr must be > 0, got {ppo.critic_lr}")
    if ppo.target_kl is not None:
        need(ppo.target_kl > 0, f"ppo.target_kl must be > 0 or none, got {ppo.target_kl}")
    need(0 < ppo.gamma <= 1, f"ppo.gamma must be in (0, 1], got {ppo.gamma}")
    need(0 <= ppo.gae_lambda <= 1, f"ppo.gae_lambda must be in [0, 1], got {ppo.gae_lambda}")
    for key in ("ent_coef", "vf_coef"):
        need(getattr(ppo, key) >= 0, f"ppo.{key} must be >= 0, got {getattr(ppo, key)}")
    _validate_onpolicy_variants(config)
    for name in ("td3", "ddpg", "sac"):
        _validate_offpolicy(name, getattr(config, name), need)
    need(run.total_steps >= 1, f"run.total_steps must be >= 1, got {run.total_steps}")
    need(run.checkpoint_every >= 0, f"run.checkpoint_every must be >= 0, got {run.checkpoint_every}")
    need(run.keep_checkpoints >= 1, f"run.keep_checkpoints must be >= 1, got {run.keep_checkpoints}")
    need(run.video_every >= 0, f"run.video_every must be >= 0, got {run.video_every}")
    if run.max_minutes is not None:
        need(run.max_minutes > 0, f"run.max_minutes must be > 0, got {run.max_minutes}")


def _validate_onpolicy_variants(config: Config) -> None:
    """ppo.objective, rpo, sym and trpo: checks that need only the config (the action range is checked by the
    algorithm against the env spec)."""
    ppo, rpo, sym, trpo = config.ppo, config.rpo, config.sym, config.trpo

    def need(ok: bool, message: str) -> None:
        if not ok:
            raise CanterError(message)

    need(ppo.objective in ("clip", "kl_penalty"), f"ppo.objective must be clip or kl_penalty, got '{ppo.objective}'")
    for key in ("kl_penalty_target", "kl_penalty_beta"):
        value = getattr(ppo, key)
        need(math.isfinite(value) and value > 0, f"ppo.{key} must be > 0, got {value}")
    need(math.isfinite(rpo.alpha) and rpo.alpha >= 0, f"rpo.alpha must be >= 0, got {rpo.alpha}")
    need(math.isfinite(sym.coef) and sym.coef >= 0, f"sym.coef must be >= 0 (0 is off), got {sym.coef}")
    need(sym.compare in ("mean", "log_prob"), f"sym.compare must be mean or log_prob, got '{sym.compare}'")
    from canter.algos.ppo.symmetry import parse_groups

    pairs = parse_groups(sym.groups, sym.negate)
    need(sym.coef == 0 or bool(pairs), "sym.coef > 0 needs sym.groups, e.g. sym.groups=3:7=7:11")
    need(math.isfinite(trpo.max_kl) and trpo.max_kl > 0, f"trpo.max_kl must be > 0, got {trpo.max_kl}")
    need(trpo.cg_iters >= 1, f"trpo.cg_iters must be >= 1, got {trpo.cg_iters}")
    need(math.isfinite(trpo.cg_damping) and trpo.cg_damping >= 0,
         f"trpo.cg_damping must be >= 0, got {trpo.cg_damping}")
    need(trpo.line_search_iters >= 1, f"trpo.line_search_iters must be >= 1, got {trpo.line_search_iters}")
    need(0 < trpo.line_search_shrink < 1, f"trpo.line_search_shrink must be in (0, 1), got "
                                          f"{trpo.line_search_shrink}")
    need(math.isfinite(trpo.critic_lr) and trpo.critic_lr > 0, f"trpo.critic_lr must be > 0, got {trpo.critic_lr}")
    need(trpo.critic_epochs >= 1, f"trpo.critic_epochs must be >= 1, got {trpo.critic_epochs}")
    need(trpo.critic_minibatch_size >= 1, f"trpo.critic_minibatch_size must be >= 1, got "
                                          f"{trpo.critic_minibatch_size}")
    need(config.run.algo != "trpo" or config.batch_size % trpo.critic_minibatch_size == 0,
         f"trpo.critic_minibatch_size {trpo.critic_minibatch_size} does not divide the batch {config.batch_size} "
         f"(ppo.n_steps x env.num_envs); pick a divisor")
def _validate_offpolicy(name: str, section: OffPolicyConfig, need: Any) -> None:
    s = section
    for key in ("buffer_size", "batch_size", "train_freq", "gradient_steps", "policy_delay", "steps_per_call"):
        need(getattr(s, key) >= 1, f"{name}.{key} must be >= 1, got {getattr(s, key)}")
    need(s.buffer_size >= s.batch_size, f"{name}.buffer_size {s.buffer_size} is smaller than {name}.batch_size "
                                        f"{s.batch_size}; raise the buffer or lower the batch")
    need(s.learning_starts >= 0, f"{name}.learning_starts must be >= 0, got {s.learning_starts}")
    need(0 < s.tau <= 1, f"{name}.tau must be in (0, 1], got {s.tau}")
    need(0 < s.gamma <= 1, f"{name}.gamma must be in (0, 1], got {s.gamma}")
    for key in ("actor_lr", "critic_lr", "ou_theta", "ou_dt"):
        value = getattr(s, key)
        need(math.isfinite(value) and value > 0, f"{name}.{key} must be > 0, got {value}")
    need(len(s.hidden) >= 1 and all(h > 0 for h in s.hidden),
         f"{name}.hidden must be positive sizes such as 256,256, got {s.hidden}")
    need(s.activation in ("tanh", "relu", "elu"), f"{name}.activation must be tanh, relu or elu, got '{s.activation}'")
    need(s.noise in ("gaussian", "ou", "none"), f"{name}.noise must be gaussian, ou or none, got '{s.noise}'")
    need(math.isfinite(s.noise_std) and s.noise_std >= 0, f"{name}.noise_std must be >= 0, got {s.noise_std}")
    if isinstance(s, TD3Config):
        need(s.target_noise >= 0, f"td3.target_noise must be >= 0, got {s.target_noise}")
        need(s.noise_clip >= 0, f"td3.noise_clip must be >= 0, got {s.noise_clip}")
    if isinstance(s, SACConfig):
        need(s.noise == "none", f"sac.noise must be none (sac explores by sampling its policy), got '{s.noise}'")
        for key in ("alpha", "alpha_lr"):
            value = getattr(s, key)
            need(math.isfinite(value) and value > 0, f"sac.{key} must be > 0, got {value}")
        if s.target_entropy is not None:
            need(math.isfinite(s.target_entropy), f"sac.target_entropy must be finite or none, "
                                                  f"got {s.target_entropy}")


# ------------------------------------------------------------------------------------------------- TOML round trip

def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value) if math.isfinite(value) else ("inf" if value > 0 else "-inf") if not math.isnan(
            value) else "nan"
    if isinstance(value, tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, str):
        escaped = value.replace("\\", "\\\\").replace('"', '\\"')
        return f'"{escaped}"'
    raise TypeError(value)


def to_toml(config: Config) -> str:
    """The complete resolved config; `none` values are written as comments, since TOML has no null."""
    lines: list[str] = []
    for section in SECTIONS:
        lines.append(f"[{section}]")
        for f in fields(getattr(config, section)):
            value = getattr(getattr(config, section), f.name)
            lines.append(f"# {f.name} = none" if value is None else f"{f.name} = {_toml_value(value)}")
        lines.append("")
    return "\n".join(lines)


def from_toml_text(text: str, source: str) -> Config:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CanterError(f"malformed TOML in {source}: {exc}") from None
    config = apply_overrides(Config(), flatten_toml(data, source), source)
    validate(config)
    return config


def docs_table() -> str:
    """Markdown table of every key, generated from the dataclasses so the README cannot drift."""
    rows = ["| key | type | default | meaning |", "|---|---|---|---|"]
    defaults = Config()
    for section in SECTIONS:
        types_ = _field_types(section)
        for f in fields(getattr(defaults, section)):
            default = getattr(getattr(defaults, section), f.name)
            shown = "none" if default is None else (
                ",".join(map(str, default)) if isinstance(default, tuple) else str(default).lower()
                if isinstance(default, bool) else str(default))
            rows.append(f"| `{section}.{f.name}` | {_type_name(types_[f.name])} | `{shown or '(empty)'}` "
                        f"| {f.metadata.get('doc', '')} |")
    return "\n".join(rows)
