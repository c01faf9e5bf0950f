"""Settings of the actor-critic MLPs in `canter.core.networks` (the `net` section, registered by the algorithms
that use them)."""

from __future__ import annotations

from dataclasses import dataclass

from canter.config.fields import setting
from canter.config.validate import need

# The hidden activations, by name: the config checks these without importing JAX; `canter.core.networks` and
# `canter.use.export` map each name to its function (tests/test_read_keys.py checks that they map exactly these).
ACTIVATIONS = ("tanh", "relu", "elu")
ACTIVATION_CHOICES = f"{', '.join(ACTIVATIONS[:-1])} or {ACTIVATIONS[-1]}"


def check_activation(key: str, value: str) -> None:
    need(value in ACTIVATIONS, f"{key} must be {ACTIVATION_CHOICES}, got '{value}'")


@dataclass(frozen=True)
class NetConfig:
    hidden: tuple[int, ...] = setting(
        "Hidden layer sizes of the actor (and of the critic unless critic_hidden is set).", default=(64, 64)
    )
    critic_hidden: tuple[int, ...] = setting(
        "Hidden sizes of the critic; empty means the same as `hidden`.", default=()
    )
    activation: str = setting(f"Hidden activation: {ACTIVATION_CHOICES}.", default="tanh")
    log_std_init: float = setting("Initial log standard deviation of the Gaussian policy.", default=0.0)
    state_dependent_std: bool = setting(
        "Predict log std from the observation instead of a learned vector.", default=False
    )
    ortho_init: bool = setting(
        "Orthogonal initialization (gain sqrt 2 hidden, 0.01 policy head, 1 value head).", default=True
    )


def check_net(net: NetConfig, name: str) -> None:
    need(
        len(net.hidden) >= 1 and all(h > 0 for h in net.hidden),
        f"{name}.hidden must be positive sizes such as 64,64, got {net.hidden}",
    )
    need(all(h > 0 for h in net.critic_hidden), f"{name}.critic_hidden must be positive sizes, got {net.critic_hidden}")
    check_activation(f"{name}.activation", net.activation)
