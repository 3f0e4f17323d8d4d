"""How the kernels are compiled: numba's options (no fast-math, numpy's error model, cached on
disk), one specialisation per function (`one_signature`), and the decorators the kernel
modules use (`jit`, `inline`, `ir_inline`, `jit_per_constant`, `python_entry`), and
`unmanaged`, an array without its reference count."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

import numba as nb
from numba.core import cgutils, types
from numba.extending import intrinsic


def one_signature(dispatcher):
    """Type a compiled function's arguments as their plain types when compiled code calls it.

    numba compiles a function once per distinct argument types, and a constant passed from
    compiled code is its own type (``Literal[int](4)`` for COULOMB, ``Literal[bool](True)``):
    `rhs` was compiled six times over for literal and plain models and ``want_normal`` flags,
    `integrate_h` twice, `_event_value` eight times, and each copy pulls in the code below it
    (docs/coldstart.md). None of these functions needs a constant argument (LLVM
    still folds a constant at an inlined call), so calls from compiled code are typed
    without the literals, one specialisation each."""
    typed = dispatcher.get_call_template

    def get_call_template(args, kws):
        return typed(tuple(nb.types.unliteral(a) for a in args),
                     {k: nb.types.unliteral(v) for k, v in kws.items()})

    dispatcher.get_call_template = get_call_template
    return dispatcher


_jit = nb.njit(cache=True, fastmath=False, error_model="numpy")
# For the per-ball rates: inlined into every caller so a loop over balls can be vectorised.
_inline = nb.njit(cache=True, fastmath=False, error_model="numpy", forceinline=True)


def jit(f):
    """The kernels' compiler: numba without fast-math, numpy's error model (1/0 = inf), cached
    on disk, one specialisation per function (`one_signature`)."""
    return one_signature(_jit(f))


_ir_inline = nb.njit(cache=True, fastmath=False, error_model="numpy", inline="always")


def ir_inline(f):
    """`jit`, with the function's code typed into each compiled caller rather than compiled
    on its own (numba inlines it before typing). For thin layers between a compiled entry
    point and the integrator: numba links a callee's whole code into each caller's and
    optimises and generates machine code for it again there, so every separately compiled
    layer above `integrators.integrate_h` paid for the integrator once more (the
    environment's step had four: docs/coldstart.md). Not for large helpers with several
    call sites: numba types each inlined copy again, and its type inference grows faster
    than the code (inlining the integrator's helpers made compiling slower)."""
    return one_signature(_ir_inline(f))


def jit_per_constant(f):
    """`jit` that keeps numba's compile per constant argument, for a copy loop whose length
    is a constant at each call (`envs.control_step._load`, `_store`: `ROW_WIDTH` or
    `STATE_WIDTH`): compiled per constant, the loop has a fixed length the compiler unrolls.
    Typed plain (`one_signature`), the vector env steps slower."""
    d: Any = _jit(f)  # Any: carries our own mark, which numba's Dispatcher does not declare
    d._per_constant = True
    return d


def inline(f):
    """`jit`, always inlined by LLVM into its callers."""
    return one_signature(_inline(f))

def python_entry(dispatcher):
    """Mark a compiled function that Python calls through `specialise`'s namespace (an entry
    point such as the environment's step): its copies keep numba's wrapper for Python
    callers. Returns the function."""
    dispatcher._python_entry = True
    return dispatcher


def _unmanaged(typingctx, arr):
    """``arr`` without its reference count: the same data, shape and strides, with numba's
    memory record (meminfo) left empty. Every view compiled code takes of such an array, and
    every call it is passed to, is then free of the atomic increments and decrements a
    managed array costs (measured: most of a single ball's compiled step went to them). Only
    for an array that something else keeps alive for as long as the result is used, and
    whose views do not outlive that: a compiled function's own arguments, which its caller
    holds for the call."""
    if not isinstance(arr, types.Array):
        return None

    def codegen(context, builder, sig, args):
        src = context.make_array(arr)(context, builder, value=args[0])
        dst = context.make_array(arr)(context, builder)
        for name in ("nitems", "itemsize", "data", "shape", "strides"):
            setattr(dst, name, getattr(src, name))
        dst.meminfo = cgutils.get_null_value(dst.meminfo.type)
        dst.parent = cgutils.get_null_value(dst.parent.type)
        return dst._getvalue()

    return arr(arr), codegen


# Called as unmanaged(arr) in compiled code (numba passes the typing context itself); typed
# so for mypy, which sees numba's intrinsic wrapper's own signature.
unmanaged = cast(Callable[[Any], Any], intrinsic(_unmanaged))
