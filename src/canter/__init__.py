"""canter: fast, correct PPO for continuous control on MuJoCo, on an ordinary CPU.

    import canter
    result = canter.train(canter.build_config("Hopper-v5", total_steps=200_000))
    policy = canter.load(result.run_dir)
    actions = policy(observations)
"""

import canter.algos  # noqa: F401  (registers every algorithm's config sections and spec)
from canter.config.build import build_config
from canter.config.schema import Config
from canter.errors import CanterError

__version__ = "0.1.0"
__all__ = ["Config", "CanterError", "build_config", "train", "train_seeds", "load", "evaluate", "RunResult",
           "Policy"]


def train(config: Config, *, quiet: bool = True, resume=None, run_dir=None):
    """Train with a resolved config; returns a `RunResult` (run folder, steps, SPS, recent return)."""
    from canter.training.loop import train as _train

    return _train(config, quiet=quiet, resume=resume, run_dir=run_dir)


def train_seeds(config: Config, seeds, quiet: bool = True):
    """Train one run per seed together in one vmapped program; returns one `RunResult` per seed, in order. Each
    seed writes the run folder that `train` with that seed would write."""
    from canter.training.loop import train_seeds as _train_seeds

    return _train_seeds(config, seeds, quiet=quiet)


def load(run_dir):
    """Load the newest checkpoint of a run folder as a callable `Policy`."""
    from canter.use.policy import load as _load

    return _load(run_dir)


def evaluate(policy, episodes: int = 10, deterministic: bool = True, seed: int = 0, env_id=None, backend=None):
    """Evaluate a `Policy` with frozen normalizer statistics; returns an `EvalResult` (returns, lengths, time)."""
    from canter.use.evaluate import evaluate as _evaluate

    return _evaluate(policy, episodes=episodes, deterministic=deterministic, seed=seed, env_id=env_id,
                     backend=backend)


def __getattr__(name):
    if name == "RunResult":
        from canter.training.loop import RunResult

        return RunResult
    if name == "Policy":
        from canter.use.policy import Policy

        return Policy
    raise AttributeError(name)
