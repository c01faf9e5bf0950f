"""TensorBoard event files, written by the training thread itself.

tensorboardX's SummaryWriter writes from a thread of its own: a write error there (a full disk) ends that thread
unseen, and the next scalars then wait forever on its full queue. This writer appends each iteration's scalars as
one write (`canter.files.AppendFile`), so a write error reaches the trainer as a one-line error and the file keeps
only whole records, which TensorBoard reads.
"""

from __future__ import annotations

import os
import socket
import struct
import time
from pathlib import Path

from canter.files import AppendFile


def _record(data: bytes) -> bytes:
    """One TFRecord: length, its masked CRC-32C, the data, its masked CRC-32C."""
    from tensorboardX.record_writer import masked_crc32c

    length = struct.pack("Q", len(data))
    return length + struct.pack("I", masked_crc32c(length)) + data + struct.pack("I", masked_crc32c(data))


class EventFile:
    """A new events.out.tfevents.* file in `folder`. A resumed run passes `purge_step`: TensorBoard then hides the
    events at and after that step that earlier files hold (work lost with a killed process)."""

    def __init__(self, folder: Path, purge_step: int | None = None) -> None:
        from tensorboardX.proto.event_pb2 import Event, SessionLog

        folder.mkdir(parents=True, exist_ok=True)
        now = time.time()
        name = f"events.out.tfevents.{int(now)}.{socket.gethostname()}.{os.getpid()}"
        self._file = AppendFile(folder / name)
        events = [Event(wall_time=now, file_version="brain.Event:2")]
        if purge_step is not None:
            events.append(Event(wall_time=now, step=purge_step, session_log=SessionLog(status=SessionLog.START)))
        self._file.append(b"".join(_record(e.SerializeToString()) for e in events))

    def add_scalars(self, step: int, scalars: dict[str, float]) -> None:
        from tensorboardX.proto.event_pb2 import Event
        from tensorboardX.summary import scalar

        now = time.time()
        events = [Event(wall_time=now, step=step, summary=scalar(tag, value)) for tag, value in scalars.items()]
        self._file.append(b"".join(_record(e.SerializeToString()) for e in events))

    def close(self) -> None:
        self._file.close()
