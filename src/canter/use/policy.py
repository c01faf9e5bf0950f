"""A trained policy as a plain callable: `policy(obs_batch) -> actions` in the env's bounds."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from canter.config.schema import Config
from canter.core.seeding import check_seed
from canter.errors import CanterError
from canter.training.checkpoint import LAST
from canter.training.evaluation import CompiledAct, TracedAct
from canter.training.restore import PolicyFacts, load_state


class Policy:
    """Applies the saved observation normalization (frozen), the actor, and action clipping.

    `checkpoint` says which checkpoint it came from (`last`, `best` or the file); `selection` is the evaluation
    during training that chose a best checkpoint (its header's `evaluation`), None for any other."""

    def __init__(
        self,
        config: Config,
        facts: PolicyFacts,
        params: Any,
        obs_stats: Any,
        source: Path,
        checkpoint: str = LAST,
        selection: dict[str, Any] | None = None,
    ) -> None:
        import jax

        self.config, self.facts, self.params, self.obs_stats, self.source = config, facts, params, obs_stats, source
        self.checkpoint, self.selection = checkpoint, selection
        self._act = CompiledAct(config, facts)
        self._key = jax.random.key(0)  # advanced by each stochastic call

    def traced(self) -> TracedAct:
        """The deterministic policy as a pure JAX function, for envs that play whole episodes in one program."""
        return self._act.traced(self.params, self.obs_stats)

    @property
    def chosen_by_evaluation(self) -> bool:
        return self.selection is not None

    @property
    def obs_dim(self) -> int:
        return self.facts.obs_dim

    @property
    def act_dim(self) -> int:
        return self.facts.act_dim

    def __repr__(self) -> str:
        return (
            f"Policy({self.facts.env_id}, {self.config.run.algo}, step {self.facts.global_step:,}, "
            f"checkpoint={self.checkpoint!r}, obs_dim={self.obs_dim}, act_dim={self.act_dim}, "
            f"source={str(self.source)!r})"
        )

    def __call__(self, obs_batch: np.ndarray, deterministic: bool = True, seed: int | None = None) -> np.ndarray:
        """Actions for one observation [obs_dim] or a batch [B, obs_dim]: the mean action, or with
        `deterministic=False` a sample, from a key that `seed` resets and each sampling call advances. Observations
        are normalized with the saved, frozen statistics; actions are clipped to the env's bounds (float32)."""
        import jax

        if not isinstance(deterministic, bool | np.bool_):  # a string such as "no" would read as true
            raise CanterError(f"deterministic must be True or False, got {deterministic!r}")
        if seed is not None:
            seed = check_seed(seed)
        given: object = obs_batch  # whatever the annotation says, a jitted caller passes a tracer
        if isinstance(given, jax.core.Tracer):  # the policy runs a compiled program of its own, on host arrays
            raise CanterError(
                "a Policy cannot be called inside jax.jit, vmap or grad; use policy.traced(), a pure JAX function of "
                "the same actions, there"
            )
        try:
            if np.iscomplexobj(obs_batch):  # numpy would drop the imaginary part with a warning
                raise CanterError("policy expects real-valued observations, got complex numbers")
            if _holds_none(obs_batch):  # numpy would read each None as NaN, and act on it
                among = "" if obs_batch is None else " among them"
                raise CanterError(
                    f"policy expects numeric observations of shape (batch, {self.obs_dim}), got None{among}"
                )
            obs = np.asarray(obs_batch, np.float32)
        except (TypeError, ValueError):
            if _ragged(obs_batch):
                raise CanterError(
                    f"policy expects observations of shape (batch, {self.obs_dim}), got rows of different lengths"
                ) from None
            raise CanterError(
                f"policy expects numeric observations of shape (batch, {self.obs_dim}), got {type(obs_batch).__name__} "
                "that is not numbers"
            ) from None
        single = obs.ndim == 1
        if single:
            obs = obs[None]
        if obs.ndim != 2 or obs.shape[1] != self.obs_dim:
            raise CanterError(
                f"policy expects observations of shape (batch, {self.obs_dim}), got {np.shape(obs_batch)}"
            )
        key = self._key
        if not deterministic:
            if seed is not None:
                self._key = jax.random.key(seed)
            self._key, key = jax.random.split(self._key)
        # A copy: the caller owns it, and may write to it, where JAX's own buffer is read-only.
        action = np.array(self._act(self.params, self.obs_stats, obs, key, deterministic))
        return action[0] if single else action


def _ragged(obs_batch: Any) -> bool:
    """Rows of different lengths, which numpy cannot stack into one array."""
    try:
        lengths = {len(row) for row in obs_batch}
    except TypeError:
        return False
    return len(lengths) > 1


def _holds_none(obs_batch: Any) -> bool:
    if obs_batch is None:
        return True
    try:
        raw = np.asarray(obs_batch)
    except ValueError:  # ragged: refused as not numbers
        return False
    return raw.dtype == object and any(value is None for value in raw.flat)


def load(run_dir: str | Path, checkpoint: str | Path = LAST, backend: str | None = None) -> Policy:
    """Load a checkpoint of a run folder as a `Policy`: `last` (the newest), `best` (the best evaluated during
    training) or a checkpoint file. `backend`: where it will play, when not on the backend it trained on. JAX is
    set up for that backend before anything loads, since the platform is fixed once: a run trained on EnvPool
    (CPU only) and played on mjx then steps MJX on the GPU where there is one."""
    import jax

    from canter.algos import get_algorithm
    from canter.core.runtime import setup_jax
    from canter.envs.registry import backend_choices, describe_backend_choices
    from canter.training.loop import need_a_folder

    need_a_folder(run_dir, "run_dir", optional=False)
    if backend is not None:
        if backend not in backend_choices():
            choices = describe_backend_choices()
            raise CanterError(f"backend must be a backend name ({choices}) or None for its own, got {backend!r}")
        setup_jax(backend, announce=False)
    config, facts, state, header = load_state(Path(run_dir), checkpoint, policy_only=True)
    params = get_algorithm(config.run.algo).policy_params(state)
    return Policy(
        config,
        facts,
        jax.device_put(params),
        jax.device_put(state.obs_stats),
        Path(run_dir),
        str(checkpoint),
        header.get("evaluation"),
    )
