"""Pin the BLAS/LAPACK libraries numpy and scipy loaded to one thread (what threadpoolctl
does, for the OpenBLAS builds in numpy's and scipy's wheels, without the dependency).

On a small shared machine an OpenBLAS call on a 4×4 matrix can spend milliseconds waking
its worker threads, far longer than the computation itself takes on one. The simulator's
benchmark (`saddle_env.workprecision`) times tiny linear algebra and runs its own
parallelism through numba, and `saddle-fit` runs many small least-squares solves: both pin
BLAS to one thread.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

_SYMBOLS = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
            "openblas_set_num_threads64_", "openblas_set_num_threads")
_GETTERS = {s: s.replace("_set_", "_get_") for s in _SYMBOLS}


def _loaded_openblas() -> list[str]:
    try:
        with open("/proc/self/maps", encoding="utf-8") as fh:
            paths = {line.split()[-1] for line in fh if "openblas" in line.lower()}
    except OSError:
        return []
    return sorted(p for p in paths if os.path.isfile(p))


def _thread_controls() -> list[tuple[str, Any, Any]]:
    """Each loaded OpenBLAS's thread-count setter and getter (None where it has none), named
    ``library:symbol``."""
    import numpy  # noqa: F401  (load the libraries first)
    import scipy.linalg  # noqa: F401

    controls = []
    for path in _loaded_openblas():
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for sym in _SYMBOLS:
            set_fn = getattr(lib, sym, None)
            if set_fn is not None:
                get_fn = getattr(lib, _GETTERS[sym], None)
                if get_fn is not None:
                    get_fn.restype = ctypes.c_int
                controls.append((f"{os.path.basename(path)}:{sym}", set_fn, get_fn))
                break
    return controls


def limit_blas_threads(n: int = 1) -> list[str]:
    """Set every loaded OpenBLAS to ``n`` threads; return the libraries changed (may be
    empty: on a platform without /proc, or another BLAS, this does nothing)."""
    controls = _thread_controls()
    for _, set_fn, _ in controls:
        set_fn(ctypes.c_int(n))
    return [name for name, _, _ in controls]


@contextmanager
def blas_threads(n: int = 1) -> Iterator[list[str]]:
    """Within the block every loaded OpenBLAS uses ``n`` threads; each gets its own count
    back after, so a library call (the fit's) leaves its caller's BLAS as it found it."""
    restore = [(name, set_fn, int(get_fn())) for name, set_fn, get_fn in _thread_controls()
               if get_fn is not None]
    for _, set_fn, _ in restore:
        set_fn(ctypes.c_int(n))
    try:
        yield [name for name, _, _ in restore]
    finally:
        for _, set_fn, threads in restore:
            set_fn(ctypes.c_int(threads))
