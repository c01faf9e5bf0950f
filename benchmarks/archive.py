"""What the table scripts share: reading an archive of finished bench runs, and rewriting (or checking) the files
and marked blocks that are generated from it.

An archive holds one folder per finished run, named as `canter bench` names them (`<env>__<algo>__s<seed>`), with
the run's config.toml, eval.json, metrics.csv, summary.json and versions.json, and no checkpoints. A long metrics.csv
is kept gzipped, as metrics.csv.gz, which canter's readers (plot, bench's tables) take as they take metrics.csv:
archives are committed, and long runs' metrics make up most of their size."""

from __future__ import annotations

import gzip
import json
import os
import re
import sys
import tarfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from canter.orchestrate.bench_results import seed_record
from canter.run_layout import METRICS_FILE
from canter.training import checkpoint

ROOT = Path(__file__).resolve().parent.parent
# What an archive keeps of a bench run: everything behind its table row, and no checkpoints.
RUN_FILES = ("config.toml", "eval.json", "metrics.csv", "summary.json", "versions.json")


PACKED_METRICS_OVER = 50_000  # bytes of metrics.csv above which the archive keeps it gzipped (2.5-5x smaller)


def has_run_files(folder: Path, files: tuple[str, ...] = RUN_FILES) -> bool:
    """Whether an archived run holds each of `files` (metrics.csv plain or gzipped)."""
    return all((folder / f).is_file() or (f == METRICS_FILE and (folder / f"{f}.gz").is_file()) for f in files)


def copy_run(source: Path, target: Path, files: tuple[str, ...] = RUN_FILES) -> bool:
    """Copy a run's archived files from its run folder, a long metrics.csv gzipped; False (and nothing copied) if one
    is missing."""
    if not all((source / f).is_file() for f in files):
        return False
    target.mkdir(parents=True, exist_ok=True)
    for f in files:
        data = (source / f).read_bytes()
        packed = f == METRICS_FILE and len(data) > PACKED_METRICS_OVER
        kept, stale = (target / f"{f}.gz", target / f) if packed else (target / f, target / f"{f}.gz")
        kept.write_bytes(gzip.compress(data, mtime=0) if packed else data)
        stale.unlink(missing_ok=True)
    return True


def finished_runs(archive: Path, algos: Iterable[str], budget: int) -> dict[tuple[str, str], list[dict[str, Any]]]:
    """(algo, env) -> one record per run that trained `budget` steps and was evaluated, sorted by seed. A record is
    the bench's `seed_record` with the run's `evaluation` (eval.json), `summary` and `folder` added."""
    pattern = re.compile(rf"(.+)__({'|'.join(map(re.escape, algos))})__s(\d+)")
    found: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for folder in sorted(archive.iterdir()) if archive.is_dir() else []:
        match = pattern.fullmatch(folder.name)
        if not match or not (folder / "eval.json").is_file() or not (folder / "summary.json").is_file():
            continue
        summary = json.loads((folder / "summary.json").read_text())
        if summary.get("global_step", 0) < budget:
            continue
        record = seed_record(folder, int(match[3]))
        record.update(evaluation=json.loads((folder / "eval.json").read_text()), summary=summary, folder=folder)
        found.setdefault((match[2], match[1]), []).append(record)
    return {key: sorted(rows, key=lambda r: r["seed"]) for key, rows in found.items()}


def replace_between(text: str, markers: tuple[str, str], block: str) -> str:
    """Put `block` between the start and the end marker, a blank line before the end marker."""
    begin, end = markers
    start = text.index(begin) + len(begin)
    return text[:start] + block + "\n\n" + text[text.index(end, start) :]


def read_text(path: Path) -> str:
    # Bytes, not text: results.csv has \r\n line ends, which text mode would translate.
    return path.read_bytes().decode() if path.is_file() else ""


def sync(wanted: dict[Path, str], check: bool, script: str) -> int:
    """Write every file whose generated content differs; with `check`, only name them and return 1."""
    stale = [path for path, content in wanted.items() if content != read_text(path)]
    if check:
        if stale:
            names = ", ".join(str(p.relative_to(ROOT)) for p in stale)
            print(f"stale tables in {names}; run python {script}", file=sys.stderr)
            return 1
        return 0
    for path in stale:
        path.write_bytes(wanted[path].encode())
    return 0


# ------------------------------------------------------------------------------------------------------ provenance
# canter names a run folder <...>__<YYYYMMDD>-<HHMMSS>-<tag>; an archived run renamed by its page keeps that name in
# the first line of its train.log.
_RUN_DATE = re.compile(r"__(\d{4})(\d{2})(\d{2})-\d{6}-[0-9a-f]{4}")


