"""The autoreset-aware episode bookkeeping that every env loop shares, against a plain Python loop."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from canter.envs.base import StepOutput
from canter.envs.episodes import EnvCarry, init_env_carry, track_episodes

GAMMA = 0.9
INFO_KEYS = ("reward_forward", "x_velocity")  # summed over an episode, and averaged per step

# Two envs, eight steps. Env 0 terminates at step 2 and is truncated at step 5; env 1 terminates at step 6. The step
# after each of those is an autoreset step: its reward, info and flags are junk that must count toward nothing.
REWARD = [[1.0, 0.5], [2.0, 0.25], [3.0, 1.0], [9.0, 2.0], [0.5, 0.75], [1.5, 4.0], [7.0, 1.0], [0.25, 8.0]]
TERMINATED = [[0, 0], [0, 0], [1, 0], [1, 0], [0, 0], [0, 0], [0, 1], [0, 1]]
TRUNCATED = [[0, 0], [0, 0], [0, 0], [0, 0], [0, 0], [1, 0], [1, 0], [0, 0]]
FORWARD = [[0.5, 1.0], [0.25, 2.0], [1.0, 0.5], [8.0, 1.0], [2.0, 0.25], [0.5, 1.0], [6.0, 0.5], [1.0, 3.0]]
VELOCITY = [[1.0, 3.0], [2.0, 1.0], [4.0, 2.0], [9.0, 5.0], [1.0, 0.5], [3.0, 1.5], [5.0, 4.0], [2.0, 6.0]]


def reference(gamma):
    """Per step: valid, done, discounted return, running return, length and per-key episode info, by hand."""
    n = len(REWARD[0])
    prev_done = [False] * n
    disc, ret, length = [0.0] * n, [0.0] * n, [0] * n
    sums = {k: [0.0] * n for k in INFO_KEYS}
    rows = []
    for t in range(len(REWARD)):
        row = {name: [] for name in ("valid", "done", "discounted", "return", "length", *INFO_KEYS)}
        for i in range(n):
            valid = not prev_done[i]
            done = valid and bool(TERMINATED[t][i] or TRUNCATED[t][i])
            if valid:
                disc[i] = disc[i] * gamma + REWARD[t][i]
                ret[i] += REWARD[t][i]
                length[i] += 1
                sums["reward_forward"][i] += FORWARD[t][i]
                sums["x_velocity"][i] += VELOCITY[t][i]
            row["valid"].append(valid)
            row["done"].append(done)
            row["discounted"].append(disc[i])
            row["return"].append(ret[i])
            row["length"].append(length[i])
            row["reward_forward"].append(sums["reward_forward"][i])
            row["x_velocity"].append(sums["x_velocity"][i] / max(length[i], 1))
            if done:
                disc[i], ret[i], length[i] = 0.0, 0.0, 0
                sums["reward_forward"][i] = sums["x_velocity"][i] = 0.0
            prev_done[i] = done
        rows.append(row)
    return {name: np.array([row[name] for row in rows]) for name in rows[0]}


def run(gamma):
    """`track_episodes` over the sequence inside `lax.scan`, as the env loops call it."""
    outputs = StepOutput(
        obs=jnp.arange(len(REWARD) * 2 * 3, dtype=jnp.float32).reshape(len(REWARD), 2, 3),
        reward=jnp.array(REWARD, jnp.float32),
        terminated=jnp.array(TERMINATED, bool),
        truncated=jnp.array(TRUNCATED, bool),
        info={"reward_forward": jnp.array(FORWARD, jnp.float32), "x_velocity": jnp.array(VELOCITY, jnp.float32)},
    )

    def step(carry, out):
        carry, episodes = track_episodes(carry, carry.env_state + 1, out, gamma)
        return carry, episodes

    carry = init_env_carry(jnp.zeros((), jnp.int32), jnp.zeros((2, 3)), INFO_KEYS)
    return jax.jit(lambda c: jax.lax.scan(step, c, outputs))(carry)


def test_episode_statistics_match_a_python_loop_across_autoreset_steps():
    expected = reference(GAMMA)
    _carry, got = run(GAMMA)
    np.testing.assert_array_equal(got.valid, expected["valid"])
    np.testing.assert_array_equal(got.done, expected["done"])
    np.testing.assert_array_equal(got.episode_length, expected["length"])
    # Rewards are multiples of 1/4, so the running sums are exact in float32.
    np.testing.assert_array_equal(got.episode_return, expected["return"])
    np.testing.assert_array_equal(got.episode_info["reward_forward"], expected["reward_forward"])
    np.testing.assert_allclose(got.episode_info["x_velocity"], expected["x_velocity"], rtol=1e-6)
    np.testing.assert_allclose(got.discounted_return, expected["discounted"], rtol=1e-6)
    assert got.episode_length.dtype == jnp.int32


def test_finished_episodes_report_their_totals_and_autoreset_steps_are_invalid():
    _, got = run(GAMMA)
    done = np.asarray(got.done)
    # (step, env) of each finished episode: the terminated step 3 of env 0 and the truncated step 6 of env 0 are
    # autoreset steps, whose flags do not end anything.
    assert [tuple(x) for x in np.argwhere(done)] == [(2, 0), (5, 0), (6, 1)]
    np.testing.assert_array_equal(np.asarray(got.episode_return)[done], [6.0, 2.0, 9.5])
    np.testing.assert_array_equal(np.asarray(got.episode_length)[done], [3, 2, 7])
    np.testing.assert_array_equal(np.asarray(got.episode_info["reward_forward"])[done], [1.75, 2.5, 6.25])
    np.testing.assert_allclose(np.asarray(got.episode_info["x_velocity"])[done], [7 / 3, 2.0, 17 / 7], rtol=1e-6)
    np.testing.assert_array_equal(np.argwhere(~np.asarray(got.valid)), [(3, 0), (6, 0), (7, 1)])


def test_the_carry_restarts_where_an_episode_ended_and_keeps_the_step_output():
    carry, _got = run(GAMMA)
    assert isinstance(carry, EnvCarry)
    assert int(carry.env_state) == len(REWARD)
    np.testing.assert_array_equal(carry.obs, np.arange(len(REWARD) * 6, dtype=np.float32).reshape(-1, 2, 3)[-1])
    # Env 0 is one step into the episode after its autoreset; env 1's last step was its autoreset step.
    np.testing.assert_array_equal(carry.prev_done, [False, False])
    np.testing.assert_array_equal(carry.episode_return, [0.25, 0.0])
    np.testing.assert_array_equal(carry.episode_length, [1, 0])
    np.testing.assert_array_equal(carry.info_sums["reward_forward"], [1.0, 0.0])
    np.testing.assert_allclose(carry.discounted_return, [0.25, 0.0])


def test_init_env_carry_starts_every_env_at_zero():
    carry = init_env_carry("handle", np.ones((3, 2), np.float64), ("reward_ctrl",))
    assert carry.env_state == "handle" and carry.obs.dtype == jnp.float32 and carry.obs.shape == (3, 2)
    assert carry.prev_done.dtype == jnp.bool_ and not np.asarray(carry.prev_done).any()
    assert carry.episode_length.dtype == jnp.int32
    for x in (carry.discounted_return, carry.episode_return, carry.info_sums["reward_ctrl"]):
        assert x.dtype == jnp.float32 and x.shape == (3,) and float(jnp.abs(x).sum()) == 0.0


@pytest.mark.parametrize("gamma", [0.0, 1.0])
def test_discounted_return_at_the_extremes(gamma):
    expected = reference(gamma)
    _, got = run(gamma)
    np.testing.assert_allclose(got.discounted_return, expected["discounted"], rtol=1e-6)
    if gamma == 1.0:
        np.testing.assert_array_equal(got.discounted_return, got.episode_return)


def test_reward_terms_add_up_over_an_episode_and_other_info_is_averaged():
    from canter.envs.base import is_summed_info

    # InvertedDoublePendulum-v5's reward is reward_survive - distance_penalty - velocity_penalty.
    summed = ["reward_survive", "reward_ctrl", "cost_contact", "distance_penalty", "velocity_penalty"]
    averaged = ["x_velocity", "x_position", "z_distance_from_origin"]
    assert [is_summed_info(k) for k in summed + averaged] == [True] * len(summed) + [False] * len(averaged)
