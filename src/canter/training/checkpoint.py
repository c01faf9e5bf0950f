"""Atomic, versioned, hashed checkpoints.

A checkpoint is one `.npz` file: the train state's leaves as arrays (named by their pytree path), plus a JSON
header with the format version, the resolved config, env facts needed to rebuild the policy without the env, the
step count, a SHA-256 of each array (`leaf_sha256`) and a SHA-256 of the header (`sha256`), which thereby vouches
for every array. A reader that needs only some arrays (a policy, without its replay buffer) reads and checks only
those. An array of 64 KiB or more is written without its trailing rows of zeros (the unfilled part of a replay
buffer); the header's `zero_tail` gives such an array's whole row count, and reading it gives the rows back. It is
written to a temp file in the same folder, fsynced and renamed, so a reader sees either the old file or the new
one, never half of one.

A run folder keeps its newest `run.keep_checkpoints` checkpoints as `checkpoints/ckpt_<step>.npz` and, when it
evaluates during training, the best evaluated state as `checkpoints/best.npz`, whose header also records the
evaluation (`evaluation`); pruning never touches it. `resolve` picks one of them by name: `last`, `best` or a file.
best.npz, which is only read for its policy, may leave out fields that only further training reads (a replay
buffer); its header lists those leaves (`left_out`), and reading it gives them back as zeros.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from canter.config.schema import Config
from canter.config.serialize import from_toml_text
from canter.errors import CanterError, new_run, resume_run, with_python
from canter.files import atomic_write_bytes
from canter.parsing import json_value
from canter.run_layout import (
    BEST_FILE,
    CHECKPOINT_FOLDER,
    CHECKPOINT_NAME,
    CONFIG_FILE,
    KEPT_BEST_FILE,
    finished_without_checkpoints,
    has_finished,
    run_files_in,
    run_format,
)
from canter.training.run_folder import (
    check_given_checkpoint,
    check_own_checkpoint,
    checkpoint_dir,
    list_checkpoints,
    read_config,
)

# Versions 1 and 2 hash all arrays together, so a file is only checked whole; version 2 marked a checkpoint that
# leaves fields out (`left_out`), which a version-1 reader would take for a checkpoint of another config.
WHOLE_FILE_HASH_VERSIONS = (1, 2)
# Version 3 hashes each array on its own; version 4 also writes a large array without its trailing zero rows, which
# a version-3 reader would take for an array of another config's shape.
FORMAT_VERSION = 4
READABLE_VERSIONS = (*WHOLE_FILE_HASH_VERSIONS, 3, FORMAT_VERSION)
# What `save` works out itself: a header given with them (one read back, edited) has them replaced.
_DERIVED_FIELDS = ("format_version", "leaves", "left_out", "env_carry_leaves", "zero_tail", "leaf_sha256", "sha256")
# Smaller arrays are written whole: what their zero rows would save is less than a header entry costs to read.
ZERO_TAIL_MIN_BYTES = 1 << 16
_SCAN_BYTES = 1 << 20  # looked at per step of the scan for an array's last set row
ENV_CARRY = "env_carry/"
LAST, BEST = "last", "best"
_CHECKPOINT_TAKES = f"{with_python('--checkpoint', 'checkpoint=')} takes {LAST}, {BEST} or a .npz file"


class DamagedCheckpoint(CanterError):
    """A checkpoint file that cannot be read as one: `what` is wrong with it, and the message says what to do about
    it where it lies. A caller that knows better advice (a bench, which trains a moved seed anew) reads `path`."""

    def __init__(self, path: Path, what: str) -> None:
        super().__init__(f"checkpoint {path} {what}; {_damaged_fix(path)}")
        self.path = path
        self.what = what


def _damaged_fix(path: Path) -> str:
    """What to do about a damaged checkpoint, by where it is: of a run folder's periodic ones, `last` is the newest
    file, so without it the one before is used, if there is one. The run's only checkpoint leaves its config.toml to
    start it again, so that advice is given only where config.toml reads as a config."""
    if path.parent.name != checkpoint_dir(Path()).name or not (
        CHECKPOINT_NAME.match(path.name) or path.name == BEST_FILE
    ):
        return "pass a sound one (a run folder's checkpoints/ckpt_*.npz)"
    run_dir = path.parent.parent
    periodic = list_checkpoints(run_dir)
    if path.name == BEST_FILE and periodic:  # read by train --resume too, which takes no --checkpoint: fits both
        return (
            f"move it out of its folder (training's next evaluation writes a new one); eval, video, export and "
            f"report can take {with_python(f'--checkpoint {LAST}', f'checkpoint={LAST!r}')} instead"
        )
    if len(periodic) > 1:
        return (
            f"move it out of its folder to use the checkpoint before it; eval, video, export and report also take "
            f"another as {with_python('--checkpoint FILE', 'checkpoint=FILE')}"
        )
    best = path.name != BEST_FILE and _sound_header(best_path(run_dir))
    finished = has_finished(run_dir)  # without its checkpoints a finished run is an archive, which no resume trains
    fault = _config_fault(run_dir, new=finished)
    or_best = f"; {_best_instead(not fault)}" if best else ""
    if fault:
        lost = "its training cannot go on" if best else "nothing of the run can be restored"
        return (
            f"it is the run's only one and {fault}, so {lost} from its folder: restore the checkpoint or "
            f"{CONFIG_FILE} from a copy, or {_NEW_RUN_WITH_ITS_SETTINGS}{or_best}"
        )
    if finished:
        return (
            f"it is the run's only one, so move it away and start the run again with "
            f"{new_run(run_dir / CONFIG_FILE)}{or_best}"
        )
    # A best.npz without the rows of its evaluation is refused by a resume that starts over: it goes too.
    moved = f"the run's metrics.csv and {BEST_FILE}" if best else "the run's metrics.csv"
    return (
        f"it is the run's only one: restore it from a copy, or move it away with {moved}, and "
        f"{resume_run(run_dir)} trains the run again from step 0{or_best}"
    )


def _best_instead(config_read: bool) -> str:
    """The commands that read best.npz where the run's last checkpoint is lost: report also reads config.toml."""
    readers = "eval, video, export and report" if config_read else "eval, video and export"
    return f"{readers} can take {with_python(f'--checkpoint {BEST}', f'checkpoint={BEST!r}')} instead"


