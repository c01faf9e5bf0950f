"""Too many envs for the machine's memory: refused in one line before they are created, from the measured memory of
a few real envs."""

import subprocess
import sys

import pytest

from canter.cli.main import main
from canter.errors import CanterError
from canter.training import host_memory


def test_the_memory_of_a_real_env_is_measured():
    # In a fresh process: in this one, envs that earlier tests made and closed left memory that new ones reuse.
    code = (
        "from canter.envs.registry import make_vec_env; from canter.training import host_memory; "
        "print(host_memory.bytes_per_env(lambda n: make_vec_env('Hopper-v5', 'envpool', n, list(range(n)))))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    per_env = float(done.stdout.strip().splitlines()[-1])
    assert 10_000 < per_env < 50 * 2**20  # MuJoCo's Hopper: about a megabyte


def test_the_check_measures_in_a_fresh_process_which_no_freed_envs_can_fool(monkeypatch):
    # A process that made and closed envs reuses their freed memory for new ones, so measured in it, their resident
    # size hardly grows: this is how 200,000 Hoppers once passed the check inside the test suite, and the
    # out-of-memory killer ended it. Here that process's measure is zero outright; the check's is not.
    monkeypatch.setattr(host_memory, "bytes_per_env", lambda make: 0.0)
    if host_memory.available_bytes() is None or host_memory.available_bytes() > 2**40:
        pytest.skip("the machine reports no available memory, or more than 200000 Hoppers need")
    with pytest.raises(CanterError, match=r"env\.num_envs=200000 needs about"):
        host_memory.check_envs_fit("Hopper-v5", "envpool", {}, 200_000)
    apart = host_memory.bytes_per_env_apart("Hopper-v5", "envpool", {})
    assert apart is not None and 200_000 < apart < 50 * 2**20
    assert host_memory.bytes_per_env_apart("NoSuchEnv-v0", "envpool", {}) is None


def test_the_refusal_names_the_setting_and_a_count_that_fits():
    assert host_memory.refusal(1000, 2**20, 2 * 2**30) is None
    error = host_memory.refusal(200_000, 2**20, 10 * 2**30)
    assert str(error) == (
        "env.num_envs=200000 needs about 195.3 GiB of memory for its envs (1.0 MiB each, measured), but 10.0 GiB "
        "are available; lower it, e.g. --set env.num_envs=9216"
    )


def test_two_hundred_thousand_hoppers_are_refused_before_they_exist(tmp_path, capsys):
    if host_memory.available_bytes() is None or host_memory.available_bytes() > 2**40:
        pytest.skip("the machine reports no available memory, or more than 200000 Hoppers need")
    code = main(["train", "Hopper-v5", "--set", "env.num_envs=200000", "--out-dir", str(tmp_path), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("canter: error: env.num_envs=200000 needs about") and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    ("size", "text"),
    [
        (0, "0.0 KiB"),
        (52_000, "50.8 KiB"),
        (2**20, "1.0 MiB"),
        (3.4e6, "3.2 MiB"),
        (2**30, "1.0 GiB"),
        (11.4e9, "10.6 GiB"),
    ],
)
def test_sizes_read_in_the_largest_binary_unit_they_fill(size, text):
    assert host_memory.size_text(size) == text
