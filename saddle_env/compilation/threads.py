"""The threads compiled code runs on: numba's threading layer for the vector environment's
parallel step (and whether a forked child may use it), and a pool of Python threads for the
batch kernels that run long per call (`in_threads`)."""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING

import numba as nb

if TYPE_CHECKING:
    from concurrent.futures import ThreadPoolExecutor

# Threads for numba's parallel loop (the vector environment's step). Measured
# on a shared 2-core machine, 1024-ball vector env, one run per row:
#   layer                          idle           beside one CPU-bound process
#   OpenMP, libgomp default spin   2.5-2.9 M/s    0.5-0.6 M/s (spinning threads steal the core)
#   workqueue (never spins)        1.3 M/s        1.1 M/s     (waking threads costs ~0.2 ms)
#   OpenMP, GOMP_SPINCOUNT=1000    2.1 M/s        1.1 M/s
# so OpenMP with a short spin is preferred; numba falls back to TBB or workqueue where no
# OpenMP runtime loads. A user's NUMBA_THREADING_LAYER, GOMP_SPINCOUNT or OMP_WAIT_POLICY
# wins. (GNU OpenMP is not fork-safe: fork after a parallel step and use it in the child
# fails loudly in numba; spawn/forkserver, SB3's default, are fine.)
if "NUMBA_THREADING_LAYER" not in os.environ:
    # numba.config sets its options from the environment at import: its stubs do not declare them
    nb.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]  # type: ignore[attr-defined]
    if "GOMP_SPINCOUNT" not in os.environ and "OMP_WAIT_POLICY" not in os.environ:
        os.environ["GOMP_SPINCOUNT"] = "1000"

# GNU OpenMP cannot be used again in a child forked after the parent used it (numba
# terminates the child), so the vector environment asks `threads_usable()` and steps on one
# thread when it says no.
_in_forked_child = False


def _mark_forked_child() -> None:
    global _in_forked_child
    _in_forked_child = True


os.register_at_fork(after_in_child=_mark_forked_child)


def threads_usable() -> bool:
    """False in a forked child whose parent already ran numba's OpenMP threads."""
    if not _in_forked_child:
        return True
    try:
        return nb.threading_layer() != "omp"
    except ValueError:  # no parallel region has run in this process (or its parent) yet
        return True


# Threads for the batch kernels that run long per call (`prediction.integrate_segments`,
# `integrators.integrate_batch`): plain Python threads, each calling a one-thread compiled
# kernel on its own range of rows, with the GIL released inside (``nogil``). Unlike numba's
# ``prange``, a kernel called this way is an ordinary compiled function, so the install's
# ahead-of-time build can hold it (`aot_build`) and a first call compiles nothing; and
# Python threads survive a fork (the pool is made again in the child). Waking a thread
# costs tens of microseconds, nothing next to these calls' milliseconds; the vector
# environment's step, a fraction of a millisecond, keeps numba's OpenMP threads (which the
# ahead-of-time build reaches through `aot_threads`).
_pool: tuple[int, int, ThreadPoolExecutor] | None = None   # (its process id, its threads, the executor)


# Below this much simulated time in a call (all balls together) the batch kernels run on the
# calling thread alone: waking a pool thread costs tens of microseconds, and a look-ahead of
# `mpc` (a few hundred runs of a few tenths of a second, ~0.2 ms) ran 10-40 % slower split
# over two threads (measured 2026-11-26; numba's OpenMP threads, which spin briefly instead
# of sleeping, had cost it less). 10 simulated seconds are about 1-2 ms of DOP853 at the
# default tolerance.
THREADS_FROM_SIMULATED_S = 10.0


def thread_count() -> int:
    """How many threads the batch kernels use: numba's setting (``NUMBA_NUM_THREADS``, by
    default the machine's cores), read without starting numba's own threads."""
    return max(1, int(nb.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]  # as above


def _executor(workers: int):
    """A pool of at least ``workers`` threads, made on first use and again in a forked child
    (which has the parent's executor object but none of its threads)."""
    global _pool
    from concurrent.futures import ThreadPoolExecutor
    if _pool is None or _pool[0] != os.getpid() or _pool[1] < workers:
        if _pool is not None and _pool[0] == os.getpid():
            _pool[2].shutdown(wait=False)   # its threads end once idle
        _pool = (os.getpid(), workers,
                 ThreadPoolExecutor(workers, thread_name_prefix="saddle_env"))
    return _pool[2]


def in_threads(kernel, n: int, *args, simulated_s: float = math.inf,
               threads: int | None = None) -> list:
    """``kernel(lo, hi, *args)`` over contiguous ranges that split rows ``0..n-1`` among up
    to ``threads`` threads (default `thread_count`; one below `THREADS_FROM_SIMULATED_S` of
    ``simulated_s``, the call's simulated time over all rows), this one included; returns
    the calls' results in the order of their ranges when all are done, and raises the first
    error any of them raised. ``kernel`` must release the GIL (compiled with ``nogil=True``)
    for the ranges to run at once."""
    if threads is None:
        threads = 1 if simulated_s < THREADS_FROM_SIMULATED_S else thread_count()
    k = max(1, min(threads, n))
    if k == 1:
        return [kernel(0, n, *args)]
    bounds = [c * n // k for c in range(k + 1)]
    pool = _executor(k - 1)
    others = [pool.submit(kernel, bounds[c], bounds[c + 1], *args) for c in range(1, k)]
    try:
        first = kernel(bounds[0], bounds[1], *args)
    finally:
        for fut in others:   # wait for every range before the caller reuses the arrays
            fut.exception()
    return [first] + [fut.result() for fut in others]
