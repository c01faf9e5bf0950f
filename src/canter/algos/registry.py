"""The algorithms: one line per algorithm folder, naming the module that declares and registers its spec."""

from __future__ import annotations

import importlib

from canter.algos.protocol import Algorithm
from canter.config.algorithms import (
    algorithm_names,
    algorithm_spec,
    check_algorithm_name,
)
from canter.errors import CanterError

DECLARATIONS = (
    "canter.algos.ppo.sections",  # ppo, rpo
    "canter.algos.trpo.sections",  # trpo
    "canter.algos.offpolicy.sections",  # td3, ddpg, sac
)
for _module in DECLARATIONS:
    importlib.import_module(_module)

__all__ = ["algorithm_names", "check_algorithm_name", "get_algorithm", "seeds_train_apart"]


def get_algorithm(name: str) -> Algorithm:
    """The runtime record (imports the algorithm's JAX code)."""
    runtime = algorithm_spec(name).runtime
    records = getattr(importlib.import_module(runtime), "ALGORITHMS", {})
    if name not in records:  # a packaging slip of the algorithm's own, which a KeyError would not name
        raise CanterError(
            f"algorithm '{name}' names {runtime} as its runtime, but {runtime}.ALGORITHMS has no '{name}' (it has "
            f"{', '.join(map(repr, records)) or 'none'}); key its Algorithm record by the AlgorithmSpec's name"
        )
    return records[name]


def seeds_train_apart(name: str) -> bool:
    return algorithm_spec(name).seeds_train_apart
