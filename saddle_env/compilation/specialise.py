"""Compiling only what a scene uses: per-scene copies of the kernel modules with the contact
models a scene lacks switched off (`specialise`), and the entry points Python calls on them
(`entry`, `checked`), taken from the install's ahead-of-time build where it has them (`aot`)."""

from __future__ import annotations

import os
import sys
import types

import numba as nb

from ..scene import COULOMB, ION_PAUL, ION_RRF, ROLLING, SLIPPING
from . import aot as _aot
from .jit import one_signature

# -- compiling only what a scene uses ------------------------------------------------------
# The kernels test these compile-time flags beside the run-time model
# (``if COULOMB_ON and model == COULOMB``). numba prunes a branch on a global constant before
# typing, so a copy compiled with a flag False never types, lowers or optimises that code,
# nor compiles the functions only that code calls. The functions as written have every flag
# True (the full kernels); `specialise` makes the copies for a scene's contact models. A copy
# meets a model it was not compiled for with NaN rates (`rhs`), which the loop reports as a
# failure: callers ask for a copy covering every model they step (the environment falls back
# to the full kernels when a reset brings a model its copy lacks).
ROLLING_ON = SLIPPING_ON = COULOMB_ON = ION_ON = RESIST_ON = True
_FLAG_OF_MODEL = {ROLLING: "ROLLING_ON", SLIPPING: "SLIPPING_ON", COULOMB: "COULOMB_ON",
                  ION_RRF: "ION_ON", ION_PAUL: "ION_ON"}
_FLAGS = ("ROLLING_ON", "SLIPPING_ON", "COULOMB_ON", "ION_ON", "RESIST_ON")

# Set to 1 in the environment: every caller runs the full kernels (every contact model), no
# per-scene copies. For a process that meets many sets of contact models (the test suite
# compiles the full kernels once instead of a copy of the loop for each set it uses).
FULL_KERNELS_ENV = "SADDLE_ENV_FULL_KERNELS"

# Modules whose compiled functions `specialise` copies, in import order (lower modules first).
_SPECIALISABLE: list[types.ModuleType] = []
class _Variant:
    """One flag set's copies (by the original's id) and, per registered module name, the
    namespace of that module with its copies."""

    def __init__(self):
        self.copies: dict[int, object] = {}
        self.spaces: dict[str, types.SimpleNamespace] = {}
        # per module name: its namespace with the ahead-of-time entry points (`_aot`) in
        # place of their JIT copies, for Python callers (the copies' own globals keep the JIT)
        self.public: dict[str, types.SimpleNamespace] = {}


_variants: dict[tuple[str, ...], _Variant] = {}
_jit_of: dict[int, object] = {}  # id of an ahead-of-time entry point (`_aot`) → its JIT copy


def specialisable(module_name: str) -> None:
    """Register a module (called at the end of its import) whose compiled functions
    `specialise` copies."""
    _SPECIALISABLE.append(sys.modules[module_name])


def variant_flags(models, resist: bool) -> tuple[str, ...]:
    """The flags a copy for the model codes ``models`` (with rolling resistance where
    ``resist``) turns on, in a fixed order."""
    on = {_FLAG_OF_MODEL[int(m)] for m in models}
    if resist:
        on.add("RESIST_ON")
    return tuple(f for f in _FLAGS if f in on)


def _is_compiled(v) -> bool:
    return isinstance(v, nb.core.dispatcher.Dispatcher)



class _CompiledCallersOnly(nb.core.registry.CPUDispatcher):
    """A copy built without numba's wrapper for Python callers (`_copy_of`): a call from
    Python would jump through the missing wrapper and crash the interpreter, so it raises."""

    def __call__(self, *args, **kwargs):
        raise TypeError(f"{self.py_func.__qualname__} is a per-scene copy that only compiled "
                        f"code calls (it has no wrapper for Python callers): call "
                        f"{self.py_func.__name__} from its module, or a `python_entry` copy")