# The fix of a run whose folder holds nothing to start it from: its settings, which only its user knows now.
_NEW_RUN_WITH_ITS_SETTINGS = "train a new run with the same settings: " + with_python(
    "canter train ENV --set KEY=VALUE ...", "canter.train(canter.build_config('ENV', sets=[...]))"
)


def _config_fault(run_dir: Path, new: bool) -> str | None:
    """What keeps the run's config.toml from starting it again, as a new run from the file (`new`) or as a resume
    from step 0 reads it; None where it can."""
    config_file = run_dir / CONFIG_FILE
    run_format(run_dir)  # a newer canter's folder, or a damaged versions.json: that error, whose fix comes first
    if not (config_file.exists() or config_file.is_symlink()):
        return f"its {CONFIG_FILE} is missing"
    try:
        if new:
            from canter.config.build import build_config  # the config layer, loaded where a fix needs it

            build_config(None, config_file=config_file, notes=False)
        else:
            read_config(run_dir)
    except (CanterError, OSError):
        return f"its {CONFIG_FILE} cannot be read as a config"
    return None


def _sound_header(path: Path) -> bool:
    """Whether a checkpoint file's header reads (its arrays are not checked)."""
    if not path.is_file():
        return False
    try:
        read_header(path)
    except (CanterError, OSError):
        return False
    return True


def _path_name(path: tuple) -> str:
    return "/".join(str(getattr(p, "key", getattr(p, "idx", getattr(p, "name", p)))) for p in path)


def _hash_array(h: Any, name: str, array: np.ndarray) -> None:
    a = np.ascontiguousarray(array)
    h.update(name.encode())
    h.update(str(a.dtype).encode())
    h.update(str(a.shape).encode())
    h.update(a.reshape(-1).view(np.uint8).data)  # its bytes in place: a replay buffer is gigabytes


