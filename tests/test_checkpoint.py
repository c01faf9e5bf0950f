import json
import shutil

import jax
import numpy as np
import pytest

from canter.algos.ppo.iteration import init_train_state
from canter.config.build import build_config
from canter.errors import CanterError
from canter.training import checkpoint, run_folder
from conftest import ARCHIVED_RUN


def _state(seed=0):
    return init_train_state(build_config("Hopper-v5", sets=["net.hidden=8,8"]), 11, 3, seed)


def _equal(a, b):
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    return len(la) == len(lb) and all(
        np.array_equal(np.asarray(x), np.asarray(y)) and np.asarray(x).dtype == np.asarray(y).dtype
        for x, y in zip(la, lb)
    )


def test_round_trip_is_exact_and_leaves_no_temp_files(tmp_path):
    state = _state()
    path = run_folder.checkpoint_path(tmp_path, 1234)
    checkpoint.save(path, state, {"global_step": 1234, "config": "", "env": {}})
    arrays, header = checkpoint.read(path)
    assert header["global_step"] == 1234 and header["format_version"] == checkpoint.FORMAT_VERSION
    assert _equal(checkpoint.restore(_state(seed=1), arrays, path), state)
    assert [p.name for p in path.parent.iterdir()] == [path.name]


def test_corrupt_truncated_and_foreign_checkpoints_are_one_line_errors(tmp_path):
    state = _state()
    path = tmp_path / "ckpt_000000000001.npz"
    checkpoint.save(path, state, {"global_step": 1})
    data = path.read_bytes()

    truncated = tmp_path / "t.npz"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(CanterError, match="corrupt or truncated"):
        checkpoint.read(truncated)

    flipped = bytearray(data)
    flipped[len(data) // 3] ^= 0xFF
    corrupt = tmp_path / "c.npz"
    corrupt.write_bytes(bytes(flipped))
    with pytest.raises(CanterError, match="corrupt"):
        checkpoint.read(corrupt)

    arrays, header = checkpoint.read(path)
    header["format_version"] = 99
    payload = {f"leaf:{k}": v for k, v in arrays.items()}
    payload["header"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
    other = tmp_path / "v.npz"
    np.savez(other, **payload)
    with pytest.raises(CanterError, match="format version 99"):
        checkpoint.read(other)

    with pytest.raises(CanterError, match="does not match this config"):
        checkpoint.restore(init_train_state(build_config("Hopper-v5", sets=["net.hidden=4"]), 11, 3, 0), arrays, path)


def test_a_leaf_of_another_dtype_is_named_with_both_dtypes(tmp_path):
    checkpoint.save(tmp_path / "c.npz", {"x": np.zeros(3, np.float64)}, {})
    arrays, _ = checkpoint.read(tmp_path / "c.npz")
    with pytest.raises(CanterError, match=r"'x' is float64 \(3,\), expected float32 \(3,\)"):
        checkpoint.restore({"x": np.zeros(3, np.float32)}, arrays, tmp_path / "c.npz")


def test_left_out_fields_are_not_written_and_read_back_as_zeros(tmp_path):
    state = {"buffer": {"obs": np.ones((1000, 5), np.float32), "size": np.int32(7)}, "policy": np.arange(3.0)}
    path = tmp_path / "best.npz"
    checkpoint.save(path, state, {}, leave_out=("buffer",))
    arrays, header = checkpoint.read(path)
    assert sorted(arrays) == ["policy"] and header["left_out"] == ["buffer/obs", "buffer/size"]
    # A reader from before `left_out` names the release to use, rather than calling it another config's.
    assert header["format_version"] == checkpoint.FORMAT_VERSION > max(checkpoint.WHOLE_FILE_HASH_VERSIONS) == 2
    assert path.stat().st_size < 2000  # the 20 kB buffer is not in the file
    back = checkpoint.restore(state, arrays, path, left_out=header["left_out"])
    np.testing.assert_array_equal(back["policy"], state["policy"])
    assert back["buffer"]["obs"].shape == (1000, 5) and not back["buffer"]["obs"].any()
    assert back["buffer"]["size"].dtype == np.int32 and back["buffer"]["size"] == 0
    # Without the header's list, a missing leaf is still a checkpoint of another config.
    with pytest.raises(CanterError, match="missing 'buffer/obs'"):
        checkpoint.restore(state, arrays, path)


def test_prune_keeps_newest(tmp_path):
    for step in (10, 20, 30, 40):
        checkpoint.save(run_folder.checkpoint_path(tmp_path, step), {"x": np.zeros(1)}, {})
    checkpoint.prune(tmp_path, 2)
    assert [p.name for p in run_folder.list_checkpoints(tmp_path)] == ["ckpt_000000000030.npz", "ckpt_000000000040.npz"]
    assert checkpoint.latest(tmp_path).name == "ckpt_000000000040.npz"
    empty = tmp_path / "empty_run"
    empty.mkdir()
    shutil.copy(ARCHIVED_RUN / "config.toml", empty)  # a run stopped before its first checkpoint: it can start again
    with pytest.raises(
        CanterError,
        match=r"no checkpoint in .* yet: .* canter train --resume .* trains one stopped before that again from step 0",
    ):
        checkpoint.latest(empty)
    with pytest.raises(CanterError, match="run folder not found"):
        checkpoint.latest(tmp_path / "missing")


def test_compressed_checkpoint_reads_back_the_same_and_is_smaller(tmp_path):
    ckpt = checkpoint
    state = {"buffer": np.full((5000, 40), 0.5, np.float32), "w": np.arange(6, dtype=np.float32)}
    plain, packed = tmp_path / "plain" / "ckpt_000000000001.npz", tmp_path / "packed" / "ckpt_000000000001.npz"
    ckpt.save(plain, state, {"global_step": 1})
    ckpt.save(packed, state, {"global_step": 1}, compress=True)
    assert packed.stat().st_size < plain.stat().st_size / 10
    for path in (plain, packed):
        arrays, _header = ckpt.read(path)
        restored = ckpt.restore(state, arrays, path)
        np.testing.assert_array_equal(restored["w"], state["w"])
        np.testing.assert_array_equal(restored["buffer"], state["buffer"])


def test_the_digest_hashes_each_arrays_bytes_as_written():
    """The digest reads each array's bytes in place (a replay buffer is gigabytes); they are the bytes a copy holds,
    so checkpoints written before hash the same."""
    import hashlib
    import json

    from canter.training.checkpoint import _digest

    arrays = {
        "b": np.arange(6, dtype=np.float32).reshape(2, 3),
        "a": np.array(3.5),
        "c": np.array([True, False]),
        "d": np.zeros((0, 4), np.int32),
    }
    header = {"global_step": 7}
    expected = hashlib.sha256(json.dumps(header, sort_keys=True).encode())
    for name in sorted(arrays):
        copy = np.ascontiguousarray(arrays[name])  # at least one axis, so a scalar hashes as shape (1,)
        expected.update(name.encode() + str(copy.dtype).encode() + str(copy.shape).encode() + copy.tobytes())
    assert _digest(arrays, header) == expected.hexdigest()


def test_the_digest_copies_no_array():
    """A checkpoint's hash reads the arrays where they lie: a copy of a gigabyte replay buffer doubled the memory
    a checkpoint needs."""
    import tracemalloc

    from canter.training.checkpoint import _digest

    arrays = {"buffer/obs": np.ones((1 << 14, 1 << 10), np.float32)}  # 64 MiB
    tracemalloc.start()
    try:
        _digest(arrays, {"global_step": 1})
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < (1 << 20), peak


def _flip_byte_of(path, needle: bytes) -> None:
    data = bytearray(path.read_bytes())
    at = data.find(needle)
    assert at >= 0
    data[at] ^= 0xFF
    path.write_bytes(bytes(data))


def _no_buffer(name: str) -> bool:
    return not name.startswith("buffer/")


def test_each_array_is_checked_on_its_own_so_a_policy_is_read_without_the_buffer(tmp_path):
    """A damaged replay buffer fails a whole read (a resume), but not a reader of the policy, which never reads it;
    a damaged policy fails both."""
    state = {"buffer": {"obs": np.full((4096, 16), 0.5, np.float32)}, "policy": np.array([1.25, 2.5, 3.75])}
    path = tmp_path / "c.npz"
    checkpoint.save(path, state, {"global_step": 3})
    arrays, header = checkpoint.read(path, wanted=_no_buffer)
    assert sorted(arrays) == ["policy"] and header["leaves"] == ["buffer/obs", "policy"]

    buffer_damaged = tmp_path / "b.npz"
    buffer_damaged.write_bytes(path.read_bytes())
    _flip_byte_of(buffer_damaged, np.full(64, 0.5, np.float32).tobytes())
    np.testing.assert_array_equal(checkpoint.read(buffer_damaged, wanted=_no_buffer)[0]["policy"], state["policy"])
    with pytest.raises(checkpoint.DamagedCheckpoint, match="corrupt"):  # the zip's own CRC says so first
        checkpoint.read(buffer_damaged)

    # A policy changed in a sound zip (rewritten by a tool): only its own hash tells.
    with np.load(path) as data:
        payload = {name: data[name] for name in data.files}
    policy_damaged = tmp_path / "p.npz"
    np.savez(policy_damaged, **dict(payload, **{"leaf:policy": state["policy"] + 1}))
    for wanted in (None, _no_buffer):
        with pytest.raises(checkpoint.DamagedCheckpoint, match=r"fails its content hash \(corrupt\)"):
            checkpoint.read(policy_damaged, wanted=wanted)


def test_a_header_edited_or_an_array_added_fails_the_hash(tmp_path):
    path = tmp_path / "c.npz"
    checkpoint.save(path, {"policy": np.arange(3.0)}, {"global_step": 3})
    with np.load(path) as data:
        payload = {name: data[name] for name in data.files}
    header = json.loads(bytes(payload["header"]).decode())
    edited = dict(payload, header=np.frombuffer(json.dumps(dict(header, global_step=4)).encode(), np.uint8))
    added = dict(payload, **{"leaf:extra": np.zeros(2)})
    for name, changed in (("edited", edited), ("added", added)):
        np.savez(tmp_path / f"{name}.npz", **changed)
        with pytest.raises(checkpoint.DamagedCheckpoint, match=r"fails its content hash"):
            checkpoint.read(tmp_path / f"{name}.npz", wanted=lambda name: name == "policy")


def test_reading_the_policy_reads_none_of_the_buffer(tmp_path):
    """An off-policy checkpoint is mostly its replay buffer (2.7 GiB for Humanoid): playing its policy once read and
    hashed all of it."""
    import tracemalloc

    state = {"buffer": {"obs": np.ones((1 << 14, 1 << 10), np.float32)}, "policy": np.arange(3.0)}  # 64 MiB
    path = tmp_path / "c.npz"
    checkpoint.save(path, state, {})
    tracemalloc.start()
    try:
        arrays, _ = checkpoint.read(path, wanted=_no_buffer)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert sorted(arrays) == ["policy"] and peak < 4 << 20, peak


def test_saving_a_header_read_back_works_out_its_own_fields_again(tmp_path):
    state = {"buffer": np.ones(4), "policy": np.arange(3.0)}
    checkpoint.save(tmp_path / "best.npz", state, {"global_step": 1}, leave_out=("buffer",))
    _, header = checkpoint.read(tmp_path / "best.npz")
    checkpoint.save(tmp_path / "c.npz", state, dict(header, global_step=2))
    arrays, again = checkpoint.read(tmp_path / "c.npz")
    assert sorted(arrays) == ["buffer", "policy"] and "left_out" not in again and again["global_step"] == 2


def test_a_policy_loads_from_an_off_policy_checkpoint_without_its_buffer(tmp_path):
    from canter.training.restore import load_state

    run = tmp_path / "td3"
    shutil.copytree(ARCHIVED_RUN.parent / "td3", run)
    newest = checkpoint.latest(run)
    _, _, state, header = load_state(run)
    checkpoint.save(newest, state, header)  # in this canter's format, which hashes each array
    _, _, whole, _ = load_state(run)
    _, _, policy, _ = load_state(run, policy_only=True)
    assert np.asarray(whole.buffer.data.obs).any() and not np.asarray(policy.buffer.data.obs).any()
    assert _equal(whole.learner, policy.learner) and _equal(whole.obs_stats, policy.obs_stats)


def _zero_tail_by_loop(array):
    """The reference: rows dropped from the end, one at a time, while every byte of the last one is zero."""
    rows = array.shape[0]
    while rows and not np.ascontiguousarray(array[rows - 1]).view(np.uint8).any():
        rows -= 1
    return array[:rows]


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int32, np.bool_])
def test_an_arrays_zero_tail_is_found_as_a_row_by_row_loop_finds_it(dtype):
    rng = np.random.default_rng(0)
    for rows, filled in ((10_000, 0), (10_000, 1), (10_000, 1234), (10_000, 9_999), (10_000, 10_000), (70_000, 65_537)):
        array = np.zeros((rows, 7), dtype)
        array[:filled] = rng.integers(1, 3, (filled, 7)).astype(dtype)
        if filled > 40:
            array[filled - 40 : filled - 20] = 0  # zero rows inside the filled part stay
        found = checkpoint.without_zero_tail(array)
        assert found.shape[0] == _zero_tail_by_loop(array).shape[0] == filled
        assert np.shares_memory(found, array) or filled == 0  # no copy of a buffer of gigabytes
        padded = np.zeros_like(array)
        padded[: found.shape[0]] = found
        np.testing.assert_array_equal(padded, array)
    negative_zero = np.zeros((20_000, 3), np.float32)
    negative_zero[12_345, 1] = -0.0  # equal to 0.0, but other bits: kept, so the rows read back are the same bits
    assert checkpoint.without_zero_tail(negative_zero).shape[0] == 12_346
    small = np.zeros((100, 3), np.float32)  # under 64 KiB: written whole
    assert checkpoint.without_zero_tail(small) is small


