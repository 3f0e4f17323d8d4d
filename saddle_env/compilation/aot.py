"""The ahead-of-time compiled kernels, when there are any that match the sources in place.

The package's install builds them (`saddle_env.coldstart.aot_build`): a C extension module per set
of contact models holding the compiled code of a first `env.step` and a first `simulate`,
the same numba compile the JIT would make, built once. Here they are found and checked:
the manifest they were built with names the digest of the package's sources, and a module
is used only while the sources still have that digest (an edited or pulled source falls
back to the JIT and its on-disk cache, as without them). ``SADDLE_ENV_AOT=0`` turns them
off. The modules are used only under the numba and llvmlite that built them, and only on a
CPU that has every instruction they may use (`unusable`): on x86-64 they are compiled for
the x86-64-v3 instruction-set level (`BASELINE`), so a wheel built on one machine serves
every CPU at that level, and, where the building machine has AVX-512, once more for
x86-64-v4 (`UPPER_LEVELS`, in a folder of its own), which a CPU with AVX-512 runs instead;
built with ``SADDLE_ENV_AOT_CPU=host``, or on a machine below the level, they are compiled
for the building machine's CPU model and features alone, as numba's JIT compiles for the
running one. Only the standard library at import here: `specialise`
imports this module, and asks it on its first specialisation.
"""
from __future__ import annotations

import hashlib
import importlib.util
import json
import logging
import os
import platform
import sys
import sysconfig
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TypeGuard

AOT_ENV = "SADDLE_ENV_AOT"  # 0 turns the build off (at install: not built; at run time: not used)
PACKAGE_DIR = Path(__file__).resolve().parents[1]  # saddle_env/
AOT_DIR = PACKAGE_DIR / "_aot"
MANIFEST = "manifest.json"

# The CPU a build is compiled for. x86-64-v3 is the x86-64 psABI's third instruction-set
# level (AVX2, FMA, BMI1/2, F16C, LZCNT, MOVBE: Intel from Haswell, 2013, AMD from Zen,
# 2017, and the x86-64 machines of the common CI services). v4 adds AVX-512, which AMD
# shipped only from Zen 4 (2022) and Intel's client CPUs mostly not at all. LLVM takes the
# level's name as a CPU name; the features are the level's own, spelled as LLVM reports a
# host's (numba's ``_get_host_cpu_features``), so that a host's report can be compared.
BASELINE = "x86-64-v3"
_V3 = ",".join("+" + f for f in (
    "64bit", "cmov", "cx8", "fxsr", "mmx", "sse", "sse2",               # x86-64
    "cx16", "sahf", "popcnt", "crc32", "sse3", "ssse3", "sse4.1", "sse4.2",  # v2
    "avx", "avx2", "bmi", "bmi2", "f16c", "fma", "lzcnt", "movbe", "xsave"))  # v3
# The levels above the baseline a build adds where the building machine has them (it runs
# the first calls it compiles), each a whole build in the folder named after it; a CPU that
# has a level's features uses its build. x86-64-v4's "-prefer-256-bit" is a tuning, not an
# instruction (`_enabled` counts only "+" features): LLVM's model of the level would keep
# to 256-bit vectors, and the environment's SIMD blocks (`saddle_env.lockstep`) step a
# fifth faster on 512-bit ones (docs/install.md, measured on AMD Zen 5).
UPPER_LEVELS = ("x86-64-v4",)
LEVEL_FEATURES = {
    BASELINE: _V3,
    "x86-64-v4": _V3 + ",+avx512f,+avx512bw,+avx512cd,+avx512dq,+avx512vl,-prefer-256-bit",
}
# At build time: "host" compiles for the building machine's CPU model and features alone
# (its own fastest code, used on that model only); "baseline" for `BASELINE` alone;
# "levels" (the default) for it and the `UPPER_LEVELS` the machine has.
AOT_CPU_ENV = "SADDLE_ENV_AOT_CPU"
# At run time: the highest level whose build may be used (a level's name, e.g. x86-64-v3:
# the baseline's build even on a CPU with AVX-512, whose 512-bit instructions some older
# CPUs run at a lower clock); unset, the highest this CPU has.
AOT_LEVEL_ENV = "SADDLE_ENV_AOT_LEVEL"
# numba's settings of the CPU its JIT compiles for (read once, when numba is imported)
CPU_VARIABLES = ("NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")

logger = logging.getLogger("saddle_env")
_loaded: dict[str, dict[str, dict[str, Callable]]] | None = None  # flags tag → module → name → fn
_why_not: str | None = None
_folder: Path | None = None  # the folder of the build in use
# id of an entry point → the argument types (numba's names) it was compiled for. An entry
# point unboxes its arguments as those types without checking them: called with others it
# reads memory wrongly, hence `matches`.
_argtypes: dict[int, tuple[str, ...]] = {}
# id of an entry point that runs on numba's threads → its module's file (`prepare`)
_threaded: dict[int, str] = {}


