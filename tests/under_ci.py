"""The one rule for a test that needs a program pip cannot install (the PostgreSQL server, Chromium).

Outside CI such a test skips, and pytest's `-ra` prints why. Under CI it fails instead, naming the Debian package to
install, so that a CI run cannot be green without the tests that need those programs. CI means the `CI` variable
holds a true value: `.ci/run` exports CI=true, and most CI systems set it too.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import NoReturn

import pytest

TRUE_VALUES = frozenset({"true", "1", "yes", "on"})


def under_ci(environ: Mapping[str, str] | None = None) -> bool:
    value = (os.environ if environ is None else environ).get("CI", "")
    return value.strip().lower() in TRUE_VALUES


def program_missing(reason: str, package: str) -> NoReturn:
    """Skip the calling test outside CI, fail it under CI; `reason` says what is missing, `package` provides it."""
    how = f"install the Debian package {package} (apt-get install -y {package}; .ci/run does it when run as root)"
    if under_ci():
        pytest.fail(f"{reason}, and under CI this test must not skip: {how}", pytrace=False)
    pytest.skip(f"{reason}; {how}")
