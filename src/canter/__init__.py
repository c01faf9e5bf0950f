"""canter: continuous-control RL for MuJoCo in JAX: PPO, RPO, TRPO, TD3, DDPG and SAC, on EnvPool, Gymnasium, MJX
or Brax envs.

import canter
result = canter.train(canter.build_config("Hopper-v5", total_steps=200_000))
policy = canter.load(result.run_dir)
actions = policy(observations)
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, Literal

import canter.algos  # noqa: F401  (registers every algorithm's config sections and spec)
from canter.config.build import build_config
from canter.config.schema import Config
from canter.errors import CanterError

if TYPE_CHECKING:  # imported lazily below, so that `import canter` stays light
    from collections.abc import Mapping, Sequence
    from pathlib import Path

    from canter.training.seed_run import RunResult
    from canter.use.evaluate import EvalResult
    from canter.use.policy import Policy

__version__ = "0.1.0"
__all__ = [
    "CanterError",
    "Config",
    "EvalResult",
    "Policy",
    "RunResult",
    "build_config",
    "evaluate",
    "load",
    "resume_seeds",
    "train",
    "train_seeds",
]


def train(
    config: Config, *, quiet: bool = True, resume: str | Path | None = None, run_dir: str | Path | None = None
) -> RunResult:
    """Train with a resolved config; returns a `RunResult` (run folder, steps, SPS, recent return). `run_dir`: the
    new run's folder (default: a new one under run.out_dir). `resume`: a run folder to continue from its newest
    checkpoint; `config` must then learn as the run's own does (the same seed and every key that changes what is
    learned; its budget, output and bookkeeping keys may differ), and `resume_seeds([folder], total_steps=...)`
    reads the run's own config."""
    from canter.training.loop import train as _train

    if isinstance(run_dir, str | os.PathLike) and str(run_dir).strip() and resume is None:  # train checks the rest
        from canter.orchestrate.bench_folder import refuse_as_run_dir

        refuse_as_run_dir(run_dir)
    return _train(config, quiet=quiet, resume=resume, run_dir=run_dir)


def train_seeds(config: Config, seeds: Sequence[int], quiet: bool = True) -> list[RunResult]:
    """Train one run per seed together in one vmapped program; returns one `RunResult` per seed, in order. Each
    seed writes the run folder that `train` with that seed would write."""
    from canter.training.loop import train_seeds as _train_seeds

    return _train_seeds(config, seeds, quiet=quiet)


def resume_seeds(
    run_dirs: Sequence[str | Path],
    total_steps: int | None = None,
    *,
    max_minutes: float | None = None,
    stop_at_return: float | None | Literal["keep"] = "keep",
    quiet: bool = True,
) -> list[RunResult]:
    """Resume the run folders of one `train_seeds` group together, each from its newest checkpoint, as each would
    resume alone. `total_steps` and `max_minutes` (inf: none) replace the saved budget where given; `stop_at_return`
    replaces the saved return target ("keep": leave it; None: no target)."""
    from canter.training.loop import resume_seeds as _resume_seeds
    from canter.training.resume import Saved

    target = Saved.KEEP if isinstance(stop_at_return, str) and stop_at_return == "keep" else stop_at_return
    return _resume_seeds(run_dirs, total_steps, max_minutes=max_minutes, stop_at_return=target, quiet=quiet)


def load(run_dir: str | Path, checkpoint: str | Path = "last", backend: str | None = None) -> Policy:
    """Load a checkpoint of a run folder as a callable `Policy`: `"last"` (the newest), `"best"` (the best state
    evaluated during training, `run.eval_every`) or a checkpoint file. `backend`: where it will be evaluated, when
    not on its own backend; an EnvPool run evaluated on `"mjx"` then steps MJX on the GPU where there is one."""
    from canter.use.policy import load as _load

    return _load(run_dir, checkpoint, backend)


def evaluate(
    policy: Policy,
    episodes: int = 10,
    deterministic: bool = True,
    seed: int = 0,
    env_id: str | None = None,
    backend: str | None = None,
    physics: Mapping[str, Any] | None = None,
) -> EvalResult:
    """Evaluate a `Policy` with frozen normalizer statistics; returns an `EvalResult` (returns, lengths, time). A
    best checkpoint plays held-out env seeds, which the evaluations that chose it never played. With
    `deterministic=False` the actions are sampled from a stream that `seed` starts, apart from the policy's own.
    `physics` changes the eval envs' physics settings on mjx, e.g. `{"solver_iterations": 4}` (default: the run's
    own)."""
    from canter.use.evaluate import evaluate as _evaluate

    return _evaluate(
        policy,
        episodes=episodes,
        deterministic=deterministic,
        seed=seed,
        env_id=env_id,
        backend=backend,
        physics=physics,
    )


# The exported classes, imported on first use so that `import canter` stays light: name -> its module.
_LAZY_CLASSES = {
    "RunResult": "canter.training.seed_run",
    "Policy": "canter.use.policy",
    "EvalResult": "canter.training.evaluation",
}


def __getattr__(name: str) -> type:
    if name not in _LAZY_CLASSES:
        raise AttributeError(f"module 'canter' has no attribute {name!r}")
    import importlib

    cls: type = getattr(importlib.import_module(_LAZY_CLASSES[name]), name)
    return cls


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
