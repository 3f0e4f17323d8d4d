"""numba's threads inside an ahead-of-time module: what lets the install's build hold the
vector environment's threaded step (`envs.control_step.step_parallel`, a ``prange`` loop).

numba compiles a ``prange`` loop into calls of its threading layer (OpenMP, TBB or its
workqueue: ``numba_parallel_for``, ``get_num_threads``, the scheduler's functions). The JIT
links those names to the layer's functions in its own symbol table when the layer starts
(``numba.np.ufunc.parallel._launch_threads``); an extension module built by ``pycc`` has no
such table, so its loader could not resolve them. The build therefore links a small C file
into each module (`SHIM`) that defines those names as forwarders through a table of function
pointers, and `wire` fills the table, once per module and process, with the addresses of
the layer numba starts, just before the module's threaded step first runs. The module then
runs the JIT's very code on numba's own threads: ``NUMBA_NUM_THREADS``,
``numba.set_num_threads`` and the threading layer numba picks (`threads`) apply to it as to
the JIT. Until it is wired the forwarders report no threads, which numba's code turns into
a RuntimeError rather than a crash. Only the standard library at import here.
"""
from __future__ import annotations

import ctypes
from pathlib import Path

# The names numba's parallel code calls, in the order of the table (`SHIM`), and the
# table's own name in a module (exported: `wire` finds it with ctypes).
SYMBOLS = ("numba_parallel_for", "get_num_threads", "set_num_threads", "get_thread_id",
           "get_parallel_chunksize", "set_parallel_chunksize", "get_sched_size",
           "allocate_sched", "deallocate_sched", "do_scheduling_signed",
           "do_scheduling_unsigned")
TABLE = "saddle_env_numba_threading"

# The forwarders take the argument and result types numba's code declares for each name
# (numba.parfors.parfor_lowering, numba.np.ufunc.parallel: intp for every integer, as the
# JIT calls them). They are hidden, so that the module's own calls bind to them and no
# other library's function of the same name can take their place.
SHIM = r"""
#include <stddef.h>
#include <stdint.h>
typedef intptr_t intp;
typedef uintptr_t uintp;
#define HIDDEN __attribute__((visibility("hidden")))
#define FN(i, type) ((type)saddle_env_numba_threading[i])

void *saddle_env_numba_threading[11];

HIDDEN void numba_parallel_for(void *fn, void *args, void *dims, void *steps, void *data,
                               intp inner_ndim, intp array_count, intp num_threads) {
    if (saddle_env_numba_threading[0])
        FN(0, void (*)(void *, void *, void *, void *, void *, intp, intp, intp))(
            fn, args, dims, steps, data, inner_ndim, array_count, num_threads);
}
/* 0 threads until wired: numba's parallel code raises RuntimeError on that */
HIDDEN intp get_num_threads(void) {
    return saddle_env_numba_threading[1] ? FN(1, intp (*)(void))() : 0;
}
HIDDEN void set_num_threads(intp n) {
    if (saddle_env_numba_threading[2]) FN(2, void (*)(intp))(n);
}
HIDDEN intp get_thread_id(void) {
    return saddle_env_numba_threading[3] ? FN(3, intp (*)(void))() : 0;
}
HIDDEN uintp get_parallel_chunksize(void) {
    return saddle_env_numba_threading[4] ? FN(4, uintp (*)(void))() : 0;
}
HIDDEN void set_parallel_chunksize(uintp n) {
    if (saddle_env_numba_threading[5]) FN(5, void (*)(uintp))(n);
}
HIDDEN uintp get_sched_size(uintp threads, uintp ndim, intp *starts, intp *ends) {
    return saddle_env_numba_threading[6]
        ? FN(6, uintp (*)(uintp, uintp, intp *, intp *))(threads, ndim, starts, ends) : 0;
}
HIDDEN void *allocate_sched(uintp size) {
    return saddle_env_numba_threading[7] ? FN(7, void *(*)(uintp))(size) : NULL;
}
HIDDEN void deallocate_sched(void *sched) {
    if (saddle_env_numba_threading[8]) FN(8, void (*)(void *))(sched);
}
HIDDEN intp *do_scheduling_signed(uintp ndim, intp *starts, intp *ends, uintp threads,
                                  void *sched, intp debug) {
    return saddle_env_numba_threading[9]
        ? FN(9, intp *(*)(uintp, intp *, intp *, uintp, void *, intp))(
              ndim, starts, ends, threads, sched, debug) : NULL;
}
HIDDEN intp *do_scheduling_unsigned(uintp ndim, intp *starts, intp *ends, uintp threads,
                                    void *sched, intp debug) {
    return saddle_env_numba_threading[10]
        ? FN(10, intp *(*)(uintp, intp *, intp *, uintp, void *, intp))(
              ndim, starts, ends, threads, sched, debug) : NULL;
}
"""

_wired: set[str] = set()  # the module files wired in this process


def write_shim(folder: str, module_name: str) -> str:
    """Write `SHIM` for the module ``module_name`` into ``folder`` (a build's scratch
    folder, which workers share); its path, for ``pycc``."""
    path = Path(folder) / f"{module_name}_threading.c"
    path.write_text(SHIM)
    return str(path)


def wire(module_file: str) -> None:
    """Point the forwarders of the loaded extension module ``module_file`` at the threading
    layer numba starts now (`threads` has set which one it prefers). Once per module."""
    if module_file in _wired:
        return
    from llvmlite import binding as ll
    from numba.np.ufunc import parallel

    from . import threads  # noqa: F401 - the layer's priority and spin-wait settings first

    parallel._launch_threads()  # what the JIT does when it compiles a parallel loop
    # the module is loaded already: dlopen hands back its handle
    table = (ctypes.c_void_p * len(SYMBOLS)).in_dll(ctypes.CDLL(module_file), TABLE)
    for i, name in enumerate(SYMBOLS):
        address = ll.address_of_symbol(name)
        if not address:
            raise RuntimeError(f"numba's threading layer has no {name}")
        table[i] = address
    _wired.add(module_file)
