"""`canter plot`: learning curves and training diagnostics of run folders, the seeds of an experiment as one line
with a band."""

from __future__ import annotations

import argparse

from canter.cli.args import check_distinct_runs, comma_entries, seed_arg, whole_arg
from canter.cli.export import check_output_path
from canter.errors import CanterError
from canter.files import check_writable, write_output


def register(sub: argparse._SubParsersAction) -> None:
    # Neither module imports JAX or matplotlib at import time, so parsing stays fast.
    from canter.use.bands import CONFIDENCE, X_AXES
    from canter.use.statistics import MIN_RUNS_FOR_INTERVAL

    p = sub.add_parser(
        "plot",
        help="learning curves and diagnostics of run folders (PNG/SVG/PDF)",
        description="Plot learning curves and diagnostics. Runs whose configs differ only in the seed are drawn as "
        f"one mean line with a band: the range of the runs below {MIN_RUNS_FOR_INTERVAL} runs, a {CONFIDENCE:.0%} "
        f"bootstrap interval from {MIN_RUNS_FOR_INTERVAL} on; groups are labelled by the config keys in which they "
        "differ.",
    )
    p.add_argument("runs", nargs="+", help="run folders")
    p.add_argument("--out", default="curves.png", help="output image; .png, .svg or .pdf (default curves.png)")
    p.add_argument("--x", choices=tuple(X_AXES), default="steps", help="x axis: env steps or wall time (default steps)")
    p.add_argument(
        "--smooth",
        type=whole_arg,
        default=1,
        metavar="W",
        help="trailing moving average over W logged rows of each run (default 1: none)",
    )
    p.add_argument(
        "--metrics",
        type=comma_entries,
        default=None,
        metavar="COL,COL",
        help="metrics.csv columns to draw, one panel each; globs work, e.g. 'info/*' (default: all but info/*)",
    )
    p.add_argument("--seed", type=seed_arg, default=0, help="seed of the bootstrap resampling (default 0)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from canter.use.plot import figure_format, render

    check_distinct_runs(args.runs)
    check_output_path(args.out, "--out", "curves.png")  # before its format is read from its name
    fmt = figure_format(args.out)
    check_writable(args.out)
    if args.metrics == [""]:
        raise CanterError(
            "--metrics is empty; give metrics.csv columns, e.g. --metrics episodic_return,episodic_length"
        )
    metrics = args.metrics
    data = render(args.runs, fmt=fmt, metrics=metrics, x_axis=args.x, smooth=args.smooth, seed=args.seed)
    write_output(args.out, data)
    print(f"wrote {args.out}")
    return 0
