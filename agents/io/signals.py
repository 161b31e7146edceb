"""SIGTERM as Ctrl-C: schedulers and ``docker stop`` end a command the way Ctrl-C does, so it
stops, saves and reports (docs/design.md §7).

Inside :func:`sigterm_as_interrupt` SIGTERM raises :class:`Terminated`, a
``KeyboardInterrupt``; inside :func:`sigterm_as_request` it only sets an event that a loop
polls; :func:`signals_deferred` holds both signals while a run folder is being completed.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread as Ctrl-C raises ``KeyboardInterrupt``: every
    ``except KeyboardInterrupt`` that saves partial work saves it on SIGTERM too.

    Attributes:
        run_dir: The run folder a training saved before passing this on (or ``None``).
    """

    def __init__(self, run_dir: Path | None = None) -> None:
        super().__init__("terminated (SIGTERM)")
        self.run_dir = run_dir


_sigterm = threading.Event()


def _raise_terminated(signum: int, frame: Any) -> None:
    _sigterm.set()
    raise Terminated()


def sigterm_received() -> bool:
    """Whether a SIGTERM arrived inside the latest :func:`sigterm_as_interrupt` block (or a
    :func:`sigterm_as_request` block inside it)."""
    return _sigterm.is_set()


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Inside the block, SIGTERM raises :class:`Terminated` (a ``KeyboardInterrupt``).

    An ignored SIGTERM (inherited ``SIG_IGN``) stays ignored; outside the main thread
    nothing changes (signals are delivered to the main thread only).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _sigterm.clear()  # one command per block: an earlier SIGTERM (in a test) is not this one's
    previous = signal.getsignal(signal.SIGTERM)
    if previous is signal.SIG_IGN:
        yield
        return
    signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextlib.contextmanager
def sigterm_as_request() -> Iterator[threading.Event]:
    """Inside the block, SIGTERM only sets the event it yields: the code polls it and stops
    where it chooses (a training between two steps, a study between two waits).

    Why: an exception raised by the handler can surface anywhere in a library's loop, e.g.
    between taking a lock and the ``with`` that would release it (in SB3's logging, in
    ``concurrent.futures``), and the save that follows then waits for that lock for ever.
    :func:`sigterm_received` reports the SIGTERM as usual. An ignored SIGTERM stays ignored;
    outside the main thread nothing changes (the event is then never set).
    """
    asked = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield asked
        return
    previous = signal.getsignal(signal.SIGTERM)
    if previous is signal.SIG_IGN:
        yield asked
        return

    def request(signum: int, frame: Any) -> None:
        _sigterm.set()
        asked.set()

    signal.signal(signal.SIGTERM, request)
    try:
        yield asked
    finally:
        signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)


@contextlib.contextmanager
def signals_deferred(note: str) -> Iterator[None]:
    """Hold Ctrl-C and SIGTERM while a set of files that belong together is written.

    A Ctrl-C inside the block only prints ``note``; a SIGTERM prints it and is delivered
    again when the block ends (the files are complete by then), so the process still stops.
    Outside the main thread nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []

    def hold(signum: int, frame: Any) -> None:
        print(note, file=sys.stderr)
        if signum == signal.SIGTERM:
            held.append(signum)

    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    for sig, handler in previous.items():
        if handler is not signal.SIG_IGN:
            signal.signal(sig, hold)

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)

    try:
        yield
    except BaseException:
        restore()  # the error ends the work anyway; it is not replaced by the held signal
        raise
    restore()
    if held:
        signal.raise_signal(signal.SIGTERM)
