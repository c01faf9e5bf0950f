"""`canter export`: write a run's deterministic policy as ONNX or as plain numpy arrays."""

from __future__ import annotations

import argparse
from pathlib import Path

from canter.cli.args import add_checkpoint_arg
from canter.errors import CanterError
from canter.files import check_writable, write_output


def register(sub: argparse._SubParsersAction) -> None:
    # It imports JAX and onnx only inside its functions, so parsing stays fast.
    from canter.use.export import FORMATS

    p = sub.add_parser(
        "export",
        help="export the deterministic policy (ONNX or npz)",
        description="Export the deterministic policy of a checkpoint (the newest by default), with "
        "observation normalization and action clipping baked in.",
    )
    p.add_argument("run", help="run folder")
    add_checkpoint_arg(p)
    p.add_argument(
        "--format", choices=tuple(FORMATS), default=None, help="file format (default: from the --out extension)"
    )
    p.add_argument("--out", required=True, help="output file, e.g. policy.onnx or policy.npz")
    p.set_defaults(func=run)


def check_output_path(path: str, flag: str, example: str) -> None:
    """An output path given with `flag` names a file that could be made: not empty, and not under a file (where
    making its folder would only say "File exists"). Checked without writing anything."""
    if not path.strip():
        raise CanterError(f"{flag} is empty; give the file to write, e.g. {flag} {example}")
    if Path(path).is_dir() and not Path(path).is_symlink():  # before its format is read from its name
        raise CanterError(f"cannot write {path}: it is a folder; give a file name, e.g. {flag} {Path(path) / example}")
    for folder in Path(path).parents:  # the nearest that exists decides
        if folder.exists():
            if not folder.is_dir():
                raise CanterError(f"cannot write {path}: {folder} is a file, not a folder; pick another path")
            break


def run(args: argparse.Namespace) -> int:
    from canter.use.export import export_bytes, format_for

    check_output_path(args.out, "--out", "policy.onnx")
    fmt = format_for(args.out, args.format)
    check_writable(args.out)
    write_output(args.out, export_bytes(args.run, fmt, args.checkpoint))
    print(f"wrote {args.out} ({fmt})")
    return 0
