"""`canter report`: one self-contained HTML page about run folders (config, evaluation, curves, robustness, video)."""

from __future__ import annotations

import argparse
from pathlib import Path

from canter.cli.args import add_checkpoint_arg, check_distinct_runs, check_one_run_for_a_file, seed_arg, whole_arg
from canter.cli.export import check_output_path
from canter.errors import CanterError
from canter.files import check_writable, write_output


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "report",
        help="one self-contained HTML page about run folders",
        description="Write one HTML file with the runs' config, an evaluation table, learning "
        "curves, robustness plots (RUN/robustness/*.png) and a video (RUN/videos/), "
        "all embedded.",
    )
    p.add_argument("runs", nargs="+", help="run folders")
    add_checkpoint_arg(p)
    p.add_argument("--out", default="report.html", help="output HTML file (default report.html)")
    p.add_argument(
        "--episodes", type=whole_arg, default=10, help="evaluation episodes per run (default 10); 0 skips evaluation"
    )
    p.add_argument(
        "--seed", type=seed_arg, default=0, help="evaluation seed, also of the curves' bootstrap (default 0)"
    )
    p.add_argument(
        "--smooth",
        type=whole_arg,
        default=1,
        metavar="W",
        help="curve smoothing, as in `canter plot` (default 1: none)",
    )
    p.add_argument(
        "--video",
        action="store_true",
        help="render one deterministic episode of each run for the page (instead of RUN/videos/)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from canter.use.report import build_report

    check_output_path(args.out, "--out", "report.html")  # an empty or folder --out, named as such
    if Path(args.out).suffix.lower() not in (".html", ".htm"):  # before check_writable, which makes its folders
        raise CanterError(f"--out {args.out}: the report is one HTML page; name it *.html")
    check_distinct_runs(args.runs)
    check_one_run_for_a_file(args.checkpoint, args.runs)
    check_writable(args.out)  # before the evaluation, which can take minutes
    page = build_report(
        args.runs,
        episodes=args.episodes,
        seed=args.seed,
        smooth=args.smooth,
        video=args.video,
        which=args.checkpoint,
    )
    write_output(args.out, page.encode("utf-8"))
    print(f"wrote {args.out}")
    return 0
