from pathlib import Path

import pytest

from canter.docs import render

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_config_table_is_generated_from_the_dataclasses():
    text = README.read_text()
    assert render(text) == text, "README.md is stale: run `make docs`"


def test_readme_names_the_two_commands():
    text = README.read_text()
    assert "make demo" in text and "make test" in text


@pytest.mark.slow
def test_offpolicy_tables_match_the_committed_runs():
    import subprocess
    import sys

    script = README.parent / "benchmarks" / "offpolicy_tables.py"
    done = subprocess.run([sys.executable, str(script), "--check"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
