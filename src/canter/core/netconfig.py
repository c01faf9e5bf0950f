"""Settings of the actor-critic MLPs in `canter.core.networks` (the `net` section, registered by the algorithms
that use them)."""

from __future__ import annotations

from dataclasses import dataclass

from canter.config.fields import setting
from canter.config.validate import ACTIVATIONS, need


@dataclass(frozen=True)
class NetConfig:
    hidden: tuple[int, ...] = setting(
        "Hidden layer sizes of the actor (and of the critic unless critic_hidden is set).", default=(64, 64)
    )
    critic_hidden: tuple[int, ...] = setting(
        "Hidden sizes of the critic; empty means the same as `hidden`.", default=()
    )
    activation: str = setting("Hidden activation: tanh, relu or elu.", default="tanh")
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
    need(net.activation in ACTIVATIONS, f"{name}.activation must be tanh, relu or elu, got '{net.activation}'")
