"""Checkpoint size, known before the first checkpoint.

A checkpoint holds the whole train state uncompressed, so its size is at most the state's bytes: small for on-policy
algorithms, and for off-policy ones mostly the replay buffer, 4 * (2 * obs_dim + act_dim + 2) bytes per
transition held (docs/algorithms-offpolicy.md has a table per env). A checkpoint holds only the filled part of a
buffer, so the room counted here is for the rows the run can fill by its end (`Algorithm.filled_rows`): the whole
buffer when the run trains longer than the buffer holds, and its run.total_steps rows otherwise. A run keeps
`run.keep_checkpoints` of them and writes the next before it deletes the oldest, plus best.npz when it evaluates
during training and a snapshot while a video renders; those two hold the state without the fields its algorithm
leaves out of them (the replay buffer). Training warns in one line when the run folder's disk has
less free space than that, rather than failing at the first checkpoint, possibly hours in.
"""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from canter.config.schema import Config

# The JSON header beside its list of leaf names: the whole resolved config (every section is written, about 2.3 KB
# as JSON), the env's facts, the run's totals and the hash: under 3 KiB, stored as it is, unpadded.
HEADER_BYTES = 3 * 1024
# numpy's savez stores each array as a zip entry of its own: a local header (30 bytes, the name, and the 20-byte
# zip64 field numpy always asks for) and a central-directory record (46 bytes and the name) around the .npy file.
_ZIP_ENTRY_BYTES = 30 + 20 + 46
_ZIP_END_BYTES = 22 + 56 + 20  # the end record, and its zip64 forms that a file past 4 GiB also has


def _stored_bytes(name: str, shape: tuple[int, ...], dtype: Any) -> int:
    """One array as savez stores it uncompressed: the zip entry, the .npy header (its length depends on the shape)
    and the data."""
    import io

    import numpy as np

    npy_header = io.BytesIO()
    described = {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)), "fortran_order": False, "shape": shape}
    np.lib.format.write_array_header_1_0(npy_header, described)
    size = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
    return _ZIP_ENTRY_BYTES + 2 * len(name.encode()) + len(npy_header.getvalue()) + size


def _written_shape(name: str, shape: tuple[int, ...], dtype: Any, filled_rows: Mapping[str, int]) -> tuple[int, ...]:
    """The shape the leaf `name` is written with when its field (the name's first part) holds at most
    `filled_rows[field]` leading rows: a checkpoint leaves out the unfilled rows of an array of
    `ZERO_TAIL_MIN_BYTES` or more (checkpoint.without_zero_tail), and writes a smaller one whole."""
    import numpy as np

    from canter.training.checkpoint import ZERO_TAIL_MIN_BYTES

    rows = filled_rows.get(name.split("/", 1)[0])
    whole = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
    if rows is None or not shape or whole < ZERO_TAIL_MIN_BYTES:
        return shape
    return (min(shape[0], rows), *shape[1:])


def state_bytes(state: Any, filled_rows: Mapping[str, int] | None = None) -> int:
    """Bytes of the checkpoint file of `state` written uncompressed, from its leaves' shapes (nothing leaves the
    device): each leaf's entry, and the JSON header, which lists every leaf's name and hash. It counts what is
    written, not a padded allowance, so a warning quotes the size the files will have. `filled_rows`: the most
    leading rows each field that fills from the front can hold (`Algorithm.filled_rows`); without it, every array
    counts whole. The episodes in flight that a JAX-native backend adds are counted by the caller, from the env's
    shapes (`warn_if_checkpoints_will_not_fit`)."""
    import json

    import numpy as np

    from canter.training.checkpoint import named_leaves

    total = _ZIP_END_BYTES
    names = []
    for name, leaf in named_leaves(state):
        array = leaf if hasattr(leaf, "shape") and hasattr(leaf, "dtype") else np.asarray(leaf)
        names.append(name)
        shape = _written_shape(name, tuple(array.shape), array.dtype, filled_rows or {})
        total += _stored_bytes(f"leaf:{name}.npy", shape, array.dtype)
    digests = dict.fromkeys(names, "0" * 64)  # each leaf's SHA-256, in hex
    header = HEADER_BYTES + len(json.dumps(names)) + len(json.dumps(digests))
    return total + _stored_bytes("header.npy", (header,), np.uint8)


def policy_files(config: Config) -> int:
    """best.npz and the one it replaced (kept until the next checkpoint), and a video's snapshot and the one being
    rendered: the files that hold the state less the fields its algorithm leaves out."""
    return (2 if config.run.eval_every else 0) + (2 if config.run.video_every else 0)


def checkpoints_at_once(config: Config, existing: int) -> int:
    """How many more full checkpoints the run will hold at its fullest than it holds now (`existing`: its
    ckpt_*.npz files)."""
    return max(config.run.keep_checkpoints + 1 - existing, 1)


def warn_if_checkpoints_will_not_fit(
    run_dirs: Sequence[Path],
    states: Sequence[Any],
    config: Config,
    policy_leaves_out: tuple[str, ...] = (),
    env_carry_bytes: int = 0,
) -> bool:
    """Print one warning line when a disk cannot hold the checkpoints of the seeds whose run folders it holds (the
    seeds of a group write theirs side by side); True if it did. `policy_leaves_out`: the state's fields that
    best.npz and video snapshots leave out. `env_carry_bytes`: the episodes in flight each seed's checkpoint of a
    JAX-native backend also holds (its envs' whole physics state, which on a GPU's thousands of envs outweighs the
    train state)."""
    from canter.algos.registry import get_algorithm
    from canter.training.checkpoint import read_header
    from canter.training.host_memory import size_text
    from canter.training.run_folder import list_checkpoints

    algorithm = get_algorithm(config.run.algo)
    filled_rows = algorithm.filled_rows(config) if algorithm.filled_rows else None
    one = 0
    needed_on: dict[int, tuple[Path, int, int]] = {}  # device -> (first run folder on it, seeds, bytes)
    for run_dir, state in zip(run_dirs, states):
        # A checkpoint that leaves fields out (one written before training began) holds little of a full one's size.
        existing = sum("left_out" not in read_header(path) for path in list_checkpoints(Path(run_dir)))
        one = state_bytes(state, filled_rows) + env_carry_bytes
        policy = state_bytes({k: v for k, v in state._asdict().items() if k not in policy_leaves_out})
        needed = one * checkpoints_at_once(config, existing) + policy * policy_files(config)
        device = os.stat(run_dir).st_dev
        first, seeds, total = needed_on.get(device, (Path(run_dir), 0, 0))
        needed_on[device] = (first, seeds + 1, total + needed)
    short = [
        (first, seeds, total) for first, seeds, total in needed_on.values() if shutil.disk_usage(first).free < total
    ]
    if not short:
        return False
    first, seeds, needed = short[0]
    free = shutil.disk_usage(first).free
    # The fields that only further training reads (a replay buffer) are the bulk of a checkpoint that has any, so
    # the keys that size them (the algorithm's `size_keys`) are the other way to make room.
    sizing = [key for name, key in algorithm.size_keys if name in policy_leaves_out]
    how = " or ".join(["lower run.keep_checkpoints", *sizing])
    whose = "this run takes" if seeds == 1 else f"each of the {seeds} seeds of this group takes"
    they = "it needs" if seeds == 1 else "they need"
    where = first if seeds == 1 else first.parent
    print(
        f"canter: warning: a checkpoint of {whose} {size_text(one)} and {they} "
        f"room for {size_text(needed)} of them, but {where} has {size_text(free)} free; free space, {how}",
        file=sys.stderr,
    )
    return True
