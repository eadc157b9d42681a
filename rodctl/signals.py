"""The one place that swaps the SIGINT / SIGTERM handlers: every stop policy goes through it.

Why one helper: a stop request is honoured at a safe point (between two steps, between two
episodes, after a log message is whole), and each of those places needs the same three rules:
only the main thread can set handlers (elsewhere this is a no-op); a signal the process was
started ignoring (nohup, a background job) stays ignored unless asked otherwise; and the
handlers found are put back afterwards. A handler that was not set from Python (`getsignal`
returns None) is left alone: it could not be put back.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from multiprocessing import resource_tracker
from typing import Any

#: The signals that ask a run to stop.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

Handler = Callable[[int, Any], Any]


def install(
    handler: Handler, signals: tuple[int, ...] = STOP_SIGNALS, *, over_ignored: bool = False
) -> dict[int, Any]:
    """Set `handler` for `signals` (main thread only); the handlers it replaced, by signal.

    Args:
        handler: called as `handler(signum, frame)`.
        signals: which signals (default: SIGINT and SIGTERM).
        over_ignored: replace an ignored signal's SIG_IGN too (default: it stays ignored).
    """
    if threading.current_thread() is not threading.main_thread():
        return {}
    previous: dict[int, Any] = {}
    for sig in signals:
        current = signal.getsignal(sig)
        if current is None or (current is signal.SIG_IGN and not over_ignored):
            continue
        previous[sig] = signal.signal(sig, handler)
    return previous


def restore(previous: dict[int, Any]) -> None:
    """Put back the handlers `install` replaced."""
    for sig, old in previous.items():
        signal.signal(sig, old)


@contextmanager
def handled(
    handler: Handler, signals: tuple[int, ...] = STOP_SIGNALS, *, over_ignored: bool = False
) -> Iterator[dict[int, Any]]:
    """`handler` for `signals` for the duration of the block (see `install`); yields the
    handlers it replaced, which are put back when the block ends."""
    previous = install(handler, signals, over_ignored=over_ignored)
    try:
        yield previous
    finally:
        restore(previous)


def name(signum: int) -> str:
    """The signal's name ("SIGINT", "SIGTERM"): what a run's stop reason says."""
    return signal.Signals(signum).name


@contextmanager
def held_from_children(signals: tuple[int, ...] = (signal.SIGINT,)) -> Iterator[None]:
    """Block `signals` in this thread for the block, so that processes started inside it
    inherit them blocked (a blocked signal stays pending, not lost); the mask is put back after.

    Why: a Ctrl-C at the terminal is sent to every process of its group, the workers included.
    A spawned worker still importing (a second or more) has no handler yet, so the signal
    raises KeyboardInterrupt in whatever it imports and the worker prints a traceback. Started
    with SIGINT blocked, a worker takes it only when it calls `release` after its cooperative
    handler is in place (`executors.base.init_worker`); a worker that never does leaves SIGINT
    to the command, which stops it. This process still takes the signal: the kernel hands a
    process-directed signal to a thread that does not block it (the Python handler runs in the
    main thread whichever thread received it), or, with none, delivers it when the mask is put
    back. No-op without `pthread_sigmask` (Windows).

    The multiprocessing resource tracker is started first: starting it unblocks SIGINT in the
    calling thread (CPython's `resource_tracker.ensure_running` blocks, spawns, then unblocks),
    which would undo the block for every process started after it, as a spawn `Pool` does.
    """
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    resource_tracker.ensure_running()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, signals)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def release(signals: tuple[int, ...] = (signal.SIGINT,)) -> None:
    """Unblock `signals` in this thread (a process started by `held_from_children`, once its
    handler is set): one that arrived meanwhile is delivered now."""
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, signals)
