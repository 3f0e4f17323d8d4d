"""Pin the BLAS/LAPACK libraries numpy and scipy loaded to one thread (what threadpoolctl
does, for the OpenBLAS builds in numpy's and scipy's wheels, without the dependency).

On a small shared machine an OpenBLAS call on a 4×4 matrix can spend milliseconds waking
its worker threads: ``scipy.linalg.expm`` of a 4×4 took 15 ms with the default threads and
0.1 ms with one, on the 2-core machine the benchmark was written on. The benchmark times
tiny linear algebra (the peer's 3×3 solves, the linearised tier's matrix exponential) and
runs its own parallelism through numba, so it pins BLAS to one thread for fairness.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Iterator
from contextlib import contextmanager

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


def limit_blas_threads(n: int = 1) -> list[str]:
    """Set every loaded OpenBLAS to ``n`` threads; return the libraries changed (may be
    empty: on a platform without /proc, or another BLAS, this does nothing)."""
    import numpy  # noqa: F401  (load the libraries first)
    import scipy.linalg  # noqa: F401

    changed = []
    for path in _loaded_openblas():
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for sym in _SYMBOLS:
            fn = getattr(lib, sym, None)
            if fn is not None:
                fn(ctypes.c_int(n))
                changed.append(f"{os.path.basename(path)}:{sym}")
                break
    return changed


@contextmanager
def blas_threads(n: int = 1) -> Iterator[list[str]]:
    """Within the block every loaded OpenBLAS uses ``n`` threads; each gets its own count
    back after, so a library call (the fit's) leaves its caller's BLAS as it found it."""
    import numpy  # noqa: F401  (load the libraries first)
    import scipy.linalg  # noqa: F401

    restore = []
    for path in _loaded_openblas():
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for sym in _SYMBOLS:
            set_fn, get_fn = getattr(lib, sym, None), getattr(lib, _GETTERS[sym], None)
            if set_fn is not None and get_fn is not None:
                get_fn.restype = ctypes.c_int
                restore.append((f"{os.path.basename(path)}:{sym}", set_fn, int(get_fn())))
                set_fn(ctypes.c_int(n))
                break
    try:
        yield [name for name, _, _ in restore]
    finally:
        for _, set_fn, threads in restore:
            set_fn(ctypes.c_int(threads))