def _digest(arrays: dict[str, np.ndarray], header: dict[str, Any]) -> str:
    """The whole-file hash of format versions 1 and 2: the header, then every array."""
    h = hashlib.sha256()
    h.update(json.dumps(header, sort_keys=True).encode())
    for name in sorted(arrays):
        _hash_array(h, name, arrays[name])
    return h.hexdigest()


def _leaf_digest(name: str, array: np.ndarray) -> str:
    h = hashlib.sha256()
    _hash_array(h, name, array)
    return h.hexdigest()


def _header_digest(header: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(header, sort_keys=True).encode()).hexdigest()


def named_leaves(tree: Any, prefix: str = "") -> list[tuple[str, Any]]:
    """A pytree's leaves, named by their paths, where they are (nothing moves off the device)."""
    return [(prefix + _path_name(p), leaf) for p, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]]


def without_zero_tail(array: np.ndarray) -> np.ndarray:
    """`array` up to its last row (along the first axis) that has a bit set: a replay buffer is written only as far
    as it is filled. Scanned from the end a block at a time, so a full buffer costs one block and no copy is made;
    -0.0 is not zero here, so the rows read back are the same bits."""
    if array.ndim == 0 or array.nbytes < ZERO_TAIL_MIN_BYTES:
        return array
    rows = np.ascontiguousarray(array).reshape(array.shape[0], -1).view(np.uint8)
    block = max(1, _SCAN_BYTES // max(rows.shape[1], 1))
    end = rows.shape[0]
    while end > 0:
        start = max(0, end - block)
        set_rows = np.flatnonzero(rows[start:end].any(axis=1))
        if set_rows.size:
            return array[: start + int(set_rows[-1]) + 1]
        end = start
    return array[:0]


def _to_host(named: list[tuple[str, Any]]) -> dict[str, np.ndarray]:
    """Named leaves as host arrays, fetched from the device in one transfer."""
    return {name: np.asarray(value) for (name, _), value in zip(named, jax.device_get([leaf for _, leaf in named]))}


def save(
    path: Path,
    state: Any,
    header: dict[str, Any],
    compress: bool = False,
    env_carry: Any = None,
    leave_out: tuple[str, ...] = (),
) -> None:
    """Write a checkpoint; `compress` deflates the arrays (slower to write, much smaller for a part-filled replay
    buffer). Both forms are read the same way. `env_carry`, where the env state is a pytree (JAX-native backends),
    holds the episodes in flight under names starting with `env_carry/`, so that a resumed run continues them.
    `leave_out` names top-level fields of the state not to write (listed in the header's `left_out`)."""
    named = named_leaves(state)
    left_out = [name for name, _ in named if name.split("/", 1)[0] in leave_out]
    # Only the kept leaves leave the device: a replay buffer left out stays where it is.
    arrays = _to_host([(name, leaf) for name, leaf in named if name not in left_out])
    header = {key: value for key, value in header.items() if key not in _DERIVED_FIELDS}
    header.update(format_version=FORMAT_VERSION, leaves=list(arrays))
    if left_out:
        header["left_out"] = left_out
    if env_carry is not None:
        carry = _to_host(named_leaves(env_carry, ENV_CARRY))
        arrays.update(carry)
        header["env_carry_leaves"] = list(carry)
    shortened = {name: without_zero_tail(value) for name, value in arrays.items()}
    zero_tail = {name: value.shape[0] for name, value in arrays.items() if shortened[name].shape != value.shape}
    if zero_tail:
        header["zero_tail"] = zero_tail
    arrays = shortened
    header["leaf_sha256"] = {name: _leaf_digest(name, value) for name, value in arrays.items()}
    header["sha256"] = _header_digest(header)
    payload = {f"leaf:{k}": v for k, v in arrays.items()}
    payload["header"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
    writer = np.savez_compressed if compress else np.savez
    # numpy's stub lets **kwds of arrays also fill its `allow_pickle: bool`, so any dict of arrays is refused.
    atomic_write_bytes(Path(path), lambda f: writer(f, **payload))  # type: ignore[arg-type]


def _named_in_checkpoint_folder(path: Path) -> bool:
    """A path found by its name in a run's checkpoints/, where no --checkpoint need have been given."""
    return path.parent.name == CHECKPOINT_FOLDER and bool(CHECKPOINT_NAME.match(path.name) or path.name == BEST_FILE)


def _refuse_not_a_file(path: Path) -> None:
    """A folder, a device or a missing path named as a checkpoint, told apart from a damaged file."""
    if path.is_dir() and _named_in_checkpoint_folder(path):
        raise CanterError(
            f"checkpoint {path} is a folder where a checkpoint file should be; move it out of {path.parent}"
        )
    if path.is_dir():
        raise CanterError(
            f"checkpoint {path} is a folder; {_CHECKPOINT_TAKES} (such as a run folder's checkpoints/ckpt_*.npz)"
        )
    if path.is_symlink() and not path.exists():
        raise CanterError(
            f"checkpoint {path} is a link to a missing file ({os.readlink(path)}); remove the link, or restore "
            f"its target"
        )
    if path.exists() and not path.is_file():  # reading a pipe would wait for a writer that never comes
        fix = f"move it out of {path.parent}" if _named_in_checkpoint_folder(path) else _CHECKPOINT_TAKES
        raise CanterError(f"checkpoint {path} is not a regular file (a device, pipe or socket); {fix}")
    if not path.is_file():
        named = path.suffix != ".npz" and len(path.parts) == 1  # a word, as `last` and `best` are
        raise CanterError(f"checkpoint not found: {path}" + (f"; {_CHECKPOINT_TAKES}" if named else ""))


# Header fields that readers index into as this type, where a header has them; a header written by canter always
# has config, env and global_step, but tests and tools write headers with fewer fields.
_FIELD_TYPES: dict[str, tuple[type, str]] = {
    "config": (str, "text"),
    "env": (dict, "an object"),
    "global_step": (int, "a whole number"),
    "left_out": (list, "a list"),
    "zero_tail": (dict, "an object"),
}


def _checked_header(header: Any, path: Path) -> dict[str, Any]:
    """A parsed header, refused as damaged where it is no JSON object or a field has a type no writer gives it (the
    content hash, kept inside the header, cannot vouch for a header that is not an object)."""
    if not isinstance(header, dict):
        raise DamagedCheckpoint(path, "is corrupt (its header is not a JSON object)")
    for key, (kind, name) in _FIELD_TYPES.items():
        value = header.get(key)
        if key in header and (not isinstance(value, kind) or isinstance(value, bool)):
            raise DamagedCheckpoint(path, f"is corrupt (its header's {key} is not {name})")
    return header


def _refuse_a_renamed_checkpoint(header: dict[str, Any], path: Path) -> None:
    """A run's periodic checkpoints are found and ordered by the step in their names, so one whose name says
    another step than it holds would be resumed as the newest (or pruned as the oldest) in the wrong place."""
    named = CHECKPOINT_NAME.match(path.name)
    step = header.get("global_step")
    if path.parent.name != CHECKPOINT_FOLDER or not named or not isinstance(step, int) or int(named[1]) == step:
        return
    raise CanterError(
        f"checkpoint {path} holds step {step}, not the step {int(named[1])} its name says (renamed or copied over?); "
        f"rename it to ckpt_{step:012d}.npz, or move it out of {path.parent}"
    )


def config_text(header: dict[str, Any], path: Path) -> str:
    """The config TOML that a checkpoint's header holds; a DamagedCheckpoint where it holds none."""
    text = header.get("config")
    if not isinstance(text, str):
        raise DamagedCheckpoint(Path(path), "is corrupt (its header holds no config)")
    return text


def read_header(path: Path) -> dict[str, Any]:
    """The header alone, unverified (the arrays are not read); a one-line CanterError for an unreadable file."""
    _refuse_not_a_file(Path(path))
    try:
        with np.load(path, allow_pickle=False) as data:
            header = json_value(bytes(data["header"]).decode())
    except PermissionError:
        raise  # a file this user may not read is not damaged; the CLI says so in one line
    except (zipfile.BadZipFile, ValueError, KeyError, OSError, EOFError, json.JSONDecodeError, UnicodeDecodeError):
        raise DamagedCheckpoint(Path(path), "is corrupt or truncated") from None
    return _checked_header(header, Path(path))


def read(path: Path, wanted: Callable[[str], bool] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Arrays and header of a checkpoint, verified; a one-line CanterError if it is not a sound canter checkpoint.
    `wanted` picks the arrays to return by name (all by default): only those are read and checked, where the file
    hashes each array on its own (an older file is still read and checked whole)."""
    path = Path(path)
    _refuse_not_a_file(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            header = _checked_header(json_value(bytes(data["header"]).decode()), path)
            version = header.get("format_version")
            if version not in READABLE_VERSIONS:
                raise CanterError(
                    f"checkpoint {path} has format version {version}, this canter reads versions "
                    f"{', '.join(map(str, READABLE_VERSIONS))}; use the canter release that wrote it"
                )
            names = [k[5:] for k in data.files if k.startswith("leaf:")]
            whole = version in WHOLE_FILE_HASH_VERSIONS
            tails = _zero_tail_rows(header, path)
            arrays, padded = {}, {}  # as the file holds them (for their hashes), and given back their zero rows
            for name in names:
                if whole or wanted is None or wanted(name):
                    if name in tails:
                        padded[name], arrays[name] = _read_into_rows(data, f"leaf:{name}", tails[name], path)
                    else:
                        arrays[name] = data[f"leaf:{name}"]
    except (PermissionError, CanterError):
        raise  # a file this user may not read is not damaged; the CLI says so in one line
    except (zipfile.BadZipFile, ValueError, KeyError, OSError, EOFError, json.JSONDecodeError, UnicodeDecodeError):
        raise DamagedCheckpoint(path, "is corrupt or truncated") from None
    expected = header.pop("sha256", None)
    sound = expected == _digest(arrays, header) if whole else _header_and_arrays_sound(header, expected, names, arrays)
    header["sha256"] = expected
    if not sound:
        raise DamagedCheckpoint(path, "fails its content hash (corrupt)")
    arrays.update(padded)
    if whole and wanted is not None:
        arrays = {name: value for name, value in arrays.items() if wanted(name)}
    return arrays, header


def _zero_tail_rows(header: dict[str, Any], path: Path) -> dict[str, int]:
    """The whole row count of each array written without its trailing zero rows (the header's `zero_tail`)."""
    rows = header.get("zero_tail", {})
    for name, count in rows.items():
        if not isinstance(count, int) or isinstance(count, bool) or count < 0:
            raise DamagedCheckpoint(path, f"is corrupt (its header gives '{name}' {count!r} rows)")
    return rows


_READ_BYTES = 1 << 22  # read per step into an array given back its zero rows
# The .npy versions savez writes: 2.0 only for a header over 64 KiB; 3.0 only for unicode field names, which no
# canter array has.
_NPY_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


def _read_into_rows(data: Any, key: str, rows: int, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The array `key` of an open .npz, read straight into one of `rows` rows whose rows after the file's are zero,
    and the view of the rows the file holds. A buffer of gigabytes nearly full is thus held once, not twice."""
    with data.zip.open(f"{key}.npy") as f:
        header_of = _NPY_HEADER_READERS.get(np.lib.format.read_magic(f))
        if header_of is None:
            raise DamagedCheckpoint(path, f"is corrupt ('{key[5:]}' is in an .npy version numpy's savez never writes)")
        shape, fortran_order, dtype = header_of(f)
        if fortran_order or dtype.hasobject or not shape or rows < shape[0]:
            raise DamagedCheckpoint(path, f"is corrupt (its header gives '{key[5:]}' {rows} rows)")
        whole = np.zeros((rows, *shape[1:]), dtype)
        stored = whole[: shape[0]]
        target = stored.reshape(-1).view(np.uint8)
        done = 0
        while done < target.size:
            chunk = f.read(min(_READ_BYTES, target.size - done))
            if not chunk:
                raise EOFError
            target[done : done + len(chunk)] = np.frombuffer(chunk, np.uint8)
            done += len(chunk)
    return whole, stored


def _header_and_arrays_sound(
    header: dict[str, Any], expected: Any, names: list[str], arrays: dict[str, np.ndarray]
) -> bool:
    """Whether a header matches its hash, the file holds the arrays its header lists, and those read match theirs."""
    digests = header.get("leaf_sha256")
    return (
        expected == _header_digest(header)
        and isinstance(digests, dict)
        and sorted(names) == sorted(digests)
        and all(digests[name] == _leaf_digest(name, value) for name, value in arrays.items())
    )


def restore(
    template: Any, arrays: dict[str, np.ndarray], source: Path, prefix: str = "", left_out: Sequence[str] = ()
) -> Any:
    """Fill a template pytree (same structure; arrays, or jax.ShapeDtypeStruct leaves) with the saved arrays named
    `prefix` + its leaf paths, checking names, shapes and dtypes. Leaves the checkpoint left out (its header's
    `left_out`, passed here) come back as zeros."""
    leaves, treedef = jax.tree_util.tree_flatten_with_path(template)
    restored = []
    for p, leaf in leaves:
        name = prefix + _path_name(p)
        if name not in arrays and name in left_out:
            restored.append(np.zeros(leaf.shape, leaf.dtype))
            continue
        if name not in arrays:
            raise CanterError(f"checkpoint {source} does not match this config (missing '{name}')")
        value = arrays[name]
        if value.shape != leaf.shape or value.dtype != leaf.dtype:
            raise CanterError(
                f"checkpoint {source} does not match this config ('{name}' is {value.dtype} {value.shape}, "
                f"expected {leaf.dtype} {leaf.shape})"
            )
        restored.append(value)
    return jax.tree_util.tree_unflatten(treedef, restored)


def restore_env_carry(fresh: Any, path: Path) -> Any:
    """The episodes in flight saved in checkpoint `path`, in the structure of `fresh` (a new env's carry); `fresh`
    itself when the checkpoint holds none (it was written by a backend that restarts its episodes)."""
    arrays, header = read(path, wanted=lambda name: name.startswith(ENV_CARRY))
    if not header.get("env_carry_leaves"):
        return fresh
    return restore(fresh, arrays, path, ENV_CARRY)


def need_run_folder(run_dir: Path) -> None:
    """A one-line refusal of a path that is not a run folder, whichever checkpoint is asked of it. A checkpoint file
    names its checkpoint, not its run; a folder with checkpoints but no config.toml is still one, as each checkpoint
    holds the config."""
    if run_dir.is_file():
        if run_dir.suffix != ".npz":
            raise CanterError(f"{run_dir} is a file, not a run folder; pass the folder that holds it")
        raise CanterError(
            f"{run_dir} is a file, not a run folder; pass the run folder, and --checkpoint {run_dir} (checkpoint= "
            f"from Python) to pick this checkpoint"
        )
    if not run_dir.is_dir():
        raise CanterError(f"run folder not found: {run_dir}")
    held = run_files_in(run_dir)
    if held & {CONFIG_FILE, CHECKPOINT_FOLDER}:
        return
    if held:  # a run's metrics or summary, left where its config and checkpoints were lost: no question of a run
        raise CanterError(
            f"{run_dir} has {', '.join(sorted(held))} but no {CONFIG_FILE} and no checkpoint: the run folder is "
            f"damaged; restore its {CONFIG_FILE} and {CHECKPOINT_FOLDER}/ from a copy"
        )
    refuse_a_folder_of_runs(run_dir)
    if run_dir.name == CHECKPOINT_FOLDER and run_files_in(run_dir.parent) & {CONFIG_FILE, CHECKPOINT_FOLDER}:
        raise CanterError(
            f"{run_dir} is a run's {CHECKPOINT_FOLDER}/ folder, not the run folder; pass {run_dir.parent}, and "
            f"--checkpoint FILE (checkpoint= from Python) to pick one of its checkpoints"
        )
    raise CanterError(f"{run_dir} has no {CONFIG_FILE} and no checkpoint; is it a canter run folder?")


def _need_checkpoint_folder(run_dir: Path) -> None:
    """A run's checkpoints/ that is a file (or a link to one) would read as a run with no checkpoint yet."""
    folder = checkpoint_dir(run_dir)
    if (folder.exists() or folder.is_symlink()) and not folder.is_dir():
        raise CanterError(
            f"{folder} is not a folder, where a run keeps its checkpoints; move it away, or restore the run's "
            f"checkpoints/ folder from a copy"
        )


def latest(run_dir: Path) -> Path:
    run_dir = Path(run_dir)
    need_run_folder(run_dir)
    _need_checkpoint_folder(run_dir)
    found = list_checkpoints(run_dir)
    _note_foreign_files(run_dir)
    if not found and finished_without_checkpoints(run_dir):
        # A best.npz kept with the archive is still a policy to play, though none to train on.
        best = f"; {_best_instead(not _config_fault(run_dir, new=False))}" if _sound_header(best_path(run_dir)) else ""
        raise CanterError(
            f"{run_dir} holds a finished run without its checkpoints (an archive?): it has no policy to load or "
            f"train on; plot reads its metrics, as report does with --episodes 0, and a new run trains it again{best}"
        )
    if not found and (fault := _config_fault(run_dir, new=False)):  # no resume can start it again
        best = f"; {_best_instead(False)}" if _sound_header(best_path(run_dir)) else ""
        raise CanterError(
            f"no checkpoint in {run_dir} and {fault}, so the run cannot be trained again from its folder: restore "
            f"{CONFIG_FILE} or its checkpoints from a copy, or {_NEW_RUN_WITH_ITS_SETTINGS}{best}"
        )
    if not found:
        raise CanterError(
            f"no checkpoint in {run_dir} yet: a run writes its first after run.checkpoint_every steps, and "
            f"{resume_run(run_dir)} trains one stopped before that again from step 0; or pass the run folder that "
            f"holds checkpoints/ckpt_*.npz"
        )
    return found[-1]


def refuse_a_folder_of_runs(folder: Path) -> None:
    """A one-line refusal of a folder that holds run folders (a bench's) where one run folder was asked for."""
    inside = runs_inside(folder)
    if inside:
        runs = f"{len(inside)} run folder{'s' if len(inside) > 1 else ''}"
        raise CanterError(f"{folder} is not a run folder but holds {runs} (a bench's?): pass them, such as {inside[0]}")


def runs_inside(folder: Path) -> list[Path]:
    """The run folders directly inside a folder that is no run folder itself (a bench's), sorted; [] otherwise, and
    where the folder cannot be read."""
    folder = Path(folder)
    try:
        if (folder / CONFIG_FILE).is_file():
            return []
        return sorted(child for child in folder.iterdir() if child.is_dir() and (child / CONFIG_FILE).is_file())
    except OSError:  # a folder or child this user may not search: not the question asked
        return []


_NOTED: set[Path] = set()


def _note_foreign_files(run_dir: Path) -> None:
    """A file in checkpoints/ that canter does not write is skipped, with a one-line notice (once per process)."""
    folder = checkpoint_dir(run_dir)
    if not folder.is_dir():
        return
    for path in sorted(folder.iterdir()):
        hidden = path.name.startswith(".")  # a temp file of a write, removed by the next writer
        if hidden or CHECKPOINT_NAME.match(path.name) or path.name == BEST_FILE or path in _NOTED:
            continue
        _NOTED.add(path)
        print(f"canter: note: skipping {path}: not a checkpoint name canter writes (ckpt_<step>.npz)", file=sys.stderr)


def best_path(run_dir: Path) -> Path:
    return checkpoint_dir(run_dir) / BEST_FILE


def kept_best_path(run_dir: Path) -> Path:
    return checkpoint_dir(run_dir) / KEPT_BEST_FILE


def resolve(run_dir: Path, which: str | Path = LAST) -> Path:
    """The checkpoint file that `which` names for a run folder: `last` (the newest), `best` (the best evaluated
    state) or a checkpoint file (any path; a `Path` is always a file)."""
    run_dir = Path(run_dir)
    if not isinstance(which, str | Path):
        raise CanterError(f"checkpoint must be {LAST!r}, {BEST!r} or a checkpoint file's path, got {which!r}")
    if isinstance(which, str) and not which.strip():  # Path("") is ".", which would be refused as a folder
        raise CanterError(
            f"the checkpoint given is an empty path; pass {LAST}, {BEST} or a checkpoint file (--checkpoint, "
            f"checkpoint= from Python)"
        )
    if which == LAST:
        return latest(run_dir)
    need_run_folder(run_dir)
    if which != BEST:  # a file: a `Path` never equals a name
        path = Path(which)
        # A name read from the run's listing, or a path read from inside the run folder: both are read from the
        # working directory.
        meant = [checkpoint_dir(run_dir) / path.name] if len(path.parts) == 1 else []
        meant += [run_dir / path] if not path.is_absolute() else []
        inside = next((candidate for candidate in meant if candidate.is_file()), None)
        if not path.exists() and inside is not None:
            raise CanterError(f"checkpoint not found: {path}; the run's own is {inside}: pass that path")
        return path
    _need_checkpoint_folder(run_dir)
    path = best_path(run_dir)
    if path.exists() or path.is_symlink():
        _refuse_not_a_file(path)  # a folder or a broken link with its name is no sign that the run never evaluated
    if not path.is_file() and _evaluates_during_training(run_dir):
        raise CanterError(
            f"{run_dir} has no best checkpoint: {path} is missing, though the run evaluates during training "
            f"(run.eval_every): deleted, or the run stopped before its first evaluation; {_LAST_INSTEAD_OF_BEST}, "
            f"or pass a checkpoint file"
        )
    if not path.is_file():
        raise CanterError(
            f"{run_dir} has no best checkpoint: it never evaluated during training (train with --eval-every N, "
            f"run.eval_every); use the last checkpoint (--checkpoint last, checkpoint='last') or a checkpoint file"
        )
    return path


_LAST_INSTEAD_OF_BEST = with_python(f"drop --checkpoint {BEST} to use the last checkpoint", f"checkpoint={LAST!r}")


def _evaluates_during_training(run_dir: Path) -> bool:
    """Whether the run's config.toml sets run.eval_every, so that a missing best.npz is no sign that it never
    evaluated; False where config.toml does not read (nothing then says that it did)."""
    try:
        return read_config(run_dir).run.eval_every > 0
    except (CanterError, OSError):
        return False


def resolve_own(run_dir: Path, which: str | Path = LAST) -> Path:
    """`resolve`, then the checkpoint's header read and matched to the run folder as loading it does: a missing
    file, or one of another run, is refused where nothing loads it (a report without an evaluation), as results
    would be labelled with a run that never made them."""
    path = resolve(run_dir, which)
    header = read_header(path)
    check_of_run(Path(run_dir), from_toml_text(config_text(header, path), str(path)), path, header)
    return path


def check_of_run(run_dir: Path, config: Config, path: Path, header: dict[str, Any]) -> None:
    """A checkpoint in the run folder's checkpoints/ must be the run's own, under the name of its step; a file given
    from elsewhere must be one of that run's, kept there."""
    if path.resolve().parent == checkpoint_dir(run_dir).resolve():
        check_own_checkpoint(run_dir, config, path)
        _refuse_a_renamed_checkpoint(header, path)
    else:
        check_given_checkpoint(run_dir, config, path)


def prune(run_dir: Path, keep: int) -> None:
    """Delete all but the newest `keep` ckpt_<step>.npz files (never best.npz)."""
    for old in list_checkpoints(run_dir)[:-keep]:
        old.unlink(missing_ok=True)
