"""Video files written atomically: frames go to a temp file beside the output, renamed into place once complete,
and readers of a videos/ folder tell such a temp file from a finished video."""

from __future__ import annotations

import contextlib
import itertools
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from canter.errors import CanterError
from canter.files import OUTPUT_FILE_MODE, remove_orphaned_temps, temp_prefix


class _GifWriter:
    """GIF frames held in memory (Pillow holds them until the end anyway) and encoded at close in one write, so
    that a failed write raises there, once, rather than again from a finalizer."""

    def __init__(self, path: Path, fps: int) -> None:
        self.path, self.fps = path, fps
        self.frames: list[np.ndarray] = []

    def append_data(self, frame: np.ndarray) -> None:
        self.frames.append(frame)

    def close(self) -> None:
        import imageio.v3 as iio

        frames, self.frames = self.frames, []
        if frames:
            delays = gif_frame_delays_ms(len(frames), self.fps)
            data = iio.imwrite("<bytes>", np.stack(frames), extension=".gif", duration=delays, loop=0)
            self.path.write_bytes(data)


def gif_frame_delays_ms(frames: int, fps: int) -> list[int]:
    """Each frame's delay, in whole hundredths of a second as a GIF stores them, written in milliseconds: frame i
    ends at floor(100 (i+1) / fps) hundredths, so the video lasts frames / fps to the hundredth. One delay of
    1000 / fps would be cut to whole hundredths for every frame, playing 30 fps at 33.3."""
    ends = [100 * i // fps for i in range(frames + 1)]
    return [10 * (end - start) for start, end in itertools.pairwise(ends)]


_TEMP_MARK = ".tmp"  # ends the stem of every temp video (`AtomicVideo`): what `is_unfinished_video` looks for


def is_unfinished_video(path: Path) -> bool:
    """Whether `path` is the temp file of a video (`.NAME.<machine>-<pid>-<random>.tmp.mp4` beside NAME.mp4): one
    still being rendered, or left by a renderer that was killed. Readers of a videos/ folder skip these."""
    name = Path(path).name
    return name.startswith(".") and Path(Path(name).stem).suffix == _TEMP_MARK


class AtomicVideo:
    """Frames go to a temp file beside the output, renamed into place only once the video is complete."""

    def __init__(self, out: Path, fps: int) -> None:
        import imageio.v2 as imageio

        suffix = out.suffix.lower()
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            remove_orphaned_temps(out.parent, out.stem)
            fd, name = tempfile.mkstemp(prefix=temp_prefix(out.stem), suffix=f"{_TEMP_MARK}{suffix}", dir=out.parent)
            os.close(fd)
        except OSError as exc:
            raise CanterError(f"cannot write {out}: {exc.strerror or exc}; pick a writable path") from None
        self.out, self.tmp, self.frames = out, Path(name), 0
        self.writer: Any
        try:
            if suffix == ".gif":
                self.writer = _GifWriter(self.tmp, fps)
            else:
                self.writer = imageio.get_writer(
                    self.tmp,
                    format="FFMPEG",
                    mode="I",
                    fps=fps,
                    codec="libx264",
                    pixelformat="yuv420p",
                    macro_block_size=1,
                    quality=7,
                    ffmpeg_log_level="fatal",  # a failed write is reported by commit() as one line
                )
        except BaseException:  # an error, or a second Ctrl-C, before the caller has a writer to abort
            self.tmp.unlink(missing_ok=True)
            raise

    def append(self, frame: np.ndarray) -> None:
        try:
            self.writer.append_data(np.ascontiguousarray(frame[..., :3], dtype=np.uint8))
        except OSError as exc:  # the encoder died, or (GIF) the write failed
            raise self._write_error(exc) from None
        self.frames += 1

    def _write_error(self, exc: OSError | None) -> CanterError:
        from canter.files import WriteError, is_write_error

        if exc is not None and is_write_error(exc):
            return WriteError(self.out, exc)
        # ffmpeg reports a failed write (a full disk) only on its stderr and exit status, which imageio drops.
        return CanterError(
            f"cannot write {self.out}: the video encoder could not finish the file (is {self.out.parent} full?); "
            f"free space in {self.out.parent}, then run the command again"
        )

    def commit(self) -> None:
        try:
            self.writer.close()
            if self.tmp.suffix.endswith(".mp4"):
                import imageio_ffmpeg

                imageio_ffmpeg.count_frames_and_secs(str(self.tmp))  # fails on a file ffmpeg could not finish
        except (OSError, RuntimeError) as exc:
            raise self._write_error(exc if isinstance(exc, OSError) else None) from None
        os.chmod(self.tmp, OUTPUT_FILE_MODE)  # mkstemp's 0600 is for the temp file, not the video
        os.replace(self.tmp, self.out)

    def abort(self) -> None:
        try:
            with contextlib.suppress(Exception):  # the temp file goes either way
                self.writer.close()
        finally:  # also when a second Ctrl-C cuts the close short
            self.tmp.unlink(missing_ok=True)
