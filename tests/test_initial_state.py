"""A new run's train state comes from one compiled program with the seed as its argument: bit for bit the state that
the algorithm's initializers build op by op, for every algorithm, in 64-bit mode (the CPU backends) and 32-bit mode
(mjx and brax), and for every seed a run may have."""

from dataclasses import replace

import jax
import numpy as np
import pytest

from canter.algos import get_algorithm
from canter.config.build import build_config
from canter.config.values import SEED_LIMIT
from canter.envs.base import EnvSpec
from canter.training.group_program import initial_state_program

SPEC = EnvSpec(
    id="InvertedPendulum-v5",
    backend="gymnasium",
    num_envs=1,
    obs_dim=4,
    act_dim=1,
    action_low=(-3.0,),
    action_high=(3.0,),
    max_episode_steps=1000,
    info_keys=(),
)
SMALL = {
    "ppo": ["net.hidden=8,8"],
    "trpo": ["net.hidden=8,8"],
    "td3": ["td3.hidden=8,8", "td3.buffer_size=256"],
    "sac": ["sac.hidden=8,8", "sac.buffer_size=256"],
    "ddpg": ["ddpg.hidden=8,8", "ddpg.buffer_size=256"],
}
SEEDS = (0, 7, SEED_LIMIT - 1)


def _assert_same_state(compiled, eager):
    assert jax.tree.structure(compiled) == jax.tree.structure(eager)
    for a, b in zip(jax.tree.leaves(compiled), jax.tree.leaves(eager)):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize("algo", sorted(SMALL))
def test_the_compiled_state_is_the_eager_one_for_every_seed(algo):
    config = build_config("InvertedPendulum-v5", algo=algo, sets=SMALL[algo])
    algorithm = get_algorithm(algo)
    initial_state = initial_state_program(algorithm, config, SPEC)
    for seed in SEEDS:
        _assert_same_state(initial_state(seed), algorithm.init_state(config, SPEC, seed))


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_the_compiled_state_is_the_eager_one_in_32_bit_mode(algo):
    config = build_config("InvertedPendulum-v5", algo=algo, sets=SMALL[algo])
    algorithm = get_algorithm(algo)
    with jax.enable_x64(False):
        initial_state = initial_state_program(algorithm, config, SPEC)
        for seed in SEEDS:
            compiled = initial_state(seed)
            assert compiled.global_step.dtype == np.int32
            _assert_same_state(compiled, algorithm.init_state(config, SPEC, seed))


def test_the_seeds_of_a_group_share_one_trace_and_differ():
    algorithm = get_algorithm("ppo")
    traced = []

    def counted(config, spec, seed):
        traced.append(seed)
        return algorithm.init_state(config, spec, seed)

    config = build_config("InvertedPendulum-v5", sets=SMALL["ppo"])
    initial_state = initial_state_program(replace(algorithm, init_state=counted), config, SPEC)
    states = [initial_state(seed) for seed in (0, 1, 2)]
    assert len(traced) == 1
    keys = {tuple(np.asarray(state.key)) for state in states}
    first_layers = {np.asarray(state.params["actor"][0]["w"]).tobytes() for state in states}
    assert len(keys) == len(first_layers) == 3
