"""SIGTERM stops the project's long commands as Ctrl-C does, and is not lost on the way.

A job manager or a container's shutdown sends SIGTERM, not Ctrl-C. Within `sigterm_interrupts`
SIGTERM raises `Terminated`, a KeyboardInterrupt, in the main thread, so every
``except KeyboardInterrupt`` that keeps what finished (the rig loop's log, the fit's last
values, the leaderboard's and the benchmark's finished rows) serves both.

Python drops an exception raised by a signal handler that runs inside a ``__del__`` (it prints
"Exception ignored in ..." and carries on): a SIGTERM that lands while numba frees a compiled
object would be lost and the command would run on. The block yields a `SignalRecord`; a loop
calls its `raise_if_lost` once per iteration, which raises such a stop again.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread (it stops a command as Ctrl-C does)."""


class SignalRecord(threading.Event):
    """Set when a stopping signal came, remembering the exception its handler raised."""

    def __init__(self) -> None:
        super().__init__()
        self.stop: BaseException | None = None

    def lost(self) -> bool:
        """A stop was raised and the code asking is still running: it was lost on the way
        (the one who asks runs only while the block goes on)."""
        return self.is_set() and self.stop is not None

    def raise_if_lost(self) -> None:
        """Raise the stop again (a new exception of its type: the first one carries the
        traceback of where it was dropped) if it was lost."""
        if self.lost():
            assert self.stop is not None
            raise type(self.stop)(*self.stop.args)


@contextmanager
def sigterm_interrupts() -> Iterator[SignalRecord]:
    """Within the block SIGTERM raises `Terminated`; the previous handler comes back after.
    Off the main thread (where Python cannot set handlers) the block changes nothing."""
    record = SignalRecord()
    if threading.current_thread() is not threading.main_thread():
        yield record
        return

    def on_term(signum: int, frame: Any) -> None:
        record.stop = record.stop or Terminated("SIGTERM")
        record.set()
        raise Terminated("SIGTERM")

    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        yield record
    finally:   # None: a handler not set from Python; the default then
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


__all__ = ["SignalRecord", "Terminated", "sigterm_interrupts"]
