"""The bytes of an algorithm's train state, from its shapes alone: `jax.eval_shape` traces `init_state` without
allocating anything, so a replay buffer or networks far beyond the machine's memory are measured as cheaply as
small ones. `Algorithm.size_keys` names the config key behind each large field, so that a state too large for the
memory is refused naming the key to lower (`canter.training.host_memory.check_state_fits`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from canter.algos.protocol import Algorithm
from canter.config.algorithms import key_value
from canter.config.schema import Config
from canter.errors import CanterError

# Halvings tried for a smaller count (2**64 is beyond any the config accepts).
MAX_HALVINGS = 64


@dataclass(frozen=True)
class StateSize:
    total: int  # bytes of one seed's train state
    key: str | None  # the config key behind the largest share of it; None where no field has one
    share: int  # the bytes of that key's fields


def field_bytes(algorithm: Algorithm, config: Config, spec: Any) -> dict[str, int]:
    """The bytes of each field of the train state that `algorithm.init_state(config, spec, seed)` would build."""
    import jax

    shapes = jax.eval_shape(lambda: algorithm.init_state(config, spec, config.run.seed))
    return {
        name: sum(math.prod(leaf.shape) * leaf.dtype.itemsize for leaf in jax.tree.leaves(value))
        for name, value in shapes._asdict().items()
    }


def state_size(algorithm: Algorithm, config: Config, spec: Any) -> StateSize:
    fields = field_bytes(algorithm, config, spec)
    keys = dict(algorithm.size_keys)
    shares: dict[str, int] = {}
    for name, size in fields.items():
        if (key := keys.get(name)) is not None:
            shares[key] = shares.get(key, 0) + size
    key = max(shares, key=lambda k: shares[k], default=None)
    return StateSize(sum(fields.values()), key, shares[key] if key is not None else 0)


def smaller_value(algorithm: Algorithm, config: Config, spec: Any, key: str, fits: Callable[[int], bool]) -> int | None:
    """The first halving of the count `key` (a buffer's capacity) whose train state's total bytes `fits`, among values
    the config accepts (a buffer no smaller than its batch); None where there is none. Layer sizes get none: a state
    that fits says little of the activations that the program's batches need of them."""
    from canter.config.validate import validate

    value = key_value(config, key)
    if not isinstance(value, int):
        return None
    for _ in range(MAX_HALVINGS):
        value //= 2
        if value < 1:
            return None
        section, _, name = key.partition(".")
        smaller = config.with_values(section, **{name: value})
        try:
            validate(smaller)
        except CanterError:
            return None
        if fits(state_size(algorithm, smaller, spec).total):
            return value
    return None
