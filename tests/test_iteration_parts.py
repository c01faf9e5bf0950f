"""An on-policy iteration on a host-stepped env runs as two programs: the rollout, which holds EnvPool's step (whose
program embeds the pool's address and is compiled again by every process), and the update, which does not, and so
is found again in the compile cache by a resume, a rerun or another seed's process."""

import os
import subprocess
import sys
from dataclasses import replace
from types import SimpleNamespace

import jax
import numpy as np
import pytest

from canter.algos.registry import get_algorithm
from canter.config.build import build_config
from canter.envs.episodes import init_env_carry
from canter.envs.registry import make_vec_env
from canter.training.group_program import GroupProgram, TwoPrograms

pytestmark = pytest.mark.slow

SETS = ["net.hidden=8,8", "env.num_envs=4", "ppo.n_steps=64", "run.tensorboard=false"]


def _program(algo: str, seeds: int):
    sets = SETS + (["ppo.minibatch_size=128", "ppo.epochs=2"] if algo == "ppo" else ["trpo.critic_epochs=2"])
    config = build_config("Pendulum-v1", algo=algo, sets=sets)
    algorithm = get_algorithm(algo)
    env = make_vec_env("Pendulum-v1", "envpool", 4 * seeds, list(range(4 * seeds)))
    states = [algorithm.init_state(config, env.spec, seed) for seed in range(seeds)]
    return config, algorithm, env, states


def _three_iterations(program: GroupProgram, seeds: int) -> list:
    runs = [SimpleNamespace(global_step=0) for _ in range(seeds)]
    program.compile(runs)
    chunks = []
    for _ in range(3):
        chunk = program.call(runs)
        program.advance(chunk)
        chunks.append(chunk)
    return chunks


def _run(algo: str, seeds: int, parted: bool) -> list:
    from canter.training import seedgroup

    config, algorithm, env, states = _program(algo, seeds)
    if not parted:
        algorithm = replace(algorithm, make_parts=None)
    handles, first = env.initial_state(), env.reset()
    if seeds == 1:
        carry = init_env_carry(handles, first, env.spec.info_keys)
    else:
        carry = seedgroup.stack(
            [init_env_carry(handles, first[4 * i : 4 * i + 4], env.spec.info_keys) for i in range(seeds)]
        )
    program = GroupProgram(config, algorithm, env.spec, env, states, carry)
    assert isinstance(program.iteration, TwoPrograms) == parted
    try:
        return _three_iterations(program, seeds)
    finally:
        env.close()


@pytest.mark.parametrize("algo,seeds", [("ppo", 1), ("trpo", 1), ("ppo", 2)])
def test_two_programs_compute_what_the_whole_iteration_computes(algo, seeds):
    """Three iterations from the same state and env seeds, parted and whole: every metric and parameter agree."""
    whole, parted = _run(algo, seeds, parted=False), _run(algo, seeds, parted=True)
    for a, b in zip(whole, parted):
        for x, y in zip(jax.tree.leaves((a.state, a.metrics)), jax.tree.leaves((b.state, b.metrics))):
            np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-6, atol=1e-7)


def test_an_off_policy_iteration_stays_one_program():
    """td3 updates between env steps, so its iteration has no parts."""
    assert get_algorithm("td3").make_parts is None and get_algorithm("sac").make_parts is None


CACHE_HITS = """
import sys
from jax import monitoring

hits = []
monitoring.register_event_listener(lambda event, **_: hits.append(event) if event.endswith("cache_hits") else None)
from canter.cli.main import main

code = main(sys.argv[1:])
print("hits", len(hits), code)
"""


def test_a_second_process_finds_the_update_in_the_compile_cache(tmp_path):
    """A rerun of the same config: its rollout is compiled again (another pool, another address), its update and
    initial state are read from the cache."""
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "xla"))
    env["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
    argv = ["train", "Pendulum-v1", "--total-steps", "512", "--quiet", "--out-dir", str(tmp_path / "runs")]
    argv += [arg for item in SETS + ["ppo.minibatch_size=128"] for arg in ("--set", item)]

    def hits() -> int:
        done = subprocess.run(
            [sys.executable, "-c", CACHE_HITS, *argv], env=env, capture_output=True, text=True, timeout=300
        )
        assert done.returncode == 0, done.stderr[-2000:]
        line = done.stdout.strip().splitlines()[-1].split()
        assert line[0] == "hits" and line[2] == "0", done.stdout
        return int(line[1])

    assert hits() == 0
    programs = {path.name.split("-")[0] for path in (tmp_path / "xla").iterdir()}
    assert "jit_learn" in programs and "jit_rollout" in programs, programs
    assert hits() >= 2  # the update and the initial state; the rollout holds the new pool's address
