"""A run folder: its name, what it holds, its format version, and the one migration path from each older format.

A run folder holds config.toml (what the run reads of its config), versions.json (the packages, code commit and
machine that made it, and `run_format`), metrics.csv, summary.json, checkpoints/, and optionally tb/ and videos/. An
archived copy of a finished run may hold metrics.csv gzipped as metrics.csv.gz; every reader takes either.

Formats:
- 1: config.toml holds every config section, whether the algorithm reads it or not; versions.json has no
  `run_format`.
- 2: config.toml holds env, run and what the algorithm reads (`canter.config.serialize`).

Reading never writes: a folder of any known format reads as the same config (keys a format-1 file holds but the
algorithm does not read are ignored). Writing to a folder (`--resume`) first migrates it to the current format; a
versions.json that is missing (format 1, as a file without `run_format`) or damaged is then written again with the
resuming session's versions and a `repaired` entry, which keeps a damaged file's text.
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import secrets
import sys
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from canter.config.schema import Config
from canter.config.serialize import from_toml_text, to_toml
from canter.errors import CanterError, resume_run, with_python
from canter.files import atomic_write_bytes, refuse_out_dir_in_a_run
from canter.run_layout import (
    ARCHIVED_METRICS_FILE,
    BEST_FILE,
    CHECKPOINT_FOLDER,
    CHECKPOINT_NAME,
    CONFIG_FILE,
    KEPT_BEST_FILE,
    METRICS_FILE,
    RUN_FORMAT,
    TENSORBOARD_FOLDER,
    TRACKERS_FILE,
    VERSIONS_FILE,
    VIDEOS_FOLDER,
    checkpoints_in,
    read_versions,
    run_files_in,
    run_format,
    versions_record,
)
from canter.training import provenance


def metrics_file(run_dir: Path) -> Path:
    """The run's metrics.csv, or metrics.csv.gz where only an archived, gzipped copy is there."""
    plain = Path(run_dir) / METRICS_FILE
    packed = plain.with_name(METRICS_FILE + ".gz")
    return packed if not plain.is_file() and packed.is_file() else plain


def _safe(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in text)


def new_run_dir(config: Config) -> Path:
    """A new run folder's path in run.out_dir, named by its env, algorithm, preset, seed and start time."""
    refuse_out_dir_in_a_run(config.run.out_dir, "--out-dir", "run.out_dir")
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    name = (
        f"{_safe(config.env.id)}__{config.run.algo}__{_safe(config.run.preset)}__s{config.run.seed}__"
        f"{stamp}-{secrets.token_hex(2)}"
    )
    return Path(config.run.out_dir) / name


