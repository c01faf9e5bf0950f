"""Argument helpers shared by the subcommand modules."""

from __future__ import annotations

import argparse


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
