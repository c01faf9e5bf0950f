"""A saved train state back in memory: the config, the env facts and the state of a checkpoint."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from canter.config.schema import Config
from canter.config.serialize import from_toml_text
from canter.errors import CanterError
from canter.training import checkpoint


@dataclass(frozen=True)
class PolicyFacts:
    """What a policy needs of its env, kept in each checkpoint so that it loads without the env."""

    env_id: str
    backend: str
    obs_dim: int
    act_dim: int
    action_low: np.ndarray
    action_high: np.ndarray
    global_step: int


def policy_facts(header: dict[str, Any], path: Path) -> PolicyFacts:
    """The env facts of a checkpoint's header; a DamagedCheckpoint where any is missing or of the wrong kind."""
    try:
        env = header["env"]
        return PolicyFacts(
            env_id=_text(env["id"]),
            backend=_text(env["backend"]),
            obs_dim=int(env["obs_dim"]),
            act_dim=int(env["act_dim"]),
            action_low=np.asarray(env["action_low"], np.float32),
            action_high=np.asarray(env["action_high"], np.float32),
            global_step=int(header["global_step"]),
        )
    except (KeyError, TypeError, ValueError):
        what = "is corrupt (its header lacks the env facts of its policy)"
        raise checkpoint.DamagedCheckpoint(path, what) from None


def _text(value: Any) -> str:
    if not isinstance(value, str):
        raise TypeError(value)
    return value


def load_state(
    run_dir: Path, which: str | Path = checkpoint.LAST, policy_only: bool = False
) -> tuple[Config, PolicyFacts, Any, dict[str, Any]]:
    """(config, facts, train state, header) from a checkpoint of a run folder: `which` is `last` (the newest),
    `best` or a checkpoint file (`checkpoint.resolve`). `policy_only` leaves unread the fields that only training
    reads (the algorithm's `policy_checkpoint_leaves_out`, a replay buffer): they come back as zeros."""
    from canter.algos import get_algorithm
    from canter.core.runtime import setup_jax

    run_dir = Path(run_dir)
    path = checkpoint.resolve(run_dir, which)
    skip = _training_only_fields(path) if policy_only else ()
    arrays, header = checkpoint.read(path, wanted=lambda name: name.split("/", 1)[0] not in skip)
    config = from_toml_text(checkpoint.config_text(header, path), str(path))
    checkpoint.check_of_run(run_dir, config, path, header)
    facts = policy_facts(header, path)
    setup_jax(facts.backend, announce=False)  # the precision it trained in; where it plays, says its player
    # Only the state's structure, shapes and dtypes: building a real one would compile and run its initializers
    # (seconds, and a replay buffer's worth of memory) just to be overwritten.
    import jax

    template = jax.eval_shape(lambda: get_algorithm(config.run.algo).init_state(config, facts, config.run.seed))
    unread = [name for name in header.get("leaves", ()) if name not in arrays]
    state = checkpoint.restore(template, arrays, path, left_out=[*header.get("left_out", ()), *unread])
    return config, facts, state, header


def _training_only_fields(path: Path) -> tuple[str, ...]:
    """The state's fields that a policy does not read, by the algorithm that the checkpoint's header names; none
    where the header does not say, so that the whole read gives its error."""
    from canter.algos import get_algorithm

    try:
        config = from_toml_text(checkpoint.config_text(checkpoint.read_header(path), path), str(path))
        return get_algorithm(config.run.algo).policy_checkpoint_leaves_out
    except (CanterError, KeyError, ImportError):
        return ()
