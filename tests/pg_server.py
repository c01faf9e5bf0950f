"""A real, throwaway PostgreSQL server for the distributed tests (session-scoped fixture `postgres_url`).

Nothing is installed here: CI installs Debian's postgresql package (.ci/run). Without it the tests that need the
server skip, or fail under CI (`under_ci`). The server runs from a temp data folder on a free port and is stopped at
the end. PostgreSQL refuses to run as root, so under root it runs as the `postgres` user.
"""

import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
from pathlib import Path

import pytest

from under_ci import program_missing


def _bin_dir() -> Path | None:
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"), key=lambda p: int(p.split("/")[4]))
    if found:
        return Path(found[-1]).parent
    initdb = shutil.which("initdb")
    return Path(initdb).parent if initdb else None


# How to stop and start the session's server again (`stop_server`, `start_server`), set by the fixture.
_CONTROL: dict[str, list[str]] = {}


def stop_server() -> None:
    """Stop the running server at once, as a crash or a restart would (its data stays)."""
    subprocess.run(_CONTROL["stop"], check=True, capture_output=True, timeout=60)


def start_server() -> None:
    subprocess.run(_CONTROL["start"], check=True, capture_output=True, timeout=120)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="session")
def postgres_url():
    bin_dir = _bin_dir()
    if bin_dir is None or not (bin_dir / "pg_ctl").exists():
        program_missing("PostgreSQL server binaries (initdb, pg_ctl) are not installed", "postgresql")
    as_user: list[str] = []
    folder = Path(tempfile.mkdtemp(prefix="canter-pg-"))
    if os.geteuid() == 0:
        try:
            user = pwd.getpwnam("postgres")
        except KeyError:
            program_missing("running as root and there is no 'postgres' user to run the server as", "postgresql")
        os.chown(folder, user.pw_uid, user.pw_gid)
        as_user = ["runuser", "-u", "postgres", "--"]
    data, log = folder / "data", folder / "server.log"
    port = _free_port()

    def run(*args: object) -> subprocess.CompletedProcess:
        return subprocess.run(as_user + [str(a) for a in args], check=True, capture_output=True, timeout=120)

    run(bin_dir / "initdb", "-D", data, "-A", "trust", "-U", "postgres", "--no-sync", "-E", "UTF8")
    options = f"-p {port} -k {folder} -c listen_addresses=127.0.0.1 -c fsync=off -c max_connections=50"
    pg_ctl = [*as_user, str(bin_dir / "pg_ctl"), "-D", str(data)]
    _CONTROL["start"] = [*pg_ctl, "-l", str(log), "-w", "-t", "60", "-o", options, "start"]
    _CONTROL["stop"] = [*pg_ctl, "-m", "fast", "-w", "stop"]
    start_server()
    try:
        yield f"postgresql://postgres@127.0.0.1:{port}/postgres"
    finally:
        subprocess.run(
            as_user + [str(bin_dir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"],
            capture_output=True,
            timeout=60,
        )
        shutil.rmtree(folder, ignore_errors=True)
