"""The ahead-of-time compiled kernels, when there are any that match the sources in place.

The package's install builds them (`saddle_env.compilation.aot_build`): a C extension module per set
of contact models holding the compiled code of a first `env.step` and a first `simulate`,
the same numba compile the JIT would make, built once. Here they are found and checked:
the manifest they were built with names the digest of the package's sources, and a module
is used only while the sources still have that digest (an edited or pulled source falls
back to the JIT and its on-disk cache, as without them). ``SADDLE_ENV_AOT=0`` turns them
off. The modules are compiled for the building machine's CPU and its features, as numba's
JIT compiles for the running one, and are used only on the same CPU and features and under
the numba and llvmlite that built them. Only the standard library at import here:
`specialise` imports this module, and asks it on its first specialisation.
"""
from __future__ import annotations

import hashlib
import importlib.util
import json
import logging
import os
import sys
import sysconfig
from collections.abc import Callable
from pathlib import Path

AOT_ENV = "SADDLE_ENV_AOT"  # 0 turns the build off (at install: not built; at run time: not used)
PACKAGE_DIR = Path(__file__).resolve().parents[1]  # saddle_env/
AOT_DIR = PACKAGE_DIR / "_aot"
MANIFEST = "manifest.json"
# The sources a build depends on: the package's own modules and the environment's (the
# kernels, the constants they fold in, and the code that picks their arguments). Any change
# to one of them, even one no kernel reads, retires the build: safe rather than clever.
SOURCE_SUBDIRS = ("", "envs", "compilation")

logger = logging.getLogger("saddle_env")
_loaded: dict[str, dict[str, dict[str, Callable]]] | None = None  # flags tag → module → name → fn
_why_not: str | None = None
# id of an entry point → the argument types (numba's names) it was compiled for. An entry
# point unboxes its arguments as those types without checking them: called with others it
# reads memory wrongly, hence `matches`.
_argtypes: dict[int, tuple[str, ...]] = {}


def source_digest(package_dir: Path = PACKAGE_DIR) -> str:
    """SHA-256 over the names and contents of the sources a build depends on."""
    h = hashlib.sha256()
    for sub in SOURCE_SUBDIRS:
        for path in sorted((package_dir / sub).glob("*.py")):
            h.update(f"{path.relative_to(package_dir).as_posix()}\0".encode())
            h.update(path.read_bytes())
            h.update(b"\0")
    return h.hexdigest()


def platform_tag() -> str:
    """What an extension module is built for: the interpreter and the platform."""
    return f"{sys.implementation.cache_tag}-{sysconfig.get_platform()}"


def machine() -> dict[str, str]:
    """What a build's machine code depends on beyond the sources: the CPU model and the
    instruction-set features numba's JIT compiles for here (its own choice, so
    ``NUMBA_CPU_NAME`` and ``NUMBA_CPU_FEATURES`` count), and the compiler's versions."""
    import llvmlite
    import numba
    from numba.core.registry import cpu_target

    codegen = cpu_target.target_context.codegen()
    return {"cpu": codegen._get_host_cpu_name(), "features": codegen._get_host_cpu_features(),
            "numba": numba.__version__, "llvmlite": llvmlite.__version__}


def flags_key(flags: tuple[str, ...]) -> str:
    return ",".join(flags)


def read_manifest() -> dict | None:
    try:
        manifest = json.loads((AOT_DIR / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    return manifest if isinstance(manifest, dict) else None


def _load() -> dict[str, dict[str, dict[str, Callable]]]:
    """Import every module of a current build once; {} (and the reason in `_why_not`) when
    there is none, it is off, or it was built from other sources or for another platform,
    CPU or compiler."""
    global _why_not
    if os.environ.get(AOT_ENV, "1") in ("0", ""):
        _why_not = f"turned off ({AOT_ENV}=0)"
        return {}
    manifest = read_manifest()
    if manifest is None:
        _why_not = f"none built (no {AOT_DIR / MANIFEST})"
        return {}
    if manifest.get("platform") != platform_tag():
        _why_not = f"built for {manifest.get('platform')}, not {platform_tag()}"
        return {}
    here = machine()
    built = {k: manifest.get(k) for k in here}
    if built != here:
        # another CPU's instructions could be illegal here; another numba's code would no
        # longer be bit for bit what the JIT compiles beside it
        differ = ", ".join(f"{k} {built[k]!r} (here {here[k]!r})" for k in here
                           if built[k] != here[k] and k != "features")
        _why_not = f"built for another machine or compiler ({differ or 'CPU features'}); " \
                   "rebuild with python -m saddle_env.compilation.precompile --aot"
        return {}
    if manifest.get("digest") != source_digest():
        _why_not = ("built from other sources (the package changed since; rebuild with "
                    "python -m saddle_env.compilation.precompile --aot)")
        logger.info("saddle_env: ahead-of-time kernels not used: %s", _why_not)
        return {}
    found: dict[str, dict[str, dict[str, Callable]]] = {}
    for entry in manifest.get("modules", []):
        try:
            path = AOT_DIR / entry["file"]
            spec = importlib.util.spec_from_file_location(
                f"saddle_env.compilation.aot.{entry['name']}", path)
            module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
            spec.loader.exec_module(module)  # type: ignore[union-attr]
            entries: dict[str, dict[str, Callable]] = {}
            types: dict[int, tuple[str, ...]] = {}
            for mod, names in entry["exports"].items():
                entries[mod] = {name: getattr(module, name) for name in names}
                for name in names:
                    types[id(entries[mod][name])] = tuple(entry["argtypes"][f"{mod}.{name}"])
            key = flags_key(tuple(entry["flags"]))
        except (ImportError, OSError, KeyError, TypeError, AttributeError) as exc:
            logger.info("saddle_env: an ahead-of-time module of %s not loaded (%s: %s); "
                        "the JIT compiles its kernels", AOT_DIR, type(exc).__name__, exc)
            continue
        _argtypes.update(types)
        found[key] = entries
    _why_not = None if found else "no module of the build could be loaded"
    return found


def compiled(flags: tuple[str, ...], module_name: str) -> dict[str, Callable]:
    """The ahead-of-time entry points of ``module_name`` compiled for ``flags``
    (`specialise.variant_flags`), by name; {} when there are none."""
    global _loaded
    if _loaded is None:
        _loaded = _load()
    return _loaded.get(flags_key(flags), {}).get(module_name, {})


def matches(fn: Callable, args: tuple) -> bool:
    """Whether ``args`` have exactly the types the ahead-of-time entry point ``fn`` was
    compiled for (numba's `typeof`, some microseconds per argument: once per configuration,
    not per call, on hot paths)."""
    import numba

    return tuple(str(numba.typeof(a)) for a in args) == _argtypes[id(fn)]


def status() -> str:
    """One line on whether ahead-of-time kernels are in use, and why not."""
    global _loaded
    if _loaded is None:
        _loaded = _load()
    if _loaded:
        return f"ahead-of-time kernels in use ({len(_loaded)} modules, {AOT_DIR})"
    return f"no ahead-of-time kernels: {_why_not}"
