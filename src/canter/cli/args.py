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


def add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seed", type=int, default=None, help="run seed")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
