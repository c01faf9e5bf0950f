"""td3 (Fujimoto et al. 2018): ddpg's learner (canter.algos.offpolicy.ddpg) with twin critics, whose minimum the
critic target takes, target policy smoothing, and an actor and targets updated every `policy_delay` critic steps
(2 by default)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from canter.algos.offpolicy.ddpg import DDPG
from canter.algos.offpolicy.record import offpolicy_algorithm
from canter.algos.offpolicy.sections import TD3Config
from canter.config.schema import Config


@dataclass(frozen=True)
class TD3(DDPG):
    """The td3 learner of the shared off-policy loop (`OffPolicyLearner`); its state is `DDPGLearner`."""

    cfg: TD3Config
    num_critics: ClassVar[int] = 2

    def target_action(self, next_action: Any, key: Any) -> Any:
        """Target policy smoothing: clipped Gaussian noise on the target actor's action."""
        import jax
        import jax.numpy as jnp

        from canter.algos.offpolicy import losses

        noise = jax.random.normal(key, next_action.shape, jnp.float32)
        return losses.smoothed_target_action(next_action, noise, self.cfg.target_noise, self.cfg.noise_clip)


def _learner(config: Config, spec: Any) -> TD3:
    return TD3(config.td3)


ALGORITHM = offpolicy_algorithm("td3", _learner, TD3.update_metrics)