def cpu_name() -> str:
    """The CPU model from /proc/cpuinfo where there is one (benchmark tables need more than 'x86_64')."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def versions() -> dict[str, Any]:
    """The packages, code and machine that make a run. `canter` is the package version; `canter_commit` and
    `canter_dirty` name the git commit canter runs from and whether the checkout differs from it, and are null when
    it does not run from a checkout (or git is missing). `gpu` is null without a GPU."""
    from importlib import metadata

    def version(name: str) -> str | None:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return None

    commit = provenance.canter_commit()
    return {
        "canter": version("canter"),
        "canter_commit": commit.sha if commit else None,
        "canter_dirty": commit.dirty if commit else None,
        "python": platform.python_version(),
        "jax": version("jax"),
        "jaxlib": version("jaxlib"),
        "optax": version("optax"),
        "envpool": version("envpool"),
        "mujoco": version("mujoco"),
        "gymnasium": version("gymnasium"),
        "numpy": version("numpy"),
        "platform": platform.platform(),
        "cpu": cpu_name(),
        "cpu_count": os.cpu_count(),
        "gpu": provenance.gpu_name(),
    }


def _write_versions(run_dir: Path, data: dict[str, Any]) -> None:
    atomic_write_bytes(Path(run_dir) / VERSIONS_FILE, lambda f: f.write(json.dumps(data, indent=2).encode()))


def checkpoint_dir(run_dir: Path) -> Path:
    return Path(run_dir) / CHECKPOINT_FOLDER


def checkpoint_path(run_dir: Path, step: int) -> Path:
    return checkpoint_dir(run_dir) / f"ckpt_{step:012d}.npz"


def step_of(path: Path) -> int:
    """The env step in a `ckpt_<step>.npz` name."""
    found = CHECKPOINT_NAME.match(Path(path).name)
    if found is None:
        raise ValueError(f"{path} is not named ckpt_<step>.npz")
    return int(found.group(1))


def list_checkpoints(run_dir: Path) -> list[Path]:
    return checkpoints_in(run_dir)


def damaged_config_fix(run_dir: Path) -> str:
    """What restores a damaged config.toml: each checkpoint holds the run's config, so with one the resume writes it
    again."""
    if not list_checkpoints(run_dir):
        return "the run folder is damaged and has no checkpoint that holds its config; restore config.toml from a copy"
    return (
        f"the run folder is damaged; restore config.toml from a copy, or let {resume_run(run_dir)} write it again "
        f"from the newest checkpoint (a run short of its budget also trains on; eval, video and export work as it is)"
    )


def read_config(run_dir: Path) -> Config:
    path = Path(run_dir) / CONFIG_FILE
    if path.is_dir():
        raise CanterError(f"{path} is a folder, where the run keeps its config.toml file; move it out of the way")
    if not path.is_file():
        # A folder with a run's own files (checkpoints, metrics) is a run that lost its config, which a checkpoint
        # can give back; only a folder with none of them may be no run at all.
        if run_files_in(run_dir):
            raise CanterError(f"{run_dir} has no config.toml: {damaged_config_fix(run_dir)}")
        raise CanterError(f"{run_dir} has no config.toml; is it a canter run folder?")
    run_format(run_dir)
    text = path.read_text(errors="replace")
    if not text.strip():
        raise CanterError(f"{path} is empty: {damaged_config_fix(run_dir)}")
    try:
        return from_toml_text(text, str(path))
    except CanterError as exc:
        if str(exc).startswith("malformed TOML"):
            raise CanterError(f"{exc}; {damaged_config_fix(run_dir)}") from None
        # A file that reads but holds what canter refuses was edited: a resume does not overwrite it unasked.
        fix = (
            f"correct it, or move config.toml away and let {resume_run(run_dir)} write it again from the newest "
            "checkpoint"
            if list_checkpoints(run_dir)
            else "correct it, or restore config.toml from a copy"
        )
        # A value the validation refuses names no file, and among several run folders the damaged one must show.
        refusal = str(exc) if str(path) in str(exc) else f"{exc} (in {path})"
        # A refusal may end in its own question ("did you mean ...?"), which the fix follows as a new sentence.
        joined = f"{refusal} {fix[0].upper()}{fix[1:]}" if refusal.endswith("?") else f"{refusal}; {fix}"
        raise CanterError(joined) from None


def _keys_apart(run_dir: Path, checkpoint_config: Config) -> list[str]:
    """The experiment keys (and the seed) in which a checkpoint's config differs from the run folder's config.toml;
    [] when they agree or the folder has no readable config.toml to compare with (what needs it refuses such a
    folder itself). The step budget may differ: a resume extends it."""
    from canter.config.experiment import differing_keys

    try:
        own = read_config(run_dir)
    except CanterError:
        return []
    keys = differing_keys([own, checkpoint_config])
    if own.run.seed != checkpoint_config.run.seed:
        keys.append("run.seed")
    # Another algorithm or env changes dozens of keys with it; the message shows only the first few, so these first.
    return sorted(keys, key=lambda key: key not in _ROOT_KEYS)


_ROOT_KEYS = frozenset({"run.algo", "env.id", "env.backend"})


def _shown_keys(keys: list[str]) -> str:
    return ", ".join(keys[:3]) + (f" and {len(keys) - 3} more" if len(keys) > 3 else "")


# What a resume may change; from Python they are train's config keys, and resume_seeds takes them by the same names.
_BUDGET = with_python(
    "--total-steps, --max-minutes, --stop-at-return", "run.total_steps, run.max_minutes, run.stop_at_return"
)


def check_own_checkpoint(run_dir: Path, checkpoint_config: Config, path: Path) -> None:
    """A checkpoint found in a run folder's checkpoints/ was written by that run: the same experiment and seed. A
    checkpoint copied in from another run is refused."""
    run_format(run_dir)  # a newer canter's folder may keep what this one would misread, as plot and resume refuse it
    keys = _keys_apart(run_dir, checkpoint_config)
    if keys:
        raise CanterError(
            f"{path} does not match {run_dir / CONFIG_FILE} in {_shown_keys(keys)}: if config.toml was edited, put "
            f"back what the checkpoint holds, as a resume changes only the budget: {_BUDGET}; if the checkpoint came "
            f"from another run, move it out of {path.parent}"
        )


def check_given_checkpoint(run_dir: Path, checkpoint_config: Config, path: Path) -> None:
    """A checkpoint file given with a run folder (`--checkpoint FILE`) is one of that run's, kept elsewhere: the
    results are labelled with the folder, so a checkpoint of another run would be reported as this one."""
    run_format(run_dir)
    keys = _keys_apart(run_dir, checkpoint_config)
    if keys:
        raise CanterError(
            f"{path} is a checkpoint of another run than {run_dir} (they differ in {_shown_keys(keys)}); pass the "
            f"run folder it came from"
        )


def write_config(run_dir: Path, config: Config) -> None:
    atomic_write_bytes(Path(run_dir) / CONFIG_FILE, lambda f: f.write(to_toml(config).encode()))


def create(run_dir: Path, config: Config) -> None:
    """Start a new run folder in the current format; versions.json records when (UTC), as evidence of when a result
    was made, which a folder renamed into an archive no longer says."""
    Path(run_dir).mkdir(parents=True, exist_ok=True)
    write_config(run_dir, config)
    created = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    _write_versions(run_dir, dict(versions(), created=created, run_format=RUN_FORMAT))


def discard_unstarted(run_dir: Path) -> None:
    """Remove what a new run wrote before its first iteration (config.toml, versions.json, trackers.json, a
    metrics.csv without rows, TensorBoard's folder) when a refusal stops it there: no folder is left that nothing can
    resume or plot. A folder with a checkpoint, a line of metrics after the header (whole or not) or an archived
    metrics file is left whole; what else is in it stays."""
    run_dir = Path(run_dir)
    metrics = run_dir / METRICS_FILE
    try:
        logged = metrics.is_file() and metrics.read_bytes().rstrip(b"\n").count(b"\n") > 0
    except OSError:  # unreadable: not this session's, which wrote a header at most
        return
    if list_checkpoints(run_dir) or logged or (run_dir / ARCHIVED_METRICS_FILE).exists():
        return
    for name in (CONFIG_FILE, VERSIONS_FILE, TRACKERS_FILE, METRICS_FILE):
        with contextlib.suppress(OSError):  # an unwritable folder: the refusal that brought us here is what to tell
            (run_dir / name).unlink(missing_ok=True)
    for events in (run_dir / TENSORBOARD_FOLDER).glob("events.out.tfevents.*"):  # a user's own files there stay
        with contextlib.suppress(OSError):
            events.unlink()
    with contextlib.suppress(OSError):
        (run_dir / TENSORBOARD_FOLDER).rmdir()


# What a run writes before its first checkpoint, by folder: a restart removes these and nothing else.
WRITTEN_BEFORE_A_CHECKPOINT = {
    ".": (METRICS_FILE, TRACKERS_FILE),
    TENSORBOARD_FOLDER: ("events.out.tfevents.*",),
    VIDEOS_FOLDER: ("step_*.mp4", ".snapshot_*.npz", ".*.tmp*", "render.log"),
    CHECKPOINT_FOLDER: (BEST_FILE, KEPT_BEST_FILE, ".*.tmp"),
}


def clear_for_a_restart(run_dir: Path) -> None:
    """Remove what a run logged before it stopped short of its first checkpoint (its metrics, events, videos,
    tracker runs, a best.npz), keeping its config.toml and every file canter does not write: it trains again from
    step 0, and its folder then holds that run alone. Folders left empty go too."""
    run_dir = Path(run_dir)
    for folder, patterns in WRITTEN_BEFORE_A_CHECKPOINT.items():
        for pattern in patterns:
            for path in (run_dir / folder).glob(pattern):
                if path.is_file() or path.is_symlink():
                    path.unlink()
        if folder != ".":
            with contextlib.suppress(OSError):  # not empty, or not there: left as it is
                (run_dir / folder).rmdir()


def _config_reads_only(run_dir: Path) -> None:
    """1 -> 2: config.toml keeps only what the run's algorithm reads."""
    write_config(run_dir, read_config(run_dir))


MIGRATIONS: dict[int, Callable[[Path], None]] = {1: _config_reads_only}


def _repair_versions(run_dir: Path, found: int) -> None:
    """A versions.json that is missing or damaged is written again before a resume writes to the folder, with this
    session's versions and a `repaired` entry that says when and why, and keeps the damaged file's text whole."""
    _, problem = versions_record(run_dir)
    if problem is None:
        return
    path = Path(run_dir) / VERSIONS_FILE
    repaired: dict[str, Any] = {"at": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"), "reason": problem}
    if problem != "missing":
        repaired["text"] = path.read_text(errors="replace")
    _write_versions(run_dir, {**versions(), "run_format": found, "repaired": repaired})
    print(
        f"canter: note: {path} was {problem}; wrote it with this session's versions (the versions that made the "
        f'run are unknown) and the old text under "repaired"'
        if problem != "missing"
        else f"canter: note: {run_dir} had no {VERSIONS_FILE}, so it is run format {found}; wrote one with this "
        f"session's versions (the versions that made the run are unknown)",
        file=sys.stderr,
    )


def migrate(run_dir: Path) -> None:
    """Bring a folder to the current format in place, one version at a time."""
    found = run_format(run_dir)
    _repair_versions(Path(run_dir), found)
    for version in range(found, RUN_FORMAT):
        MIGRATIONS[version](Path(run_dir))
        _write_versions(run_dir, dict(read_versions(run_dir), run_format=version + 1))
