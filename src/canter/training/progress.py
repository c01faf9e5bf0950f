"""The progress bar of a training run in a terminal."""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rich.console import Console


class Progress:
    """A rich progress bar with steps, SPS, ETA and the recent mean return; a no-op when quiet."""

    def __init__(self, total: int, start: int, quiet: bool, description: str) -> None:
        self._bar = None
        if quiet:
            return
        from rich.progress import BarColumn, TextColumn, TimeRemainingColumn
        from rich.progress import Progress as RichProgress

        self._total = total
        self._bar = RichProgress(
            TextColumn("[bold]{task.description}"),
            BarColumn(bar_width=24),
            TextColumn("{task.fields[steps]}"),
            TextColumn("{task.fields[sps]} SPS"),
            TextColumn("ret {task.fields[ret]}"),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            transient=False,
            console=_console_that_outlives_stdout(),
        )
        self._bar.start()
        self._task = self._bar.add_task(
            description, total=total, completed=start, steps=self._steps(start), sps="-", ret="-"
        )

    def _steps(self, step: int) -> str:
        def short(n: float) -> str:
            if n >= 1e6:
                return f"{n / 1e6:.2f}M"
            return f"{n / 1e3:.0f}k" if n >= 1e4 else f"{n:,.0f}"

        return f"{short(step)}/{short(self._total)}"

    def update(self, step: int, sps: float, recent_return: float | None) -> None:
        if self._bar is None:
            return
        ret = "-" if recent_return is None else f"{recent_return:.1f}"
        self._bar.update(self._task, completed=step, steps=self._steps(step), sps=f"{sps:,.0f}", ret=ret)

    def close(self) -> None:
        if self._bar is not None:
            # A terminal that hung up (a dropped ssh session, which also stops the run) fails the last draw with EIO:
            # it costs only the bar, as a closed pipe does (`_console_that_outlives_stdout`).
            with contextlib.suppress(OSError):
                self._bar.stop()


def _console_that_outlives_stdout() -> Console:
    """A rich console that stops drawing once stdout is closed (`canter train ... | head`), where rich's own exits
    the process (SystemExit(1)) from whatever draws: the bar is only shown, and the run it shows goes on, closes its
    files and returns its result. A command then ends as `canter.cli.main` ends one whose stdout is closed."""
    from rich.console import Console

    class QuietOnceStdoutCloses(Console):
        def on_broken_pipe(self) -> None:
            self.quiet = True

    return QuietOnceStdoutCloses()