def source_digest(folders: Sequence[str], package_dir: Path = PACKAGE_DIR) -> str:
    """SHA-256 over the names and contents of the modules of ``folders``, the folders of the
    package (``""``: its own top level) a build depends on. The build names them in its
    manifest (``sources``), so that this layer names no folder of the layers above it."""
    h = hashlib.sha256()
    for sub in folders:
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


def _enabled(features: str) -> set[str]:
    return {f[1:] for f in features.split(",") if f.startswith("+")}


def build_targets() -> list[dict[str, str]]:
    """The CPU names and features a build here compiles for (`AOT_CPU_ENV`), the one that
    goes into `AOT_DIR` first: on an x86-64 machine at `BASELINE`, that level and then each
    of `UPPER_LEVELS` the machine has (``levels``, the default) or the baseline alone
    (``baseline``); else, or with ``host``, this machine's own model (`machine`)."""
    choice = os.environ.get(AOT_CPU_ENV, "") or "levels"
    if choice not in ("levels", "baseline", "host"):
        raise ValueError(f"{AOT_CPU_ENV} must be 'levels', 'baseline' or 'host', got {choice!r}")
    here = machine()
    has = _enabled(here["features"])
    if (choice != "host" and platform.machine().lower() in ("x86_64", "amd64")
            and _enabled(LEVEL_FEATURES[BASELINE]) <= has):
        levels = [BASELINE] + ([lv for lv in UPPER_LEVELS if _enabled(LEVEL_FEATURES[lv]) <= has]
                               if choice == "levels" else [])
        return [{"cpu": lv, "features": LEVEL_FEATURES[lv]} for lv in levels]
    return [{"cpu": here["cpu"], "features": here["features"]}]


def build_folder(cpu: str) -> Path:
    """Where the build for ``cpu`` goes: `AOT_DIR`, or its folder for an upper level."""
    return AOT_DIR / cpu if cpu in UPPER_LEVELS else AOT_DIR


def unusable(built: Mapping[str, object], here: Mapping[str, str]) -> str | None:
    """Why modules built for ``built`` (a manifest's ``cpu``, ``features``, ``numba`` and
    ``llvmlite``) cannot run on ``here`` (`machine`); None if they can. A build for an
    instruction-set level (`LEVEL_FEATURES`) runs on any CPU model that reports every
    feature of the level; a build for a CPU model, only on that model with the same
    features (a virtual machine may hide some of its model's); either only under the
    numba and llvmlite that built it, whose code would otherwise no longer be bit for bit
    what the JIT compiles beside it."""
    cpu, features = built.get("cpu"), built.get("features")
    if cpu in LEVEL_FEATURES and isinstance(features, str):
        missing = sorted(_enabled(features) - _enabled(here["features"]))
        if missing:
            return (f"this CPU ({here['cpu']}) lacks {', '.join(missing)} of the "
                    f"instruction-set level {cpu} they were built for")
        differ = [k for k in ("numba", "llvmlite") if built.get(k) != here[k]]
    else:
        differ = [k for k in here if built.get(k) != here[k]]
    if not differ:
        return None
    named = ", ".join(f"{k} {built.get(k)!r} (here {here[k]!r})" for k in differ
                      if k != "features")
    return f"built for another machine or compiler ({named or 'CPU features'})"


def flags_key(flags: tuple[str, ...]) -> str:
    """The manifest's key for a set of CPU ``flags``."""
    return ",".join(flags)


