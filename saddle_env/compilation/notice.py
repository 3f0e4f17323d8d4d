"""No silent freeze: say so when numba compiles our code for more than a moment.

The first call of a compiled function after an install or an upgrade compiles it (seconds;
docs/coldstart.md), and nothing else shows that the process is working. numba reports every
compile through its event API (``numba.core.event``, kind ``numba:compile``); a listener
times each outermost compile of saddle_env's or agents' code, and one that is still running
after `NOTICE_AFTER` seconds is announced once, on the ``saddle_env`` logger at WARNING
level (Python prints that on stderr when logging is not configured): what is compiled, and
that the result is cached so it happens once. Its end is logged at INFO with the time taken.
Cache loads are not compiles and say nothing. When the install's ahead-of-time build exists
but cannot run on this CPU, that is said once too, before the first compile
(`announce_no_build`).
"""

from __future__ import annotations

import logging
import threading
import time

logger = logging.getLogger("saddle_env")

NOTICE_AFTER = 2.0  # [s] a compile still running after this is announced
_OURS = ("saddle_env", "agents")
_state = threading.local()  # per thread: nesting depth of our compiles, the pending notice
_installed = False


def _announce(name: str, fired: threading.Event) -> None:
    fired.set()
    logger.warning("saddle_env: compiling %s with numba, once: the compiled code is cached "
                   "on disk, so later runs (and this run's next calls) start at once "
                   "(python -m saddle_env.coldstart.precompile compiles every level ahead)",
                   name)


def announce_no_build(why: str) -> None:
    """Say once per process, at WARNING, that the install's ahead-of-time kernels are not
    used (``why``), so first calls compile."""
    global _announced_no_build
    if _announced_no_build:
        return
    _announced_no_build = True
    logger.warning("saddle_env: the install's ahead-of-time kernels are not used: %s. numba "
                   "compiles each first call instead (10-20 s, then cached on disk)", why)


_announced_no_build = False


def _ours(f) -> bool:
    # numba makes some functions with no module (a jitclass's property getters, which
    # numbalsoda's import compiles): those are not ours either.
    return (f.__module__ or "").startswith(_OURS)


def _start(ev) -> None:
    f = ev.data["dispatcher"].py_func
    if not _ours(f):
        return
    depth = getattr(_state, "depth", 0)
    _state.depth = depth + 1
    if depth:  # a callee of a compile already timed
        return
    name = f"{f.__module__}.{f.__qualname__}"
    fired = threading.Event()
    timer = threading.Timer(NOTICE_AFTER, _announce, (name, fired))
    timer.daemon = True
    timer.start()
    _state.pending = (timer, fired, name, time.perf_counter())


def _end(ev) -> None:
    f = ev.data["dispatcher"].py_func
    if not _ours(f):
        return
    _state.depth -= 1
    if _state.depth:
        return
    timer, fired, name, start = _state.pending
    timer.cancel()
    if fired.is_set():
        logger.info("saddle_env: compiled %s in %.1f s", name, time.perf_counter() - start)


def install() -> None:
    """Listen to numba's compile events (once per process)."""
    global _installed
    if _installed:
        return
    from numba.core import event

    class _Listener(event.Listener):
        def on_start(self, ev):
            _start(ev)

        def on_end(self, ev):
            _end(ev)

    event.register("numba:compile", _Listener())
    _installed = True
