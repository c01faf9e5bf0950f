"""The CI rule for tests whose programs are missing (tests/under_ci.py), and the CI entry point that relies on it."""

import re
from pathlib import Path

import pytest

from under_ci import program_missing, under_ci

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("value", ["true", "TRUE", "True", "1", "yes", "Yes", "on", " true\n"])
def test_a_true_ci_value_means_ci(monkeypatch, value):
    monkeypatch.setenv("CI", value)
    assert under_ci()


@pytest.mark.parametrize("value", ["", "false", "0", "no", "off", "ci"])
def test_an_unset_or_false_ci_value_means_a_local_run(monkeypatch, value):
    monkeypatch.setenv("CI", value)
    assert not under_ci()
    monkeypatch.delenv("CI")
    assert not under_ci()


def test_an_explicit_environment_is_read_instead_of_the_process_one(monkeypatch):
    monkeypatch.delenv("CI", raising=False)
    assert under_ci({"CI": "1"}) and not under_ci({})


def test_a_missing_program_fails_under_ci_naming_the_package(monkeypatch):
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception) as failed:
        program_missing("chromium is not installed", "chromium")
    message = str(failed.value)
    assert "chromium is not installed" in message and "apt-get install -y chromium" in message


def test_a_missing_program_skips_outside_ci_with_its_reason(monkeypatch):
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception) as skipped:
        program_missing("PostgreSQL server binaries (initdb, pg_ctl) are not installed", "postgresql")
    message = str(skipped.value)
    assert "initdb" in message and "apt-get install -y postgresql" in message


def test_the_ci_entry_point_runs_under_ci_and_installs_the_programs():
    script = (ROOT / ".ci" / "run").read_text()
    assert re.search(r"^export CI=true$", script, re.MULTILINE)
    packages = set(re.search(r'SYSTEM_PACKAGES="([^"]*)"', script)[1].split())
    assert {"libosmesa6", "libegl1", "libgl1", "postgresql", "chromium"} <= packages
    assert "apt-get install" in script and "make test" in script
