"""Argument helpers shared by the subcommand modules."""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from canter.config.values import STEP_LIMIT
from canter.core.seeding import SEED_LIMIT
from canter.errors import CanterError

if TYPE_CHECKING:
    from canter.training.trackers import TrackSpec


def steps_arg(text: str) -> int:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a step count such as 1000000 or 1e6, got {text!r}") from None
    if not value.is_integer() or value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole step count, got {text!r}")
    if value >= STEP_LIMIT:
        raise argparse.ArgumentTypeError(f"expected a step count below 2**53 ({STEP_LIMIT:,}), got {text!r}")
    return int(value)


def limit_arg(text: str) -> float:
    """A limit that inf lifts (--max-minutes, --stop-at-return): a number, or inf; nan and -inf limit nothing, and
    the config's own refusal of them would offer `none`, which a flag does not take."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, or inf for no limit, got {text!r}") from None
    if math.isnan(value) or value == -math.inf:
        raise argparse.ArgumentTypeError(f"expected a finite number, or inf for no limit, got {text!r}")
    return value


def whole_arg(text: str) -> int:
    """A whole number, written as 1000 or as 1e3 (as --total-steps takes it); each command checks its own range."""
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value.is_integer():  # also nan and inf
        raise argparse.ArgumentTypeError(f"expected a whole number such as 10 or 1e3, got {text!r}")
    if abs(value) >= STEP_LIMIT:  # past 2**53 a float skips whole numbers, so 1e17 may not be the number meant
        raise argparse.ArgumentTypeError(f"expected a whole number below 2**53 ({STEP_LIMIT:,}), got {text!r}")
    return int(value)


def seed_arg(text: str) -> int:
    """A whole number from 0 to 2**32 - 1."""
    try:
        seed = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number such as 0, got {text!r}") from None
    if not 0 <= seed < SEED_LIMIT:
        raise argparse.ArgumentTypeError(f"expected a seed from 0 to {SEED_LIMIT - 1}, got {text!r}")
    return seed


def comma_entries(text: str) -> list[str]:
    """The entries of a comma-separated flag value, stripped. An empty one (`a,`, `a,,b`, `,`) is refused, not
    dropped: it is a slip, such as an entry lost in editing, and dropped it would run one cell or draw one panel fewer
    than the user meant, or leave a flag of commas alone at its default."""
    entries = [entry.strip() for entry in text.split(",")]
    if len(entries) > 1 and "" in entries:  # a blank value is another slip, which each flag words itself
        raise argparse.ArgumentTypeError(f"{text!r} has an empty entry; drop the stray comma or fill in the entry")
    return entries


def seeds_arg(text: str) -> tuple[int, ...]:
    """`0,1,2` -> (0, 1, 2): distinct whole numbers separated by commas."""
    entries = comma_entries(text)
    try:
        seeds = tuple(int(part) for part in entries)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected whole numbers separated by commas such as 0,1,2, got {text!r}"
        ) from None
    if len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"each seed may appear once, got {text!r}")
    if not all(0 <= seed < SEED_LIMIT for seed in seeds):
        raise argparse.ArgumentTypeError(f"expected seeds from 0 to {SEED_LIMIT - 1}, got {text!r}")
    return seeds


def check_storage_arg(url: str | None, without: str) -> None:
    """`--storage ''` would read as not given, and the command would quietly use `without` instead."""
    if url == "":
        raise CanterError(
            "--storage is empty; give a database URL such as sqlite:///study.db or postgresql://user:pw@host/db, "
            f"or drop --storage for {without}"
        )


def add_checkpoint_arg(parser: argparse.ArgumentParser) -> None:
    """`--checkpoint last|best|FILE`, with one meaning in every command that reads a run's policy."""
    parser.add_argument(
        "--checkpoint",
        default="last",
        metavar="last|best|FILE",
        help="which checkpoint: last (the newest, default), best (the best evaluated during training, "
        "checkpoints/best.npz; see train --eval-every) or a checkpoint file",
    )


def check_one_run_for_a_file(checkpoint: str, runs: list[str]) -> None:
    """A checkpoint file is one run's; `last` and `best` name one checkpoint in each run folder."""
    # Imported here, not at the top: checkpoint imports JAX, which parsing must not (eval and report have imported
    # it by the time they check).
    from canter.training.checkpoint import BEST, LAST

    if checkpoint not in (LAST, BEST) and len(runs) > 1:
        raise CanterError(
            f"--checkpoint {checkpoint} is one checkpoint file, but {len(runs)} run folders are given; "
            f"pass one run folder, or --checkpoint {LAST} or {BEST}"
        )


def check_distinct_runs(runs: Sequence[str]) -> None:
    """Each run folder once: a repeated one would count as another seed in the means, intervals and tables."""
    seen: dict[Path, str] = {}
    for run in runs:
        key = Path(run).resolve()
        if key in seen:
            same = f"{run!r} twice" if seen[key] == run else f"{seen[key]!r} and {run!r}, the same folder"
            raise CanterError(f"run folders {same}: each run counts once; drop the repeat")
        seen[key] = run


def add_track_args(parser: argparse.ArgumentParser, runs: str) -> None:
    """`--track NAME` (repeatable) and `--mlflow-uri URI`, with one meaning in train, tune and bench; `runs` says
    which tracker runs the command makes."""
    from canter.training.trackers import tracker_names

    parser.add_argument(
        "--track",
        action="append",
        choices=tracker_names(),
        default=[],
        help=f"also log to this experiment tracker (repeatable; extras canter[wandb], canter[mlflow]): {runs}",
    )
    parser.add_argument("--mlflow-uri", default=None, metavar="URI", help="MLflow tracking store for --track mlflow")


def track_spec(args: argparse.Namespace, resumed: Sequence[Path] = ()) -> TrackSpec:
    """The trackers of `--track` and `--mlflow-uri`; resuming run folders, also those they were tracked with."""
    from canter.training.trackers import TrackSpec, resume_spec

    names = tuple(dict.fromkeys(args.track))
    if args.mlflow_uri == "":  # it would read as not given, and MLflow would pick its default store
        raise CanterError("--mlflow-uri is empty; give a store such as sqlite:///mlflow.db, or drop --mlflow-uri")
    spec = resume_spec(names, args.mlflow_uri, resumed) if resumed else TrackSpec(names, args.mlflow_uri)
    if args.mlflow_uri and "mlflow" not in spec.names:
        raise CanterError("--mlflow-uri sets the store of --track mlflow; also pass --track mlflow")
    return spec


def add_backend_arg(parser: argparse.ArgumentParser) -> None:
    """`--backend NAME`, as env.backend, with one meaning in train, tune and bench."""
    from canter.envs.registry import backend_choices

    parser.add_argument(
        "--backend",
        choices=backend_choices(),
        default=None,
        help="env backend, as env.backend (default: the config's, normally auto, the first CPU backend that has the "
        "env; README 'Environments' lists them, docs/gpu.md the ones whose step is JAX)",
    )


def sets_with_backend(args: argparse.Namespace) -> tuple[str, ...]:
    """`--set` values with `--backend X` laid over them as `--set env.backend=X` would be (tune and bench hand their
    `--set` values to every trial or cell); refuses both given, as train does, since one of the two would be ignored."""
    from canter.config.overrides import parse_set_args

    sets = tuple(args.set)
    if args.backend is None:
        return sets
    if "env.backend" in parse_set_args(list(sets)):
        raise CanterError("env.backend is given twice, by --backend and by --set env.backend; give it once")
    return (*sets, f"env.backend={args.backend}")
