import atexit
import contextlib
import os
import shutil
import tempfile
from pathlib import Path

import pytest

# One persistent XLA compilation cache for the session, inherited by the child processes of bench and tune: many
# tests compile the same tiny programs again (a run and its resume, the seeds of a grid), and a cache hit takes a
# few seconds instead of tens (an MJX iteration: 42 s, then 5 s). Set before JAX is imported.
_CACHE = tempfile.mkdtemp(prefix="canter-test-xla-cache-")
atexit.register(shutil.rmtree, _CACHE, ignore_errors=True)
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", _CACHE)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")

from canter.core.runtime import setup_jax  # noqa: E402

setup_jax()


@pytest.fixture(autouse=True)
def _in_tmp_dir(tmp_path, monkeypatch):
    # MuJoCo writes MUJOCO_LOG.TXT into the working folder, and runs default to ./runs.
    monkeypatch.chdir(tmp_path)
    yield


@pytest.fixture(autouse=True)
def _host_precision_after_each_test():
    # A test that trains on mjx or brax turns JAX's 64-bit types off for the process; the next test in the same
    # worker, whichever it is, starts from the host backends' precision again.
    yield
    from canter.envs.functional import x64_enabled

    if not x64_enabled():
        setup_jax()


TINY = ["net.hidden=16,16", "run.tensorboard=false"]


def error_line(capsys, argv) -> str:
    """The one stderr line of a refused command, without its `canter: error: ` prefix."""
    from canter.cli.main import main

    code = main(argv)
    out, err = capsys.readouterr()
    assert code == 2, (argv, out, err)
    assert err.count("\n") == 1 and err.startswith("canter: error: ") and "Traceback" not in err, err
    return err.removeprefix("canter: error: ").rstrip("\n")


# A run folder of canter's format 1 (tests/fixtures/make_runs.py wrote it): InvertedPendulum-v4, ppo, no best.npz.
ARCHIVED_RUN = Path(__file__).parent / "fixtures" / "runs-v1" / "ppo"


@pytest.fixture
def archived_run(tmp_path: Path) -> Path:
    """A copy of ARCHIVED_RUN, free to damage."""
    folder = tmp_path / "run"
    shutil.copytree(ARCHIVED_RUN, folder)
    return folder


def _train_inside(folder, config):
    """Train with `folder` as the working folder, where MuJoCo writes its log, for session-scoped runs that
    outlive the per-test working folder."""
    from canter.training.loop import train

    cwd = os.getcwd()
    os.chdir(folder)
    try:
        return train(config)
    finally:
        os.chdir(cwd)


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """A short Pendulum run shared by the tests that only need some run folder."""
    from canter.config.build import build_config

    out = tmp_path_factory.mktemp("shared_runs")
    config = build_config(
        "Pendulum-v1",
        preset="fast",
        total_steps=8192,
        sets=TINY
        + [
            f"run.out_dir={out}",
            "run.checkpoint_every=4096",
            "env.num_envs=4",
            "ppo.n_steps=256",
            "ppo.minibatch_size=256",
            "ppo.epochs=2",
        ],
    )
    return _train_inside(out, config)


def _choose_gl() -> None:
    # MuJoCo reads MUJOCO_GL when it is first imported, so pick EGL or OSMesa before any test imports it.
    from canter.errors import CanterError
    from canter.use.renderer import configure_gl

    with contextlib.suppress(CanterError):  # the video tests then fail with the message naming the package to install
        configure_gl()


_choose_gl()


@pytest.fixture(scope="session")
def tiny_hopper_run(tmp_path_factory):
    """A few hundred steps of Hopper-v5 on EnvPool: a MuJoCo run for the eval, vary and video tests."""
    from canter.config.build import build_config
    from canter.training.loop import train

    out = tmp_path_factory.mktemp("hopper_runs")
    config = build_config(
        "Hopper-v5",
        preset="fast",
        total_steps=256,
        seed=1,
        sets=TINY
        + [
            f"run.out_dir={out}",
            "env.backend=envpool",
            "env.num_envs=2",
            "ppo.n_steps=64",
            "ppo.minibatch_size=128",
            "ppo.epochs=1",
        ],
    )
    return train(config).run_dir


@pytest.fixture(scope="session")
def tiny_run_seed1(tiny_run, tmp_path_factory):
    """tiny_run's config with run.seed=1: two runs that differ only in their seed (plot grouping, reports)."""
    from canter.config.overrides import apply_overrides
    from canter.training.run_folder import read_config

    out = tmp_path_factory.mktemp("shared_runs_seed1")
    config = apply_overrides(read_config(tiny_run.run_dir), {"run.seed": 1, "run.out_dir": str(out)}, "test")
    return _train_inside(out, config)


def pytest_addoption(parser):
    parser.addoption("--run-heavy", action="store_true", help="also run the tests marked heavy")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--run-heavy"):
        return
    skip = pytest.mark.skip(reason="heavy: run with --run-heavy")
    for item in items:
        if "heavy" in item.keywords:
            item.add_marker(skip)
