"""The `OffPolicyLearner` protocol: one off-policy algorithm as the shared loop (canter.algos.offpolicy.iteration)
drives it."""

from __future__ import annotations

from typing import Any, Protocol

from canter.algos.offpolicy.sections import OffPolicyConfig

# Diagnostics of the updates that every off-policy algorithm reports, averaged over the gradient steps of one call
# (actor terms over the actor steps).
UPDATE_METRICS = ("critic_loss", "actor_loss", "q_mean")
# Reported by the shared loop, after the algorithm's update diagnostics.
LOOP_METRICS = ("gradient_steps", "buffer_size", "learning_rate")


class OffPolicyLearner(Protocol):
    """One off-policy algorithm as the shared loop sees it. Actions are in [-1, 1]; `state` is the algorithm's
    learner state, a NamedTuple holding `actor`, the parameters that `act` takes."""

    # Read-only properties, so that a frozen dataclass with a narrower section or a class-level tuple satisfies them.
    @property
    def cfg(self) -> OffPolicyConfig:
        """The algorithm's own config section: the loop reads the keys that all of them share."""

    @property
    def update_metrics(self) -> tuple[str, ...]:
        """The keys of the diagnostics dict that `update` returns, in metrics.csv order."""

    def init(self, key: Any, obs_dim: int, act_dim: int) -> Any: ...

    def update(self, state: Any, batch: Any, key: Any) -> tuple[Any, dict]:
        """One gradient step on a sampled batch (canter.core.replay.Transitions); diagnostics that a step did not
        compute (a delayed actor step) are NaN."""

    def explore(self, state: Any, obs: Any, ou_state: Any, key: Any) -> tuple[Any, Any]:
        """The behaviour policy's action for normalized `obs` and the next Ornstein-Uhlenbeck noise state."""

    def act(self, actor: Any, obs: Any, key: Any, deterministic: bool) -> Any:
        """The policy's action for normalized `obs`, as `canter.load` gives it."""
