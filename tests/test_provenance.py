"""versions.json names the code (git commit and dirty flag, or the package version) and the GPU that made a run,
without depending on the working folder and without slowing down or breaking a run where git or a GPU is missing."""

import json
import shutil
import subprocess
import sys
import types

import pytest

from canter.training import provenance
from canter.training.run_folder import versions
from under_ci import program_missing


def _git(root, *args):
    subprocess.run(["git", "-C", str(root), *args], check=True, capture_output=True)


@pytest.fixture
def checkout(tmp_path):
    """A git checkout with canter's src layout and one commit."""
    if shutil.which("git") is None:
        program_missing("git is not installed", "git")
    root = tmp_path / "checkout"
    (root / "src" / "canter").mkdir(parents=True)
    (root / "src" / "canter" / "__init__.py").write_text("")
    _git(root, "init", "-q")
    _git(root, "add", "-A")
    _git(root, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "first")
    sha = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    return root, sha


@pytest.fixture
def no_gpu(monkeypatch):
    monkeypatch.setattr(provenance, "gpu_name", lambda: None)


def test_the_checkout_is_found_from_the_package_path_only_in_the_src_layout(tmp_path):
    root = tmp_path / "repo"
    (root / "src" / "canter").mkdir(parents=True)
    assert provenance.checkout_root(root / "src" / "canter") is None  # no .git
    (root / ".git").mkdir()
    assert provenance.checkout_root(root / "src" / "canter") == root
    # An installed canter inside some other project's repository is not that repository's code.
    installed = root / ".venv" / "lib" / "python3.11" / "site-packages" / "canter"
    installed.mkdir(parents=True)
    assert provenance.checkout_root(installed) is None


def test_a_clean_checkout_then_an_edited_one_then_one_with_a_new_file(checkout):
    root, sha = checkout
    assert provenance.commit_of(root) == provenance.Commit(sha, dirty=False)
    (root / "src" / "canter" / "__init__.py").write_text("x = 1\n")
    assert provenance.commit_of(root) == provenance.Commit(sha, dirty=True)
    _git(root, "checkout", "-q", "--", ".")
    (root / "src" / "canter" / "extra.py").write_text("")
    assert provenance.commit_of(root) == provenance.Commit(sha, dirty=True)
    (root / "src" / "canter" / "extra.py").unlink()
    (root / "pyproject.toml").write_text("[project]\nname = 'other'\n")
    assert provenance.commit_of(root) == provenance.Commit(sha, dirty=True)


def test_results_written_into_the_checkout_leave_it_clean(checkout):
    """A benchmark appending to its results.md, or new logs beside it, changes no code."""
    root, sha = checkout
    (root / "README.md").write_text("new table\n")
    (root / "benchmarks" / "logs").mkdir(parents=True)
    (root / "benchmarks" / "logs" / "rows.json").write_text("{}")
    assert provenance.commit_of(root) == provenance.Commit(sha, dirty=False)


def test_versions_names_the_commit_of_the_packages_checkout_not_of_the_working_folder(
    checkout, tmp_path, monkeypatch, no_gpu
):
    root, sha = checkout
    other = tmp_path / "elsewhere"
    other.mkdir()
    _git(other, "init", "-q")
    monkeypatch.chdir(other)
    monkeypatch.setenv("GIT_DIR", str(other / ".git"))  # git's own variables must not redirect it either
    monkeypatch.setattr(provenance, "_PACKAGE_DIR", root / "src" / "canter")
    found = versions()
    assert found["canter_commit"] == sha and found["canter_dirty"] is False
    assert json.loads(json.dumps(found)) == found


def test_without_a_checkout_or_without_git_only_the_package_version_is_recorded(
    checkout, tmp_path, monkeypatch, no_gpu
):
    root, _ = checkout
    installed = tmp_path / "site-packages" / "canter"
    installed.mkdir(parents=True)
    monkeypatch.setattr(provenance, "_PACKAGE_DIR", installed)
    found = versions()
    assert found["canter_commit"] is None and found["canter_dirty"] is None and found["canter"]

    monkeypatch.setattr(provenance, "_PACKAGE_DIR", root / "src" / "canter")
    monkeypatch.setenv("PATH", str(tmp_path / "no-programs-here"))
    assert provenance.commit_of(root) is None
    assert versions()["canter_commit"] is None