def _run_dates(folder: Path, versions: dict[str, Any]) -> set[str]:
    """The days a run folder was made on: versions.json's `created` (runs from 2026-11-29 on), else the date in its
    folder's name or its train.log's first lines."""
    if isinstance(versions.get("created"), str):
        return {versions["created"][:10]}
    log = folder / "train.log"
    text = folder.name + (log.read_text(errors="replace")[:2000] if log.is_file() else "")
    return {f"{y}-{m}-{d}" for y, m, d in _RUN_DATE.findall(text)}


def provenance_table(folders: Iterable[Path]) -> str:
    """Which code, machine and library versions trained the archived runs under `folders` (each run's
    versions.json) and on which days: one row per commit, machine and versions. A resumed run counts under the
    commit of its first session, which made its versions.json."""
    rows: dict[tuple[str, str, str], tuple[int, set[str]]] = {}
    for folder in folders:
        for versions_file in sorted(folder.rglob("versions.json")) if folder.is_dir() else []:
            versions = json.loads(versions_file.read_text())
            commit = versions.get("canter_commit")
            code = (
                "not recorded (runs before 2026-11-26)"
                if not commit
                else f"{commit[:7]}" + (" with uncommitted changes" if versions.get("canter_dirty") else "")
            )
            gpu = versions.get("gpu")
            # The kernel build tells this workplace's machines apart, which the CPU's name does not; runs repeat to
            # the bit only on one of them (report 004 measured a first episode that differs across two).
            kernel = str(versions.get("platform") or "").split("-x86_64")[0].split("-aarch64")[0]
            machine = (
                f"{versions.get('cpu', '?')}, {versions.get('cpu_count', '?')} cores"
                + (f", {gpu}" if gpu else "")
                + (f", `{kernel}`" if kernel else "")
            )
            libraries = ", ".join(
                f"{name} {versions[name]}" for name in ("jax", "envpool", "mujoco") if versions.get(name) is not None
            )
            count, dates = rows.get((code, machine, libraries), (0, set()))
            rows[(code, machine, libraries)] = (count + 1, dates | _run_dates(versions_file.parent, versions))
    lines = ["| canter commit | runs | trained | machine | versions |", "|---|---:|---|---|---|"]
    # Runs with no recorded commit are the oldest; the others in order of their first recorded day.
    order = sorted(rows.items(), key=lambda r: (not r[0][0].startswith("not recorded"), min(r[1][1], default=""), r[0]))
    for (code, machine, libraries), (count, dates) in order:
        when = " to ".join(dict.fromkeys([min(dates), max(dates)])) if dates else "not recorded"
        lines.append(f"| {code} | {count} | {when} | {machine} | {libraries} |")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------ in-flight packs
# Work folders (runs/) do not outlive the machine, so a page keeps what a stopped run needs to carry on in a file of
# its own, committed with it: <page>/inflight/<name>.tar. A pack over this size is not kept (an off-policy run's
# replay buffer, for one); such a run starts again on a fresh machine.
PACK_LIMIT_BYTES = 25 * 2**20


def inflight_pack(page: Path, name: str) -> Path:
    return page / "inflight" / f"{name}.tar"


def _kept(item: Path) -> bool:
    """Whether a work folder's file goes into a pack: not TensorBoard files (metrics.csv repeats them), locks or
    hidden files, and of a run's checkpoints only the newest and the best."""
    if "tb" in item.parts or item.name.startswith("."):
        return False
    if item.parent.name != "checkpoints":
        return True
    return item.name == checkpoint.BEST_FILE or item == checkpoint.latest(item.parent.parent)


def write_pack(path: Path, root: Path, members: Sequence[Path]) -> bool:
    """Write `members` (files under `root`, and folders under it whole but for what `_kept` leaves out) to the tar
    file `path`, named relative to `root`. A pack is whole or absent: it is written beside and renamed. False, and
    no pack, when it would be over PACK_LIMIT_BYTES."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".partial")
    with tarfile.open(partial, "w") as tar:
        for member in members:
            files = sorted(f for f in member.rglob("*") if f.is_file()) if member.is_dir() else [member]
            for item in files:
                if _kept(item):
                    tar.add(item, arcname=str(item.relative_to(root)))
    if partial.stat().st_size > PACK_LIMIT_BYTES:
        partial.unlink()
        path.unlink(missing_ok=True)
        return False
    os.replace(partial, path)
    return True


def read_pack(path: Path, root: Path) -> list[str]:
    """Extract the pack's entries into `root` where `root` has nothing of that name (a fresh machine: what is there
    is as new as the pack or newer); returns the top-level names extracted."""
    if not path.is_file():
        return []
    with tarfile.open(path) as tar:
        members = tar.getmembers()
        names = sorted({Path(m.name).parts[0] for m in members})
        fresh = [n for n in names if not (root / n).exists()]
        tar.extractall(root, [m for m in members if Path(m.name).parts[0] in fresh], filter="data")
    return fresh
