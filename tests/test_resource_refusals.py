"""Settings whose memory or open files the machine cannot hold are refused in one line, before anything is
allocated and with no run folder left behind. The machine's memory is faked small here: nothing large is ever
allocated, so a refusal that regressed cannot take the machine down."""

from __future__ import annotations

import math
import re
import shutil
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from canter.algos import get_algorithm
from canter.algos.state_size import state_size
from canter.cli.main import main
from canter.config.build import build_config
from canter.errors import CanterError, DoesNotFitError
from canter.training import device_memory, host_memory, loop, run_folder, run_lock
from conftest import ARCHIVED_RUN

GIB = 2**30
# InvertedPendulum's sizes, for estimates that need no env.
PENDULUM = SimpleNamespace(obs_dim=4, act_dim=1, action_low=np.array([-3.0]), action_high=np.array([3.0]))


@pytest.fixture
def memory(monkeypatch):
    """Fake the machine's available memory (the CPU reports no free device memory)."""

    def fake(available: int) -> None:
        monkeypatch.setattr(host_memory, "available_bytes", lambda: available)
        monkeypatch.setattr(device_memory, "free_bytes", lambda: None)

    return fake


def _one_line_error(capsys) -> str:
    """The error a command wrote, which must be one line (notes aside)."""
    err = capsys.readouterr().err
    lines = [line for line in err.strip().splitlines() if not line.startswith("canter: note: ")]
    assert len(lines) == 1 and lines[0].startswith("canter: error: ") and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize(
    ("algo", "sets"),
    [("td3", ["td3.buffer_size=1000"]), ("ppo", ["net.hidden=64,64"]), ("sac", ["sac.hidden=32"]), ("trpo", [])],
)
def test_the_estimate_is_the_size_of_the_state_that_init_builds(algo, sets):
    config = build_config("InvertedPendulum-v5", algo=algo, sets=sets)
    algorithm = get_algorithm(algo)
    built = algorithm.init_state(config, PENDULUM, 0)
    assert state_size(algorithm, config, PENDULUM).total == sum(leaf.nbytes for leaf in jax.tree.leaves(built))


def test_a_replay_buffer_of_a_billion_is_measured_without_allocating_it():
    config = build_config("InvertedPendulum-v5", algo="td3", sets=["td3.buffer_size=1000000000"])
    size = state_size(get_algorithm("td3"), config, PENDULUM)
    # float32 obs, action, reward, next obs and done per row, and two int32 counters
    assert size.key == "td3.buffer_size" and size.share == 4 * (2 * 4 + 1 + 2) * 10**9 + 8


def test_networks_too_large_for_the_memory_are_refused_naming_the_key(memory):
    memory(16 * GIB)
    config = build_config("InvertedPendulum-v5", sets=["net.hidden=1000000000"])
    with pytest.raises(CanterError) as error:
        host_memory.check_state_fits(get_algorithm("ppo"), config, PENDULUM, 1, None)
    assert str(error.value) == (
        "the train state needs about 134.1 GiB of memory, 134.1 GiB of it for net.hidden=1000000000, but 16.0 GiB "
        "are available; lower net.hidden"
    )


def test_a_group_whose_states_do_not_fit_is_told_how_many_seeds_do(memory):
    memory(16 * GIB)
    config = build_config("InvertedPendulum-v5", algo="td3", sets=["td3.buffer_size=100000000"])  # 4.1 GiB each
    with pytest.raises(CanterError, match=r"the train states of 5 seeds need about 41\.0 GiB .*; train one seed at a"):
        host_memory.check_state_fits(get_algorithm("td3"), config, PENDULUM, 5, None)
    host_memory.check_state_fits(get_algorithm("td3"), config, PENDULUM, 1, None)
    assert [host_memory.seeds_that_fit(10, room) for room in (9, 10, 39, 40, 60)] == [0, 1, 1, 2, 3]


def test_on_a_device_that_reports_its_memory_the_state_is_checked_against_its_free_memory(memory):
    memory(1024 * GIB)
    config = build_config("InvertedPendulum-v5", algo="td3", sets=["td3.buffer_size=100000000"])
    with pytest.raises(CanterError, match=r"about 4\.1 GiB of the device's memory, .* but 2\.0 GiB are available"):
        host_memory.check_state_fits(get_algorithm("td3"), config, PENDULUM, 1, 2 * GIB)


