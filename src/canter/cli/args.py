"""Argument helpers shared by the subcommand modules."""

from __future__ import annotations

import argparse

from canter.errors import CanterError


def steps_arg(text: str) -> int:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a step count such as 1000000 or 1e6, got {text!r}") from None
    if not value.is_integer() or value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole step count, got {text!r}")
    return int(value)


def seeds_arg(text: str) -> tuple[int, ...]:
    """`0,1,2` -> (0, 1, 2): distinct whole numbers separated by commas."""
    try:
        seeds = tuple(int(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected whole numbers separated by commas such as 0,1,2, got {text!r}"
        ) from None
    if len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"each seed may appear once, got {text!r}")
    return seeds


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
    if checkpoint not in ("last", "best") and len(runs) > 1:
        raise CanterError(
            f"--checkpoint {checkpoint} is one checkpoint file, but {len(runs)} run folders are given; "
            f"pass one run folder, or --checkpoint last or best"
        )
