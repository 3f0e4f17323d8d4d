"""saddle_env.jobs.signals: SIGTERM stops a command as Ctrl-C does, puts the previous handler
back, and a SIGTERM that Python dropped inside a ``__del__`` is raised again by the loop's
check (the rig loop, saddle-fit, the leaderboard and the benchmark runner use it)."""
from __future__ import annotations

import gc
import os
import signal
import threading

import pytest
from helpers import SignalledWhileFreed

from saddle_env.jobs.signals import Terminated, sigterm_interrupts


def test_sigterm_raises_terminated_and_the_previous_handler_comes_back():
    def previous(signum, frame):
        raise AssertionError("the block's handler should have run")

    before = signal.signal(signal.SIGTERM, previous)
    try:
        with pytest.raises(KeyboardInterrupt) as exc, sigterm_interrupts() as term:
            assert not term.lost()
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(10**6):
                pass
        assert isinstance(exc.value, Terminated)
        assert signal.getsignal(signal.SIGTERM) is previous
        # off the main thread Python cannot set handlers: the block changes nothing there
        seen = []
        worker = threading.Thread(target=lambda: seen.append(_enter_off_main()))
        worker.start()
        worker.join()
        assert seen == [previous]
    finally:
        signal.signal(signal.SIGTERM, before)


def _enter_off_main():
    with sigterm_interrupts() as term:
        assert not term.lost()
        return signal.getsignal(signal.SIGTERM)


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_sigterm_dropped_inside_a_del_is_raised_by_the_next_check():
    with pytest.raises(Terminated), sigterm_interrupts() as term:
        term.raise_if_lost()                     # no signal yet: nothing happens
        SignalledWhileFreed()                    # freed here; its Terminated is dropped
        gc.collect()
        assert term.lost()                       # the command would have run on from here
        term.raise_if_lost()