def test_a_replay_buffer_too_large_is_refused_before_it_is_allocated_and_leaves_no_folder(memory, tmp_path, capsys):
    memory(32 * 2**20)  # the default buffer of a million rows takes 42 MiB
    out = tmp_path / "runs"
    code = main(
        ["train", "InvertedPendulum-v5", "--algo", "td3", "--total-steps", "2000", "--out-dir", str(out), "--quiet"]
        + ["--set", "td3.learning_starts=100"]
    )
    assert code == 2
    err = _one_line_error(capsys)
    assert err.endswith(
        "for td3.buffer_size=1000000, but 32.0 MiB are available; lower td3.buffer_size, e.g. --set "
        "td3.buffer_size=500000"
    )
    config = build_config("InvertedPendulum-v5", algo="td3", sets=["td3.buffer_size=500000"])
    assert state_size(get_algorithm("td3"), config, PENDULUM).total <= host_memory.HEADROOM * 32 * 2**20
    assert not out.exists()


def test_the_env_count_is_checked_before_the_envs_seeds_are_listed_or_a_folder_is_made(memory, monkeypatch, tmp_path):
    memory(GIB)
    monkeypatch.setattr(host_memory, "bytes_per_env_apart", lambda *args: 2**20)

    def listed(*args):
        raise AssertionError("the env seeds were listed before the memory check")

    monkeypatch.setattr(loop.SeedStart, "env_seeds", listed)
    config = build_config(
        "InvertedPendulum-v5", total_steps=20_000, sets=["env.num_envs=5000", f"run.out_dir={tmp_path / 'runs'}"]
    )
    with pytest.raises(CanterError, match=r"^env\.num_envs=5000 needs about 4\.9 GiB"):
        loop.train(config)
    with pytest.raises(CanterError, match=r"^2 seeds of env\.num_envs=5000 \(10000 envs\) need about 9\.8 GiB"):
        loop.train_seeds(config, [0, 1])
    assert not (tmp_path / "runs").exists()


def test_an_env_count_no_machine_holds_is_refused_also_where_the_envs_cannot_be_measured(memory, monkeypatch):
    memory(16 * GIB)
    monkeypatch.setattr(host_memory, "bytes_per_env_apart", lambda *args: None)
    with pytest.raises(CanterError, match=r"at least 48 bytes each\), but 16\.0 GiB are available; lower it by far"):
        host_memory.check_envs_fit("InvertedPendulum-v5", "envpool", {}, 2_000_000_000)


