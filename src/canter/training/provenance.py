"""Which code and which accelerator made a run, for its versions.json.

Both answers are best effort and never stop a run: without git, outside a checkout, or on a machine without a GPU,
the answer is None and the run goes on. Neither question may slow a CPU run down, so no accelerator library is
imported here: JAX is asked only when the process has already imported it, and nvidia-smi only where it exists.
"""

from __future__ import annotations

import functools
import os
import shutil
import subprocess
import sys
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

# This file's package, canter, is src/canter in a checkout.
_PACKAGE_DIR = Path(__file__).resolve().parent.parent
# git's own variables would point it at another repository than the one around the package.
_GIT_ENVIRONMENT = ("GIT_DIR", "GIT_WORK_TREE", "GIT_INDEX_FILE", "GIT_OBJECT_DIRECTORY", "GIT_COMMON_DIR")
_TIMEOUT_SECONDS = 10


@dataclass(frozen=True)
class Commit:
    sha: str
    dirty: bool


def checkout_root(package_dir: Path) -> Path | None:
    """The git checkout that `package_dir` (the imported canter package) was loaded from, or None.

    Only canter's own src layout counts (`<root>/src/canter` beside `<root>/.git`): a canter installed into a
    virtual environment that happens to sit inside some other repository must not report that repository."""
    package_dir = package_dir.resolve()
    if package_dir.name != "canter" or package_dir.parent.name != "src":
        return None
    root = package_dir.parent.parent
    return root if (root / ".git").exists() else None


def _git(root: Path, *args: str) -> str:
    environment = {k: v for k, v in os.environ.items() if k not in _GIT_ENVIRONMENT}
    # --no-optional-locks: several runs started at once must not fight over the index lock that `status` takes.
    return subprocess.run(
        ["git", "--no-optional-locks", "-C", str(root), *args],
        check=True,
        capture_output=True,
        text=True,
        timeout=_TIMEOUT_SECONDS,
        env=environment,
    ).stdout


# The files of a checkout that make up canter's code. Results written into the checkout (a benchmark's tables and
# logs, a report page) change no run, so they leave the flag clean.
CODE_PATHS = ("src", "pyproject.toml")


def commit_of(root: Path) -> Commit | None:
    """HEAD of the checkout at `root`, and whether its code (CODE_PATHS) differs from it (untracked files that git
    does not ignore count: a new module changes the code as much as an edit does). None when git is missing or
    fails."""
    try:
        sha = _git(root, "rev-parse", "HEAD").strip()
        changes = _git(root, "status", "--porcelain", "--", *CODE_PATHS)
    except (OSError, subprocess.SubprocessError):
        return None
    return Commit(sha, bool(changes.strip())) if sha else None


def canter_commit() -> Commit | None:
    """The commit canter runs from, when it runs from a git checkout (found from the package's own path, not the
    working folder)."""
    root = checkout_root(_PACKAGE_DIR)
    return commit_of(root) if root else None


def describe_gpus(names: Iterable[str]) -> str | None:
    """One line for a set of GPU names: "NVIDIA H100 80GB HBM3", "2 x NVIDIA H100 80GB HBM3", or None."""
    counts = Counter(name.strip() for name in names if name.strip())
    if not counts:
        return None
    return ", ".join(name if n == 1 else f"{n} x {name}" for name, n in counts.items())


def _jax_gpus() -> list[str] | None:
    """The GPUs JAX computes on, or None when JAX has not been imported (importing it here would cost a CPU run
    seconds) or cannot say."""
    jax = sys.modules.get("jax")
    if jax is None:
        return None
    try:
        return [d.device_kind for d in jax.devices() if d.platform in ("gpu", "cuda", "rocm")]
    except Exception:  # any backend failure: the run must go on without this answer
        return None


@functools.cache
def _nvidia_smi_gpus() -> list[str]:
    program = shutil.which("nvidia-smi")
    if program is None:
        return []
    try:
        listing = subprocess.run(
            [program, "--query-gpu=name", "--format=csv,noheader"],
            check=True,
            capture_output=True,
            text=True,
            timeout=_TIMEOUT_SECONDS,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    return listing.splitlines()


def gpu_name() -> str | None:
    """The GPUs JAX computes on if JAX is loaded and uses one, else the machine's GPUs as nvidia-smi lists them."""
    return describe_gpus(_jax_gpus() or []) or describe_gpus(_nvidia_smi_gpus())