def test_a_failing_git_gives_no_commit(tmp_path, monkeypatch):
    root = tmp_path / "broken"
    (root / ".git").mkdir(parents=True)  # not a repository git can read
    assert provenance.commit_of(root) is None


@pytest.mark.parametrize(
    "names, line",
    [
        ([], None),
        (["", "  "], None),
        (["NVIDIA H100 80GB HBM3"], "NVIDIA H100 80GB HBM3"),
        (["NVIDIA H100 80GB HBM3", "NVIDIA H100 80GB HBM3"], "2 x NVIDIA H100 80GB HBM3"),
        (["NVIDIA A100", "NVIDIA H100 80GB HBM3\n", "NVIDIA A100"], "2 x NVIDIA A100, NVIDIA H100 80GB HBM3"),
    ],
)
def test_describe_gpus(names, line):
    assert provenance.describe_gpus(names) == line


def _fake_nvidia_smi(folder, listing):
    folder.mkdir(exist_ok=True)
    program = folder / "nvidia-smi"
    program.write_text(f"#!/bin/sh\nprintf '{listing}'\n")
    program.chmod(0o755)


@pytest.fixture
def fresh_gpu_lookup(monkeypatch):
    provenance._nvidia_smi_gpus.cache_clear()
    monkeypatch.delitem(sys.modules, "jax", raising=False)
    yield
    provenance._nvidia_smi_gpus.cache_clear()


def test_without_jax_loaded_the_gpu_comes_from_nvidia_smi(tmp_path, monkeypatch, fresh_gpu_lookup):
    _fake_nvidia_smi(tmp_path / "bin", "NVIDIA H100 80GB HBM3\\nNVIDIA H100 80GB HBM3\\n")
    monkeypatch.setenv("PATH", str(tmp_path / "bin"))
    assert provenance.gpu_name() == "2 x NVIDIA H100 80GB HBM3"
    assert "jax" not in sys.modules  # never imported to answer


def test_no_nvidia_smi_and_no_jax_means_no_gpu(tmp_path, monkeypatch, fresh_gpu_lookup):
    monkeypatch.setenv("PATH", str(tmp_path / "nothing"))
    assert provenance.gpu_name() is None


def test_a_failing_nvidia_smi_means_no_gpu(tmp_path, monkeypatch, fresh_gpu_lookup):
    (tmp_path / "bin").mkdir()
    (tmp_path / "bin" / "nvidia-smi").write_text("#!/bin/sh\necho 'no devices were found' >&2\nexit 9\n")
    (tmp_path / "bin" / "nvidia-smi").chmod(0o755)
    monkeypatch.setenv("PATH", str(tmp_path / "bin"))
    assert provenance.gpu_name() is None


def _fake_jax(devices):
    def list_devices():
        if isinstance(devices, Exception):
            raise devices
        return devices

    return types.SimpleNamespace(devices=list_devices)


def test_with_jax_loaded_the_gpu_is_the_one_jax_computes_on(tmp_path, monkeypatch, fresh_gpu_lookup):
    _fake_nvidia_smi(tmp_path / "bin", "Some Other GPU\\n")
    monkeypatch.setenv("PATH", str(tmp_path / "bin"))
    gpu = types.SimpleNamespace(platform="gpu", device_kind="NVIDIA H200")
    cpu = types.SimpleNamespace(platform="cpu", device_kind="cpu")
    monkeypatch.setitem(sys.modules, "jax", _fake_jax([gpu, cpu]))
    assert provenance.gpu_name() == "NVIDIA H200"
    # JAX on the CPU, or a JAX that cannot list its devices: the machine's GPU, as nvidia-smi names it.
    monkeypatch.setitem(sys.modules, "jax", _fake_jax([cpu]))
    assert provenance.gpu_name() == "Some Other GPU"
    monkeypatch.setitem(sys.modules, "jax", _fake_jax(RuntimeError("no backend")))
    assert provenance.gpu_name() == "Some Other GPU"


def test_this_machines_versions_record_the_gpu_field():
    found = versions()
    assert "gpu" in found and (found["gpu"] is None or isinstance(found["gpu"], str))