def test_a_part_filled_buffer_is_written_as_far_as_it_is_filled_and_read_back_whole(tmp_path):
    """A replay buffer a tenth filled took a checkpoint of its whole capacity: 2.7 GiB for Humanoid from the first
    checkpoint on."""
    capacity, filled = 100_000, 10_000
    rng = np.random.default_rng(1)
    buffer = {"obs": np.zeros((capacity, 17), np.float32), "done": np.zeros(capacity, np.float32)}
    buffer["obs"][:filled] = rng.normal(size=(filled, 17))
    buffer["done"][filled - 1] = 1.0
    state = {"buffer": buffer, "policy": rng.normal(size=(64, 64)).astype(np.float32)}
    path = tmp_path / "ckpt_000000010000.npz"
    checkpoint.save(path, state, {"global_step": filled})
    full = tmp_path / "full.npz"
    checkpoint.save(full, dict(state, buffer={k: v + 1 for k, v in buffer.items()}), {"global_step": filled})
    assert path.stat().st_size < 0.12 * full.stat().st_size
    arrays, header = checkpoint.read(path)
    assert header["zero_tail"] == {"buffer/done": capacity, "buffer/obs": capacity}
    assert header["format_version"] == checkpoint.FORMAT_VERSION == 4
    assert _equal(checkpoint.restore(state, arrays, path), state)
    policy, _ = checkpoint.read(path, wanted=_no_buffer)
    np.testing.assert_array_equal(policy["policy"], state["policy"])