def _copy_of(dispatcher, space: dict, tag: str):
    """A copy of a compiled function whose globals are ``space``, compiled as the original
    (same options, same typing rule), cached on disk under its own name. Only compiled code
    calls a copy unless it is a `python_entry`, so the others are built without numba's
    wrappers for Python and C callers: those wrappers were a fixed cost in each function's
    compile (docs/coldstart.md)."""
    f = dispatcher.py_func
    twin = types.FunctionType(f.__code__, space, f.__name__, f.__defaults__, f.__closure__)
    twin.__qualname__ = f"{f.__qualname__}__{tag}"
    twin.__doc__ = f.__doc__
    options = {k: v for k, v in dispatcher.targetoptions.items() if k != "nopython"}
    if not getattr(dispatcher, "_python_entry", False):
        options.update(no_cpython_wrapper=True, no_cfunc_wrapper=True)
    copy = nb.njit(cache=True, **options)(twin)
    if options.get("no_cpython_wrapper"):
        copy.__class__ = _CompiledCallersOnly
    if getattr(dispatcher, "_per_constant", False):
        copy._per_constant = True
        return copy
    return one_signature(copy)


def specialise(models, resist: bool, module: types.ModuleType):
    """``module`` as compiled for the contact models ``models`` (model codes) alone and, with
    ``resist``, rolling resistance: a namespace of the module's names in which every compiled
    function of the registered modules is a copy whose globals are its module's with the
    other flags False and the compiled functions replaced by their copies, so a whole chain
    below an entry point is specialised together. (Functions that test no flag are copied
    too, so that no copy needs numba's wrappers for Python callers: `_copy_of`.) Made once per flag
    set and process (a module registered later is added when first asked for); compiled (or loaded
    from the on-disk cache) on first call, as any kernel. Where an ahead-of-time build of the same
    sources has this flag set's entry points (`_aot`: a first env step's and a first simulate's),
    the namespace has those in place of the JIT copies: nothing compiles. With every flag on, or
    with `FULL_KERNELS_ENV` set to
    1, the module itself."""
    flags = variant_flags(models, resist)
    if flags == _FLAGS or os.environ.get(FULL_KERNELS_ENV, "0") not in ("", "0"):
        return module
    variant = _variants.setdefault(flags, _Variant())
    if module.__name__ not in variant.spaces:
        tag = "_".join(f[:-3].lower() for f in flags) or "none"
        values = {f: f in flags for f in _FLAGS}
        for mod in _SPECIALISABLE:  # lower modules first: their copies exist
            if mod.__name__ in variant.spaces:
                continue
            space = dict(vars(mod))
            space.update(values)
            for v in vars(mod).values():
                if (_is_compiled(v) and id(v) not in variant.copies
                        and v.py_func.__globals__ is vars(mod)):
                    variant.copies[id(v)] = _copy_of(v, space, tag)
            for k, v in list(space.items()):  # this module's and lower modules' functions
                if _is_compiled(v) and id(v) in variant.copies:
                    space[k] = variant.copies[id(v)]
            variant.spaces[mod.__name__] = types.SimpleNamespace(**space)
    if module.__name__ not in variant.public:
        ahead = _aot.compiled(flags, module.__name__)
        namespace = variant.spaces[module.__name__]
        for name, fn in ahead.items():
            _jit_of[id(fn)] = getattr(namespace, name)
        variant.public[module.__name__] = \
            types.SimpleNamespace(**{**vars(namespace), **ahead}) if ahead else namespace
    return variant.public[module.__name__]


def checked(space: types.SimpleNamespace, name: str, args: tuple):
    """``space``'s entry point ``name`` (from `specialise`) for a call with ``args``: the
    ahead-of-time one if it was compiled for exactly these argument types, else its JIT copy
    (which compiles for them). A caller whose argument types are fixed keeps the answer."""
    fn = getattr(space, name)
    if id(fn) not in _jit_of:
        return fn
    return fn if _aot.matches(fn, args) and _aot.prepare(fn) else _jit_of[id(fn)]


_entries: dict[tuple[int, str], object] = {}  # (id of a `specialise` namespace, name) → checked


def entry(models, resist: bool, module: types.ModuleType, name: str, args: tuple):
    """``module``'s entry point ``name`` compiled for the contact models ``models`` alone
    (`specialise`), checked once per namespace against the types of ``args`` (`checked`).
    For callers that build every argument themselves (float64 and int64 arrays, records of
    floats and ints), whose types therefore never change from call to call."""
    space = specialise(models, resist, module)
    key = (id(space), name)  # namespaces live as long as the process
    fn = _entries.get(key)
    if fn is None:
        fn = _entries[key] = checked(space, name, args)
    return fn
