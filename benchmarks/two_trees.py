"""What the benchmarks that time two source trees side by side share: the `src/` of a git ref, the heading that
dates each section of results, and appending a section and its raw rows beside the script that measured them."""

from __future__ import annotations

import json
import os
import platform
import subprocess
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, check=True, capture_output=True, text=True).stdout.strip()


def commits(before: str) -> tuple[str, str]:
    """The short hashes of `before` and of HEAD."""
    return git("rev-parse", "--short", before), git("rev-parse", "--short", "HEAD")


def extract_src(ref: str, into: Path) -> Path:
    """The `src/` folder of `ref`, written under `into`; its path."""
    archive = subprocess.run(["git", "archive", ref, "src"], cwd=ROOT, check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into / "src"


def heading(now: str, before: str) -> str:
    """A results section's heading: when, on what machine, which commits."""
    machine = platform.processor() or platform.machine()
    return f"## {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, {machine}, {os.cpu_count()} cores, {now} against {before}"


def append_results(
    folder: Path, title: str, lines: Sequence[str], raw_file: str, rows: Sequence[dict[str, Any]], **shared: Any
) -> None:
    """Append each raw row, with the fields all rows share, to `raw_file` (JSON lines) and the section `lines` to
    results.md, which starts with `title` when this makes it."""
    with (folder / raw_file).open("a") as f:
        for row in rows:
            f.write(json.dumps(dict(row, **shared)) + "\n")
    results = folder / "results.md"
    head = "" if results.exists() else f"# {title}\n\n"
    with results.open("a") as f:
        f.write(head + "\n".join(lines) + "\n")
