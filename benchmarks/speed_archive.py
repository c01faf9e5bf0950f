"""The raw files behind a speed table, kept beside it.

When a speed benchmark (ppo_speed, td3_speed, time_to_score, multiseed) appends a section to its results.md, it
copies the small files of every process it timed from its git-ignored run folder into `logs/<stamp>/` next to that
results.md, keeping their layout: train and eval logs, and of each canter run summary.json, versions.json,
config.toml, eval.json and metrics.csv (gzipped when it is long). Checkpoints, TensorBoard events, videos and saved
models stay behind. Beside them it writes rows.json, every number the section's tables are rendered from (each row with
its whole-process wall time and SPS), and machine.json, the machine and its load. A script's tables are rendered
from the rows.json record only, so a test can render them again from the archive and compare.

Also the machine description and the commit that every speed section names.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import platform
import re
import subprocess
import sys
from collections.abc import Callable
from datetime import datetime
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
ROWS_FILE, MACHINE_FILE = "rows.json", "machine.json"
KEPT_NAMES = frozenset({"summary.json", "versions.json", "config.toml", "eval.json", "train.json", "metrics.csv"})
KEPT_SUFFIXES = frozenset({".log"})
# bytes; a longer file (a 1M-step td3 run's metrics.csv is ~215 KB) is kept gzipped, and left behind where even that
# is longer (rows.json has every number the tables need)
FILE_LIMIT = 200_000
ARCHIVE_LIMIT = 1_000_000  # bytes; an archive above it is reported, since archives are committed
REQUIRED = ("process_wall", "sps")  # every row states its whole-process wall time and its SPS
# A section renderer: (rows.json record, machine.json, the folder its logs are in) -> markdown.
Render = Callable[[dict, dict[str, Any], str], str]


def machine() -> dict[str, Any]:
    """CPU model, cores (logical and usable by this process), memory, OS, Python, GPU and load averages now."""
    from canter.training.provenance import gpu_name
    from canter.training.run_folder import cpu_name

    cores = os.cpu_count() or 0
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else cores
    memory = ""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                memory = f"{int(line.split()[1]) / 2**20:.0f} GiB"
                break
    except OSError:
        pass
    return {
        "cpu": cpu_name(),
        "cores": f"{cores} logical ({usable} usable)",
        "usable_cores": usable,
        "memory": memory,
        "os": f"{platform.system()} {platform.release()}",
        "python": platform.python_version(),
        "gpu": gpu_name(),
        "load_average_1_5_15_min": [round(x, 2) for x in os.getloadavg()],
    }


def git_commit() -> str:
    """The short commit of this checkout, marked when src/ or pyproject.toml differ from it."""
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--", "src", "pyproject.toml"], cwd=ROOT, capture_output=True, text=True
        ).stdout.strip()
        return commit + (" (src modified)" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def shown(path: Path) -> str:
    """`path` as a section names it: relative to the repository root where it lies inside it."""
    path = path.resolve()
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def logs_dir(results: Path, content: dict) -> Path:
    """Where the section of `content` appended to `results` keeps its raw files: logs/<stamp>/ beside it."""
    started = datetime.fromisoformat(content["started"])
    return results.resolve().parent / "logs" / started.strftime("%Y%m%d-%H%M%S")


def record(benchmark: str, started: datetime, settings: dict[str, Any], rows: list[dict[str, Any]]) -> dict:
    """What rows.json holds: the benchmark, when and how it ran, and its rows (plain JSON values)."""
    for row in rows:
        missing = [key for key in REQUIRED if key not in row]
        if missing:
            raise ValueError(f"a {benchmark} row lacks {', '.join(missing)}: {row}")
    content = {
        "benchmark": benchmark,
        "started": started.isoformat(timespec="seconds"),
        "command": [Path(sys.argv[0]).name, *sys.argv[1:]],
        "commit": git_commit(),
        "settings": settings,
        "rows": rows,
    }
    loaded: dict = json.loads(json.dumps(content, default=str))  # Paths and the like as the file will hold them
    return loaded


def _kept(path: Path) -> tuple[str, bytes] | None:
    """The name and content the archive keeps of the file at `path` (None for nothing)."""
    if path.name not in KEPT_NAMES and path.suffix not in KEPT_SUFFIXES:
        return None
    data = path.read_bytes()
    if len(data) <= FILE_LIMIT:
        return path.name, data
    packed = gzip.compress(data, mtime=0)
    return (f"{path.name}.gz", packed) if len(packed) <= FILE_LIMIT else None


def archive(runs: Path, dest: Path, content: dict, machine_info: dict[str, Any]) -> list[Path]:
    """Copy the small raw files under `runs` into `dest` (same layout), write rows.json and machine.json there, and
    return the files written. Warns when the archive is larger than ARCHIVE_LIMIT."""
    dest.mkdir(parents=True, exist_ok=True)
    written = []
    for path in sorted(p for p in runs.rglob("*") if p.is_file()):
        kept = _kept(path)
        if kept is None:
            continue
        target = (dest / path.relative_to(runs)).with_name(kept[0])
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(kept[1])
        written.append(target)
    for name, data in ((ROWS_FILE, content), (MACHINE_FILE, machine_info)):
        (dest / name).write_text(json.dumps(data, indent=2) + "\n")
        written.append(dest / name)
    size = sum(p.stat().st_size for p in written)
    if size > ARCHIVE_LIMIT:
        print(f"warning: {shown(dest)} holds {size / 1e6:.1f} MB; look for a large log before committing it")
    return written


def load(folder: Path) -> tuple[dict, dict]:
    """The rows.json record and the machine.json of an archive folder."""
    return json.loads((folder / ROWS_FILE).read_text()), json.loads((folder / MACHINE_FILE).read_text())


def publish(content: dict, runs: Path, results: Path | None, head: str, render: Render) -> str:
    """Render the section from `content` and print it. With `results`, also archive the raw files under `runs`
    beside it (the section names that folder) and append the section, to a new file that starts with `head`;
    without, the section names `runs`. Returns the section."""
    machine_info = machine()
    dest = None if results is None else logs_dir(results, content)
    text = render(content, machine_info, shown(dest or runs))
    (runs / ROWS_FILE).write_text(json.dumps(content, indent=2) + "\n")
    print("\n" + text, flush=True)
    if results is not None and dest is not None:
        archive(runs, dest, content, machine_info)
        existing = results.read_text() if results.exists() else head
        results.write_text(existing.rstrip("\n") + "\n\n" + text)
        print(f"appended to {results}; raw files and rows.json in {shown(dest)}")
    return text


def block_logs(readme: str, markers: tuple[str, str]) -> Path | None:
    """The archive a README block names as its raw logs (None for a block that names none)."""
    begin, end = markers
    block = readme[readme.index(begin) : readme.index(end)]
    found = re.search(r"raw\s+logs:\s+\[([^\]]+)\]", block)
    return ROOT / found[1] if found else None


def write_block(folder: Path, markers: tuple[str, str], render: Render, check: bool, readme: Path, option: str) -> int:
    """Render a README block from an archive folder (its text names the folder as `raw logs: [..](..)`); with
    `check`, exit 1 where the README differs instead. `option` is the script's flag that rewrites it."""
    from archive import replace_between  # benchmarks/archive.py; it imports canter, which a timed run does not need

    content, machine_info = load(folder)
    text = readme.read_text()
    wanted = replace_between(text, markers, render(content, machine_info, shown(folder)))
    if wanted == text:
        return 0
    if check:
        print(
            f"{readme}'s {markers[0].strip()} block differs from {folder}; rewrite it with {option} {folder}",
            file=sys.stderr,
        )
        return 1
    readme.write_text(wanted)
    print(f"rewrote the {markers[0].strip()} block of {readme} from {folder}")
    return 0


def parse_with_readme_options(parser: argparse.ArgumentParser, argv: list[str] | None, flag: str, block: str):
    """Parse `argv` after adding `flag LOGS_DIR` (run nothing; rewrite the README's `block` from that archive) and
    `--check` (with `flag`: exit 1 where the README differs instead)."""
    rewrite = f"run nothing; rewrite README.md's {block} from an archive (logs/<stamp>)"
    parser.add_argument(flag, type=Path, metavar="LOGS_DIR", help=rewrite)
    parser.add_argument("--check", action="store_true", help=f"with {flag}: exit 1 if README.md's {block} differs")
    args = parser.parse_args(argv)
    if args.check and not getattr(args, flag.lstrip("-").replace("-", "_")):
        parser.error(f"--check goes with {flag}")
    return args
