"""SIGINT, SIGTERM and SIGHUP, the signals that stop a canter command: handlers set for a stretch of work and put back
after, and a stop held back until the work is in a safe state, then passed on to the handling it would have had."""

from __future__ import annotations

import contextlib
import logging
import os
import select
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Any, NoReturn

# SIGHUP too: a dropped ssh session or a closed terminal stops a run as a scheduler's SIGTERM does, with a checkpoint.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
INTERRUPTED = 130  # the shell's code for a process ended by SIGINT
# The exit code of a command whose stdout nobody reads any more (`canter eval RUN | head -1`, a terminal that hung
# up): it ends quietly with 1, as in Python's own recipe (https://docs.python.org/3/library/signal.html#note-on-sigpipe)
# and rich's.
STDOUT_CLOSED = 1


def ignore_stop_signals() -> None:
    """From here on a further Ctrl-C, SIGTERM or SIGHUP is ignored: the process is already ending, and one landing in
    its last lines would end it by a traceback instead (a user presses Ctrl-C again and again)."""
    if threading.current_thread() is threading.main_thread():
        for sig in STOP_SIGNALS:
            signal.signal(sig, signal.SIG_IGN)


def interrupt_once() -> None:
    """For a command's process: the first SIGINT that reaches Python raises KeyboardInterrupt, as Python's own handler
    does, and stops further ones at that moment (`ignore_stop_signals`), with no gap in which one more could land
    while the process ends. A process started with SIGINT ignored keeps it ignored."""
    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGINT) is (
        signal.default_int_handler
    ):
        signal.signal(signal.SIGINT, _interrupt_and_ignore_the_rest)


def _interrupt_and_ignore_the_rest(signum: int, frame: FrameType | None) -> None:
    ignore_stop_signals()
    raise KeyboardInterrupt


def end_of_interrupts() -> None:
    """In a command's process (`interrupt_once`), once a KeyboardInterrupt ends its command: further stops are
    ignored. A StopFlag raises one for a second Ctrl-C and then puts back the handler before it, so a third one,
    between the command's end and the process's, would raise again where nothing catches it, and the interpreter's
    shutdown after an interrupted compile can crash. A process that did not take that handler (pytest, a script
    calling canter) keeps its own."""
    if signal.getsignal(signal.SIGINT) is _interrupt_and_ignore_the_rest:
        ignore_stop_signals()


def exit_interrupted() -> NoReturn:
    """End an interrupted process with INTERRUPTED, skipping the interpreter's shutdown. A Ctrl-C can land inside
    native code (an XLA compile, an env pool's threads) and leave it in a state that crashes that shutdown with a
    segfault (exit -11 instead of 130). Every file canter writes was closed as the interrupt unwound; only logging and
    the standard streams are flushed here."""
    ignore_stop_signals()
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(INTERRUPTED)