def read_manifest(folder: Path | None = None) -> dict | None:
    """The manifest of the build in ``folder`` (default `AOT_DIR`), or None if it is
    missing or unreadable."""
    try:
        manifest = json.loads(((folder or AOT_DIR) / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    return manifest if isinstance(manifest, dict) else None


def _folder_names(folders: object) -> TypeGuard[list[str]]:
    """Whether a manifest's ``sources`` is a list of the package's own folders by name (a
    manifest is data: a path out of the package is not followed)."""
    return isinstance(folders, list) and all(
        isinstance(f, str) and (f == "" or f.isidentifier()) for f in folders)


def _load() -> dict[str, dict[str, dict[str, Callable]]]:
    """Import every module of a current build once, an upper level's (`UPPER_LEVELS`,
    highest first) where this CPU and its sources allow, else `AOT_DIR`'s; {} (and the
    reason in `_why_not`) when there is none, it is off, or it was built from other sources
    or for another platform, CPU or compiler."""
    global _why_not, _folder
    if os.environ.get(AOT_ENV, "1") in ("0", ""):
        _why_not = f"turned off ({AOT_ENV}=0)"
        return {}
    here = machine()
    for level in reversed(_levels_allowed()):
        upper = read_manifest(AOT_DIR / level)
        if upper is not None and upper.get("cpu") == level and _why_stale(upper, here) is None:
            found = _import_modules(AOT_DIR / level, upper)
            if found:
                _why_not, _folder = None, AOT_DIR / level
                return found
    _folder = AOT_DIR
    manifest = read_manifest()
    if manifest is None:
        _why_not = f"none built (no {AOT_DIR / MANIFEST})"
        return {}
    stale = _why_stale(manifest, here)
    if stale is not None:
        kind, _why_not = stale
        if kind == "cpu" and manifest.get("cpu") in LEVEL_FEATURES:
            from .notice import announce_no_build
            announce_no_build(_why_not)   # a portable build that cannot serve here: said once
        elif kind == "sources":
            logger.info("saddle_env: ahead-of-time kernels not used: %s", _why_not)
        return {}
    found = _import_modules(AOT_DIR, manifest)
    _why_not = None if found else "no module of the build could be loaded"
    return found


def _why_stale(manifest: Mapping[str, object], here: Mapping[str, str]) -> tuple[str, str] | None:
    """Why the build of ``manifest`` cannot serve this process, as (kind, reason) with kind
    "platform", "cpu" or "sources"; None if it can (`here`: `machine`)."""
    if manifest.get("platform") != platform_tag():
        return "platform", f"built for {manifest.get('platform')}, not {platform_tag()}"
    why = unusable(manifest, here)
    if why is not None:
        return "cpu", f"{why}; rebuild with python -m saddle_env.coldstart.precompile --aot"
    if not _from_these_sources(manifest):
        return "sources", ("built from other sources (the package changed since; rebuild "
                           "with python -m saddle_env.coldstart.precompile --aot)")
    return None


def _levels_allowed() -> tuple[str, ...]:
    """The `UPPER_LEVELS` whose builds this process may use (`AOT_LEVEL_ENV`); ValueError
    naming the variable and the levels for a value that is none of them."""
    cap = os.environ.get(AOT_LEVEL_ENV, "")
    if not cap:
        return UPPER_LEVELS
    levels = (BASELINE, *UPPER_LEVELS)
    if cap not in levels:
        raise ValueError(f"{AOT_LEVEL_ENV} must be one of {', '.join(levels)} (or unset), "
                         f"got {cap!r}")
    return UPPER_LEVELS[:levels.index(cap)]


def _from_these_sources(manifest: Mapping[str, object]) -> bool:
    """Whether the build of ``manifest`` was made from the package's sources in place."""
    folders = manifest.get("sources")
    return _folder_names(folders) and manifest.get("digest") == source_digest(folders)


def _import_modules(folder: Path, manifest: Mapping) -> dict[str, dict[str, dict[str, Callable]]]:
    """Import the modules of the build in ``folder``: flags tag → module → name → entry
    point ({} if none could be imported)."""
    found: dict[str, dict[str, dict[str, Callable]]] = {}
    for entry in manifest.get("modules", []):
        try:
            path = folder / entry["file"]
            spec = importlib.util.spec_from_file_location(
                f"saddle_env.compilation.aot.{entry['name']}", path)
            module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
            spec.loader.exec_module(module)  # type: ignore[union-attr]
            entries: dict[str, dict[str, Callable]] = {}
            types: dict[int, tuple[str, ...]] = {}
            threaded: dict[int, str] = {}
            for mod, names in entry["exports"].items():
                entries[mod] = {name: getattr(module, name) for name in names}
                for name in names:
                    types[id(entries[mod][name])] = tuple(entry["argtypes"][f"{mod}.{name}"])
                    if f"{mod}.{name}" in entry.get("threaded", ()):
                        threaded[id(entries[mod][name])] = str(path)
            key = flags_key(tuple(entry["flags"]))
        except (ImportError, OSError, KeyError, TypeError, AttributeError) as exc:
            logger.info("saddle_env: an ahead-of-time module of %s not loaded (%s: %s); "
                        "the JIT compiles its kernels", AOT_DIR, type(exc).__name__, exc)
            continue
        _argtypes.update(types)
        _threaded.update(threaded)
        found[key] = entries
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


def prepare(fn: Callable) -> bool:
    """Make ``fn``, an ahead-of-time entry point, ready to be called: one that runs on
    numba's threads has its module wired to numba's threading layer first
    (`aot_threads.wire`; only then, so a process that never steps on threads starts none).
    False if that failed (the caller then takes the JIT's copy)."""
    module_file = _threaded.get(id(fn))
    if module_file is None:
        return True
    from .aot_threads import wire
    try:
        wire(module_file)
    except (OSError, ValueError, RuntimeError, AttributeError) as exc:
        logger.info("saddle_env: the ahead-of-time threaded step of %s not used (%s: %s); "
                    "the JIT compiles it", module_file, type(exc).__name__, exc)
        return False
    return True


def status() -> str:
    """One line on whether ahead-of-time kernels are in use, and why not."""
    global _loaded
    if _loaded is None:
        _loaded = _load()
    if _loaded:
        return f"ahead-of-time kernels in use ({len(_loaded)} modules, {_folder})"
    return f"no ahead-of-time kernels: {_why_not}"
