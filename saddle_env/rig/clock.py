"""Clocks the loop and a simulated rig share: the real one (`time.monotonic`) and a virtual
one for tests, which advances only when somebody sleeps on it, so a run of many seconds
takes as long as its computations and gives the same result every time."""

from __future__ import annotations

import math
import threading
import time
from typing import Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    """What the loop needs of a clock: the time [s] and a sleep until a time on it."""

    def now(self) -> float:
        """The time [s]."""

    def sleep_until(self, t: float) -> None:
        """Return at the time ``t`` [s] (at once if it has passed)."""


class MonotonicClock:
    """Wall-clock time from `time.monotonic` (never jumps backwards)."""

    def now(self) -> float:
        """The time [s]."""
        return time.monotonic()

    def sleep_until(self, t: float) -> None:
        """Sleep until the time ``t`` [s]."""
        wait = t - time.monotonic()
        if wait > 0:
            time.sleep(wait)

    def sleep(self, seconds: float) -> None:
        """Sleep ``seconds`` [s]."""
        time.sleep(max(0.0, seconds))


class VirtualClock:
    """A clock that stands still until `sleep_until` (or `sleep`) moves it: the loop's sleep
    to its next deadline moves time forward at once, and a controller that "computes for
    30 ms" calls ``clock.sleep(0.03)``. Thread-safe; time never goes backwards."""

    def __init__(self, start: float = 0.0):
        if not math.isfinite(start):
            raise ValueError(f"start must be a finite time [s], got {start!r}")
        self._now = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        """The time [s]."""
        with self._lock:
            return self._now

    def sleep_until(self, t: float) -> None:
        """Move the time to ``t`` [s], at once (never backwards)."""
        with self._lock:
            self._now = max(self._now, float(t))

    def sleep(self, seconds: float) -> None:
        """Move the time on by ``seconds`` [s], at once."""
        with self._lock:
            self._now += max(0.0, float(seconds))


__all__ = ["Clock", "MonotonicClock", "VirtualClock"]