def test_jax_envs_whose_state_cannot_fit_are_refused_before_they_are_reset(memory, monkeypatch, tmp_path, capsys):
    """Resetting 10^8 MJX envs on the CPU ran for minutes before anything could refuse it; their state's shapes say
    at once that it cannot fit."""
    from canter.envs.functional import FunctionalVecEnv

    memory(16 * GIB)
    monkeypatch.setattr(device_memory, "free_bytes", lambda: None)
    monkeypatch.setattr(FunctionalVecEnv, "_start", lambda self: pytest.fail("the envs were reset"))
    out = tmp_path / "runs"
    argv = ["train", "InvertedPendulum-v5", "--backend", "mjx", "--out-dir", str(out), "--quiet"]
    assert main([*argv, "--set", "env.num_envs=100000000"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]  # after the line that says there is no GPU
    assert re.fullmatch(
        r"canter: error: env\.num_envs=100000000 needs about [\d.]+ GiB of memory for its envs \([\d.]+ KiB each, "
        r"from its state's shapes\), but 16\.0 GiB are available; lower it, e\.g\. --set env\.num_envs=\d+",
        err,
    ), err
    assert not out.exists()
    # Envs that pass the check but that the device cannot reset after all are refused in one line too.
    monkeypatch.undo()
    memory(16 * GIB)

    def out_of_memory(self):
        raise RuntimeError("RESOURCE_EXHAUSTED: Out of memory while trying to allocate 123.45GiB.")

    monkeypatch.setattr(FunctionalVecEnv, "_start", out_of_memory)
    assert main([*argv, "--set", "env.num_envs=64"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        "canter: error: env.num_envs=64 does not fit in the device's memory; lower it, e.g. --set env.num_envs=32"
    )
    assert not out.exists() or not any(out.iterdir()), sorted(out.rglob("*"))
    # On a GPU the device's free memory bounds them, and one seed's envs that fit make the fix fewer seeds.
    monkeypatch.setattr(device_memory, "free_bytes", lambda: 64 * GIB)
    per_env = 4 * 1024
    with pytest.raises(CanterError, match=r"\(4\.0 KiB each, from its state's shapes\), but 64\.0 GiB are available"):
        host_memory.check_jax_envs_fit(lambda: per_env, 2**22, 8, device_memory.free_bytes())


def test_the_env_refusal_of_a_group_counts_envs_per_seed_and_suggests_fewer_seeds():
    error = host_memory.refusal(16, 2**20, 10 * GIB, group=5000)
    assert str(error) == (
        "5000 seeds of env.num_envs=16 (80000 envs) need about 78.1 GiB of memory for their envs (1.0 MiB each, "
        "measured), but 10.0 GiB are available; train at most 576 seeds at a time"
    )
    error = host_memory.refusal(20_000, 2**20, 10 * GIB, group=2)
    assert str(error).endswith("lower it, e.g. --set env.num_envs=9216, with one seed at a time")


def test_a_resumed_run_is_told_the_fix_that_a_resume_can_take():
    """--resume refuses --set: fewer seeds at a time stays a fix, settings to lower go to a new run."""
    seeds = host_memory.refusal(16, 2**20, 10 * GIB, group=5000)
    assert str(seeds.for_a_resume("r/config.toml")).endswith("; resume at most 576 seeds at a time")
    settings = host_memory.refusal(20_000, 2**20, 10 * GIB)
    assert str(settings.for_a_resume("r/config.toml")).endswith(
        "are available; a resume keeps the run's settings: resume it where more memory is free, or lower it, e.g. "
        "--set env.num_envs=9216 in a new run from its config: canter train --config r/config.toml "
        "(canter.train(canter.build_config(None, config_file='r/config.toml')) from Python)"
    )
    bare = DoesNotFitError("the train state needs about 9.0 GiB, but 1.0 GiB are available")
    assert str(bare.for_a_resume("r/config.toml")).endswith(
        "; a resume keeps the run's settings: resume it where more memory is free"
    )


def test_a_program_too_large_for_the_host_is_refused_after_the_compile(memory):
    x = jnp.ones((256, 256), jnp.float32)
    compiled = jax.jit(lambda a: jnp.tanh(a @ a) @ a).lower(x).compile()
    more = device_memory.required_bytes(compiled) - 256 * 256 * 4  # the argument is in memory already
    memory(math.ceil(more / host_memory.HEADROOM))
    device_memory.check_fits(compiled, 1)
    memory(more)
    with pytest.raises(
        CanterError, match=r"^the training program needs about [\d.]+ [KM]iB of memory beyond its train"
    ):
        device_memory.check_fits(compiled, 1)


@pytest.mark.slow
def test_a_program_refused_after_its_compile_names_what_sizes_a_call_and_leaves_no_run_folder(
    monkeypatch, tmp_path, capsys
):
    """The compiled program is measured only once the run folder is made: its refusal removes the folder again,
    which nothing could have resumed (no checkpoint) or plotted (no row)."""
    monkeypatch.setattr(device_memory, "free_bytes", lambda: None)
    monkeypatch.setattr(device_memory, "required_bytes", lambda compiled: 2**50)
    out = tmp_path / "runs"
    argv = ["train", "Pendulum-v1", "--total-steps", "2048", "--out-dir", str(out), "--quiet"]
    assert main([*argv, "--set", "net.hidden=16,16", "--set", "ppo.n_steps=64"]) == 2
    err = _one_line_error(capsys)
    assert "canter: error: the training program needs about " in err
    assert err.endswith(
        "lower what sizes one call (env.num_envs=16, ppo.n_steps=64), the batch sizes, or the hidden layer sizes"
    ), err
    assert not out.exists()
    # A resumed run keeps its folder whole: its checkpoints hold what it trained.
    monkeypatch.undo()
    shutil.copytree(ARCHIVED_RUN, tmp_path / "resumed")
    monkeypatch.setattr(device_memory, "free_bytes", lambda: None)
    monkeypatch.setattr(device_memory, "required_bytes", lambda compiled: 2**50)
    before = sorted(p.relative_to(tmp_path) for p in (tmp_path / "resumed").rglob("*"))
    budget = run_folder.read_config(tmp_path / "resumed").run.total_steps
    assert main(["train", "--resume", str(tmp_path / "resumed"), "--total-steps", "1e6", "--quiet"]) == 2
    # --resume refuses --set, so the settings to lower go to a new run from the run's config.
    err = _one_line_error(capsys)
    assert (
        "are available; a resume keeps the run's settings: resume it where more memory is free, or lower what sizes "
        "one call (env.num_envs=4, ppo.n_steps=64), the batch sizes, or the hidden layer sizes in a new run from its "
        f"config: canter train --config {tmp_path / 'resumed' / 'config.toml'} (canter.train(canter.build_config("
        f"None, config_file={str(tmp_path / 'resumed' / 'config.toml')!r})) from Python)"
    ) in err, err
    assert set(before) <= {p.relative_to(tmp_path) for p in (tmp_path / "resumed").rglob("*")}
    # The advised new run from its config, or a later resume, trains the run's own budget, not the refused one.
    assert run_folder.read_config(tmp_path / "resumed").run.total_steps == budget != 10**6


def test_a_refusal_while_the_program_is_built_leaves_no_run_folder(monkeypatch, tmp_path, capsys):
    """Any one-line refusal between a new run's folder and its first iteration removes the folder again."""

    def refuse(*args, **kwargs):
        raise CanterError("refused while the program is built")

    monkeypatch.setattr(loop, "GroupProgram", refuse)
    out = tmp_path / "runs"
    argv = ["train", "Pendulum-v1", "--total-steps", "2048", "--out-dir", str(out), "--quiet"]
    assert main([*argv, "--seeds", "0,1", "--set", "net.hidden=16,16", "--set", "ppo.n_steps=64"]) == 2
    assert _one_line_error(capsys) == "canter: error: refused while the program is built"
    assert not out.exists() or not any(out.iterdir()), sorted(out.rglob("*"))


def test_too_many_seeds_for_the_open_files_are_refused_before_a_folder_is_made(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(run_lock.resource, "getrlimit", lambda which: (256, 4096))

    def made(*args):
        raise AssertionError("the envs were made before the open files were checked")

    monkeypatch.setattr(loop, "_make_env", made)
    seeds = ",".join(map(str, range(200)))
    out = tmp_path / "runs"
    code = main(["train", "InvertedPendulum-v5", "--seeds", seeds, "--out-dir", str(out), "--quiet"])
    assert code == 2
    err = _one_line_error(capsys)
    assert "200 runs at once keep about 600 files open (3 each" in err
    assert "this process may open only 256 (ulimit -n); train at most " in err and "`ulimit -n 1024`" in err
    assert not out.exists()


def test_the_open_files_refusal_says_how_many_seeds_fit_and_what_limit_holds_them():
    assert run_lock.open_files_refusal(10, 3, 20, 1024, 1024) is None
    error = str(run_lock.open_files_refusal(2000, 3, 20, 1024, 1024))
    assert "train at most 324 seeds at a time, or have the hard limit (ulimit -Hn, now 1024) raised to 6052" in error
    error = str(run_lock.open_files_refusal(2000, 3, 20, 1024, run_lock.resource.RLIM_INFINITY))
    assert error.endswith("train at most 324 seeds at a time, or raise the limit first, e.g. `ulimit -n 8192`")
    assert run_lock.open_files_refusal(10**6, 3, 20, run_lock.resource.RLIM_INFINITY, 1) is None


@pytest.fixture
def two_experiments(tmp_path) -> tuple[Path, Path]:
    """A ppo run and a td3 run of the same env and seed."""
    ppo, td3 = tmp_path / "ppo", tmp_path / "td3"
    shutil.copytree(ARCHIVED_RUN, ppo)
    shutil.copytree(ARCHIVED_RUN.parent / "td3", td3)
    return ppo, td3


def test_runs_of_different_experiments_resumed_together_are_told_so_not_that_their_seeds_repeat(
    two_experiments, capsys
):
    ppo, td3 = two_experiments
    assert main(["train", "--resume", str(ppo), str(td3), "--total-steps", "1e6", "--quiet"]) == 2
    err = _one_line_error(capsys)
    assert f"{td3} differs from {ppo} in more than run.seed (run.algo, " in err
    assert "they are runs of different experiments, which resume one at a time" in err
    assert main(["train", "--resume", str(ppo), f"{ppo}/.", "--total-steps", "1e6", "--quiet"]) == 2
    assert f"repeated seeds: {ppo} is given twice; give each run folder once" in _one_line_error(capsys)


def test_a_programs_memory_is_named_by_the_rollout_on_policy_and_by_the_batch_off_policy():
    from canter.config.algorithms import algorithm_spec

    assert algorithm_spec("ppo").memory_keys() == ("env.num_envs", "ppo.n_steps")
    for name in ("td3", "ddpg", "sac"):
        assert algorithm_spec(name).memory_keys() == ("env.num_envs", f"{name}.batch_size")


def test_only_a_new_run_that_logged_nothing_is_discarded(tmp_path):
    from canter.training import run_folder

    def folder(name, metrics="global_step,iteration\n", extra=None):
        run = tmp_path / name
        run.mkdir()
        for file in ("config.toml", "versions.json", "trackers.json"):
            (run / file).write_text("x")
        (run / "metrics.csv").write_text(metrics)
        (run / "tb").mkdir()
        if extra:
            (run / extra).parent.mkdir(parents=True, exist_ok=True)
            (run / extra).write_text("x")
        run_folder.discard_unstarted(run)
        return sorted(p.name for p in run.iterdir())

    assert folder("header_only") == []
    kept = ["config.toml", "metrics.csv", "tb", "trackers.json", "versions.json"]
    assert folder("a_row", "global_step,iteration\n128,1\n") == kept
    assert folder("half_a_row", "global_step,iteration\n12") == kept  # not this session's: it logged nothing
    assert folder("archived", extra="metrics.csv.gz") == sorted([*kept, "metrics.csv.gz"])
    assert folder("checkpointed", extra="checkpoints/ckpt_000000000000.npz") == sorted([*kept, "checkpoints"])
    assert folder("users_own", extra="notes.txt") == ["notes.txt"]