def die_with_parent(sig: int, parent: int | None = None) -> None:
    """Ask Linux to send this process `sig` when its parent dies (elsewhere nothing changes). A parent that died
    before the request took hold never sends it, so the process gets `sig` at once when its parent id is not
    `parent` (where the caller knows it) or, without one, is init's."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    pr_set_pdeathsig = 1
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, sig)
    orphaned = os.getppid() == 1 if parent is None else os.getppid() != parent
    if orphaned:
        os.kill(os.getpid(), sig)


@contextlib.contextmanager
def handling_stop_signals(handler: Callable[[int, FrameType | None], Any]) -> Iterator[dict[signal.Signals, Any]]:
    """Within it, `handler` handles SIGINT, SIGTERM and SIGHUP; yields the handlers it replaced, by signal, put back at
    the end (but for those the caller takes out of it). A signal the process ignores stays ignored: a shell starts a
    background job (`cmd &` in a script) with SIGINT ignored so that a Ctrl-C meant for the foreground leaves it
    running, as Python itself does then, and `nohup` starts its command with SIGHUP ignored. So does a handler that
    was not set from Python, which could not be put back. Outside the main thread, where Python cannot set handlers,
    nothing changes."""
    replaced: dict[signal.Signals, Any] = {}
    if threading.current_thread() is threading.main_thread():
        for sig in STOP_SIGNALS:
            if signal.getsignal(sig) not in (signal.SIG_IGN, None):
                replaced[sig] = signal.signal(sig, handler)
    try:
        yield replaced
    finally:
        for sig, earlier in replaced.items():
            signal.signal(sig, earlier)


_stops_held = 0  # how many signals every StopFlag of this process has held, for work made of several such stretches


def stops_held() -> int:
    """How many stop signals StopFlags have held in this process so far: work that runs several stretches, each in
    its own StopFlag, compares it before and after to learn of a stop that one of them took in (even one that came
    after the stretch's last check)."""
    return _stops_held


def _write_stderr(text: str) -> None:
    """Write to the process's stderr from a signal handler: os.write, not print, as the handler may have cut into a
    print and a buffered stream refuses re-entry; nothing, where stderr is no file (a StringIO) or a closed pipe."""
    # io.UnsupportedOperation (no fileno) is both an OSError and a ValueError; a closed pipe is an OSError.
    with contextlib.suppress(OSError, ValueError, AttributeError):
        os.write(sys.stderr.fileno(), text.encode())


# Within `stops_dropped_after_the_work`: the handlers that StopFlags ending there left to it, by signal, rather than
# putting them back; its end puts them back.
_after_the_work: dict[signal.Signals, Any] | None = None


def _drop(signum: int, frame: FrameType | None) -> None:
    """A stop signal once the work is saved: the command ends as it would have without it."""


@contextlib.contextmanager
def stops_dropped_after_the_work() -> Iterator[None]:
    """For a command whose work is a StopFlag's stretch (`canter train`: the run is saved and summarized when its
    StopFlag ends): a stop signal from the end of that stretch to the end of this context is dropped, as what is left
    only closes the work, and a finished run must not end as a killed (143) or interrupted (130) one. The StopFlag
    leaves its handlers to this context rather than put them back (with no moment between in which a signal finds
    the handlers from before it), and the end of this context puts them back."""
    global _after_the_work
    _after_the_work = {}
    try:
        yield
    finally:
        handed_over, _after_the_work = _after_the_work, None
        for sig, earlier in handed_over.items():
            signal.signal(sig, earlier)


def _hand_over(replaced: dict[signal.Signals, Any], kept: dict[signal.Signals, Any]) -> None:
    """Drop the stop signals that `replaced` names, keeping in `kept` the handlers from before the first StopFlag that
    handed them over; `replaced` is emptied, so that its StopFlag puts back none of them."""
    for sig, earlier in replaced.items():
        signal.signal(sig, _drop)
        kept.setdefault(sig, earlier)
    replaced.clear()


class StopFlag:
    """A context in which SIGINT, SIGTERM and SIGHUP (those `handling_stop_signals` handles) set `signal`, for work
    that stops at its next safe point: an exception raised in a handler is lost when the signal lands in a
    garbage-collection callback (JAX has one). A second Ctrl-C meanwhile means now: it raises KeyboardInterrupt. Its
    end puts back the handlers from before it; inside `stops_dropped_after_the_work`, an end without an exception
    leaves them to that context instead.

    `notice`, where given, is printed to stderr when the first signal lands: the next safe point can be many seconds
    away (the end of an XLA compile), and a stop that says nothing until then looks ignored. The work may change it
    once it knows how far apart its safe points are."""

    def __init__(self, notice: str | None = None) -> None:
        self.signal: int | None = None
        self.notice = notice
        self._handling = contextlib.ExitStack()
        self._replaced: dict[signal.Signals, Any] = {}

    def __enter__(self) -> StopFlag:
        self._replaced = self._handling.enter_context(handling_stop_signals(self._handle))
        return self

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        global _stops_held
        if self.signal is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        first = self.signal is None
        self.signal = signum  # before the notice: a notice that cannot be written must not lose the stop
        _stops_held += 1
        if first and self.notice:
            again = "; Ctrl-C again stops at once" if signum == signal.SIGINT else ""
            _write_stderr(f"canter: {signal.Signals(signum).name}: {self.notice}{again}\n")

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is None and _after_the_work is not None:
            _hand_over(self._replaced, _after_the_work)
        self._handling.close()

    def deliver(self) -> None:
        """Once the context is left: the signal it held back, if any, acts now as it would have when it came. The
        handler from before runs (Python's own raises KeyboardInterrupt for SIGINT) and, if it returns, so does this;
        where there was none, the default action ends the process by the signal (143 in a shell for SIGTERM)."""
        if self.signal is not None:
            signal.raise_signal(self.signal)


def stdout_is_gone() -> bool:
    """Whether nothing can read stdout any more: poll reports an error on a pipe whose reader is gone and on a
    terminal that hung up. Where poll cannot tell (no poll on Windows, no stdout file), it is not."""
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & (select.POLLERR | select.POLLHUP) for _, events in poller.poll(0))
    except (AttributeError, OSError, ValueError):
        return False


def end_quietly_without_stdout() -> int:
    """STDOUT_CLOSED, with stdout pointed at /dev/null: the interpreter's shutdown flushes what is still buffered for
    it, which would fail again and print an error of its own."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return STDOUT_CLOSED
