"""How the envs of one EnvPool backend are split over concurrent single-threaded pools."""

from __future__ import annotations

import os


def default_shards(num_envs: int) -> int:
    """One single-threaded pool per core this process may run on (a bench or tune job is pinned to its share), fewer
    when there are fewer envs than cores."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return max(1, min(cores, num_envs))


def shard_sizes(num_envs: int, shards: int) -> list[int]:
    """Envs per pool, as even as possible: 5 envs on 2 shards are 3 + 2. An uneven split still steps both pools at
    once, where insisting on an even one would leave 5 envs (5 seeds of one env each) on a single core."""
    if not 1 <= shards <= num_envs:
        raise ValueError(f"{shards} envpool shards cannot split {num_envs} envs; use 1 to {num_envs}")
    base, extra = divmod(num_envs, shards)
    return [base + 1 if i < extra else base for i in range(shards)]
