import jax
import jax.numpy as jnp
import numpy as np

from canter.core.replay import Transitions, init_buffer, insert, sample


def _rows(values, obs_dim=2, act_dim=1):
    v = np.asarray(values, np.float32)
    return Transitions(
        np.repeat(v[:, None], obs_dim, 1),
        np.repeat(v[:, None], act_dim, 1) / 10,
        v * 100,
        np.repeat(v[:, None], obs_dim, 1) + 0.5,
        (v % 2 == 0).astype(np.float32),
    )


def test_insert_wraps_and_skips_masked_rows_like_a_python_ring_buffer():
    capacity = 5
    buffer = init_buffer(capacity, 2, 1)
    reference = [None] * capacity
    ptr = size = 0
    value = 1
    rng = np.random.default_rng(0)
    for _ in range(7):
        values = np.arange(value, value + 3)
        value += 3
        mask = rng.random(3) < 0.7
        buffer = insert(buffer, _rows(values), jnp.asarray(mask))
        for v, m in zip(values, mask):
            if m:
                reference[ptr] = v
                ptr = (ptr + 1) % capacity
                size = min(size + 1, capacity)
        assert int(buffer.ptr) == ptr and int(buffer.size) == size
        stored = [reference[i] for i in range(size)]
        expected = _rows(stored)
        for got, want in zip(buffer.data, expected):
            np.testing.assert_array_equal(np.asarray(got)[:size], want)
    assert size == capacity  # the ring wrapped


def test_sample_draws_only_filled_slots_uniformly():
    buffer = insert(init_buffer(100, 2, 1), _rows(np.arange(1, 11)), jnp.ones(10, bool))
    batch = sample(buffer, jax.random.key(0), 20_000)
    rewards = np.asarray(batch.reward) / 100
    assert set(np.unique(rewards)) == set(range(1, 11))  # never an empty (zero) slot
    counts = np.bincount(rewards.astype(int), minlength=11)[1:]
    assert np.all(np.abs(counts / 20_000 - 0.1) < 0.01)
    # Rows stay aligned across fields.
    np.testing.assert_allclose(np.asarray(batch.next_obs)[:, 0], rewards + 0.5)
    np.testing.assert_allclose(np.asarray(batch.action)[:, 0], rewards / 10, rtol=1e-6)
