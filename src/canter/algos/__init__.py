"""The algorithms: the runtime protocol (`protocol`), the registry of algorithm folders (`registry`), the on-policy
rollout shared by ppo, rpo and trpo, and one folder per family: ppo/ (ppo, rpo), trpo/, offpolicy/ (td3, ddpg, sac).
"""

from canter.algos.protocol import Algorithm, ExportedActor
from canter.algos.registry import (
    algorithm_names,
    check_algorithm_name,
    get_algorithm,
    seeds_train_apart,
)

__all__ = [
    "Algorithm",
    "ExportedActor",
    "algorithm_names",
    "check_algorithm_name",
    "get_algorithm",
    "seeds_train_apart",
]