def test_a_zero_tail_that_gives_fewer_rows_than_written_is_damage(tmp_path):
    state = {"buffer": np.zeros((20_000, 4), np.float32)}
    state["buffer"][:5] = 1.0
    path = tmp_path / "c.npz"
    checkpoint.save(path, state, {"global_step": 1})
    with np.load(path) as data:
        payload = {name: data[name] for name in data.files}
    header = json.loads(bytes(payload["header"]).decode())
    for rows in (3, "many"):
        edited = dict(header, zero_tail={"buffer": rows})
        edited["sha256"] = checkpoint._header_digest({k: v for k, v in edited.items() if k != "sha256"})
        np.savez(tmp_path / "e.npz", **dict(payload, header=np.frombuffer(json.dumps(edited).encode(), np.uint8)))
        with pytest.raises(checkpoint.DamagedCheckpoint, match=r"its header gives 'buffer'"):
            checkpoint.read(tmp_path / "e.npz")


def test_a_checkpoint_of_format_3_still_reads(tmp_path, monkeypatch):
    """Written as the release before wrote it: each array whole, and format version 3."""
    state = {"buffer": np.zeros((20_000, 4), np.float32), "policy": np.arange(3.0)}
    monkeypatch.setattr(checkpoint, "FORMAT_VERSION", 3)
    monkeypatch.setattr(checkpoint, "ZERO_TAIL_MIN_BYTES", 1 << 40)
    checkpoint.save(tmp_path / "c.npz", state, {"global_step": 1})
    monkeypatch.undo()
    arrays, header = checkpoint.read(tmp_path / "c.npz")
    assert header["format_version"] == 3 and "zero_tail" not in header
    assert _equal(checkpoint.restore(state, arrays, tmp_path / "c.npz"), state)


def test_a_nearly_full_buffer_is_read_into_its_whole_array_without_a_second_copy(tmp_path):
    """Padding a buffer read whole held it twice: a resume of a Humanoid run at 90% would peak 2.4 GiB higher."""
    import tracemalloc

    buffer = np.zeros((1 << 14, 1 << 10), np.float32)  # 64 MiB
    buffer[: 9 * (1 << 14) // 10] = 0.5
    path = tmp_path / "c.npz"
    checkpoint.save(path, {"buffer": buffer}, {})
    tracemalloc.start()
    try:
        arrays, header = checkpoint.read(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # The buffer once, and a few MiB the zip reader holds at a time (it read 1.9 times the buffer).
    assert header["zero_tail"] == {"buffer": 1 << 14} and peak < buffer.nbytes + (12 << 20), peak / buffer.nbytes
    np.testing.assert_array_equal(arrays["buffer"], buffer)
