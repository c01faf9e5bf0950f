"""The return of a policy that acts uniformly at random: the zero of normalized scores (`canter.use.reference_scores`).

Each env id's value is measured by canter on the env canter trains on, and shipped in `canter/data/random.toml`
with the command that wrote it:

    python -m canter.use.random_score --episodes 100 --out src/canter/data/random.toml

Actions are drawn uniformly between the action bounds from `np.random.default_rng(seed)`, one per env per step.
The episodes are played as `canter eval` plays them (`canter.training.evaluation.run_episodes`): every env runs a
fixed quota of episodes to their end (termination or the time limit), so short episodes are not over-represented.
On a JAX backend (mjx, brax) that means up to 1024 envs at once, as `canter eval` plays them there, where EnvPool and
Gymnasium play at most 32.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from datetime import UTC, datetime

import numpy as np

from canter.core.seeding import EVAL, SEED_LIMIT, env_seeds
from canter.errors import CanterError

# The published environments (canter/data/published.toml) in both MuJoCo versions canter trains on.
PUBLISHED_BASES = (
    "HalfCheetah",
    "Hopper",
    "Walker2d",
    "Ant",
    "Humanoid",
    "HumanoidStandup",
    "Swimmer",
    "InvertedPendulum",
    "InvertedDoublePendulum",
    "Reacher",
    "Pusher",
)
DEFAULT_ENVS = tuple(f"{base}-v{version}" for base in PUBLISHED_BASES for version in (4, 5))


def random_returns(env_id: str, episodes: int, seed: int = 0, backend: str = "auto") -> tuple[np.ndarray, str]:
    """(returns of `episodes` episodes of uniformly random actions, the backend that ran them)."""
    from canter.envs.registry import make_vec_env, resolve_backend
    from canter.training.evaluation import run_episodes

    if episodes < 1:
        raise CanterError(f"--episodes must be >= 1, got {episodes}")
    backend = resolve_backend(env_id, backend)
    # run_episodes makes its own envs and shows `act` only their observations, so the bounds come from one env
    # made to read them.
    probe = make_vec_env(env_id, backend, 1, env_seeds(seed, 1, EVAL))
    try:
        low = np.asarray(probe.spec.action_low, np.float32)
        high = np.asarray(probe.spec.action_high, np.float32)
    finally:
        probe.close()
    rng = np.random.default_rng(seed)

    def act(obs: np.ndarray) -> np.ndarray:
        return rng.uniform(low, high, size=(len(obs), low.size)).astype(np.float32)

    return run_episodes(act, env_id, backend, episodes, seed).returns, backend


def random_toml(rows: Sequence[tuple[str, np.ndarray, str]], command: str, seed: int) -> str:
    """The file canter/data/random.toml: the command that wrote it, then one table per env id."""
    from canter import __version__

    lines = [
        "# Return of uniformly random actions per env, measured by canter (canter.use.random_score): the zero point",
        "# of normalized scores, (score - random) / (reference - random). Written by the command below; rerun it to",
        "# measure again.",
        f'command = "{command}"',
        f'written = "{datetime.now(UTC).strftime("%Y-%m-%d")} by canter {__version__}"',
        f"seed = {seed}",
        "",
    ]
    for env_id, returns, backend in rows:
        lines += [
            f'[env."{env_id}"]',
            f"mean = {float(returns.mean()):.4f}",
            f"std = {float(returns.std()):.4f}",
            f"episodes = {returns.size}",
            f'backend = "{backend}"',
            "",
        ]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m canter.use.random_score",
        description="Measure the return of uniformly random actions per env and write canter/data/random.toml.",
    )
    parser.add_argument("envs", nargs="*", default=list(DEFAULT_ENVS), help="env ids (default: the published envs)")
    parser.add_argument("--episodes", type=int, default=100, help="episodes per env (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the actions and the env seeds")
    parser.add_argument("--out", required=True, help="TOML file to write")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if not 0 <= args.seed < SEED_LIMIT:
        parser.error(f"--seed must be from 0 to {SEED_LIMIT - 1}, got {args.seed}")
    from canter.files import write_output

    rows = []
    for env_id in args.envs:
        returns, backend = random_returns(env_id, args.episodes, args.seed)
        print(f"{env_id:28s} {returns.mean():12.3f} ± {returns.std():10.3f} ({returns.size} episodes, {backend})")
        rows.append((env_id, returns, backend))
    shown_envs = "" if list(args.envs) == list(DEFAULT_ENVS) else " " + " ".join(args.envs)
    command = (
        f"python -m canter.use.random_score{shown_envs} --episodes {args.episodes} --seed {args.seed} --out {args.out}"
    )
    write_output(args.out, random_toml(rows, command, args.seed).encode())
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except CanterError as exc:
        print(f"python -m canter.use.random_score: error: {exc}", file=sys.stderr)  # as argparse's own errors
        sys.exit(2)
