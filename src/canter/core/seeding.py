"""Per-env seeds derived from (run seed, purpose, env index).

EnvPool seeds env i with `seed + i` when given an integer, so runs with seeds 0 and 1 would share all but one env
stream. Hashing through numpy's SeedSequence gives statistically independent 31-bit seeds instead.
"""

from __future__ import annotations

import numpy as np

from canter.config.values import SEED_LIMIT
from canter.errors import CanterError

__all__ = ["EVAL", "HELD_OUT", "RESUME", "SEED_LIMIT", "TRAIN", "check_seed", "env_seeds"]

# Purposes keep streams apart: training envs, envs recreated on resume (mixed with the step), evaluation envs (of
# `canter eval` and of evaluations during training), and held-out evaluation envs for a checkpoint that was chosen
# on EVAL episodes (best.npz), whose score on those episodes would be biased upward.
TRAIN, RESUME, EVAL, HELD_OUT = 0, 1, 2, 3


def check_seed(seed: object, name: str = "seed") -> int:
    """A seed given to the Python API: a whole number from 0 to SEED_LIMIT - 1 (not a bool, not a float)."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or not 0 <= int(seed) < SEED_LIMIT:
        raise CanterError(f"{name} must be a whole number from 0 to {SEED_LIMIT - 1}, got {seed!r}")
    return int(seed)


def env_seeds(run_seed: int, num_envs: int, purpose: int = TRAIN, salt: int = 0) -> list[int]:
    sequence = np.random.SeedSequence([int(run_seed) & 0xFFFFFFFF, purpose, int(salt) & 0xFFFFFFFFFFFF, 0x63616E74])
    return [int(s) & 0x7FFFFFFF for s in sequence.generate_state(num_envs, dtype=np.uint32)]
