import numpy as np

from canter.core.gae import compute_gae


def reference_gae(rewards, values, terminated, done, valid, gamma, lam):
    """Plain per-env Python loop over episodes."""
    T, N = rewards.shape
    adv = np.zeros((T, N))
    for n in range(N):
        running = 0.0
        for t in reversed(range(T)):
            if not valid[t, n]:
                running = 0.0
                continue
            next_value = 0.0 if terminated[t, n] else values[t + 1, n]
            delta = rewards[t, n] + gamma * next_value - values[t, n]
            running = delta if done[t, n] else delta + gamma * lam * running
            adv[t, n] = running
    return adv, (adv + values[:-1]) * valid


def test_gae_matches_python_loop_with_termination_truncation_and_reset_steps():
    rng = np.random.default_rng(0)
    T, N = 12, 3
    rewards = rng.normal(size=(T, N)).astype(np.float32)
    values = rng.normal(size=(T + 1, N)).astype(np.float32)
    terminated = np.zeros((T, N), bool)
    truncated = np.zeros((T, N), bool)
    terminated[3, 0] = True  # env 0 terminates at 3, autoreset step at 4
    truncated[7, 1] = True  # env 1 truncated at 7: bootstrap from values[8] (true final obs)
    terminated[T - 1, 2] = True  # env 2 ends on the last step
    done = terminated | truncated
    valid = np.ones((T, N), bool)
    valid[4, 0] = False
    valid[8, 1] = False
    rewards[~valid] = 0.0
    adv, ret = compute_gae(rewards, values, terminated, done, valid, 0.99, 0.95)
    ref_adv, ref_ret = reference_gae(rewards, values, terminated, done, valid, 0.99, 0.95)
    np.testing.assert_allclose(np.asarray(adv), ref_adv, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(ret), ref_ret, rtol=1e-5, atol=1e-5)


def test_truncation_bootstraps_from_final_observation_and_termination_does_not():
    values = np.array([[0.0], [0.0], [5.0]], np.float32)
    rewards = np.array([[1.0], [1.0]], np.float32)
    valid = np.ones((2, 1), bool)
    done = np.array([[False], [True]])
    truncated_adv, _ = compute_gae(rewards, values, np.zeros((2, 1), bool), done, valid, 0.5, 1.0)
    terminated_adv, _ = compute_gae(rewards, values, done, done, valid, 0.5, 1.0)
    assert np.isclose(float(truncated_adv[1, 0]), 1.0 + 0.5 * 5.0)
    assert np.isclose(float(terminated_adv[1, 0]), 1.0)
    assert np.isclose(float(truncated_adv[0, 0]), 1.0 + 0.5 * (1.0 + 0.5 * 5.0))


def test_reset_step_has_zero_advantage_and_cuts_the_chain():
    values = np.ones((4, 1), np.float32)
    rewards = np.array([[1.0], [0.0], [1.0]], np.float32)
    terminated = np.array([[True], [False], [False]])
    valid = np.array([[True], [False], [True]])
    adv, ret = compute_gae(rewards, values, terminated, terminated, valid, 0.9, 0.9)
    assert float(adv[1, 0]) == 0.0 and float(ret[1, 0]) == 0.0
    assert np.isclose(float(adv[0, 0]), 1.0 - 1.0)
