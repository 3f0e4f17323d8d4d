"""Keep numba's on-disk cache honest, one source file at a time.

numba checks a cached function against its *own* source file only (numba 0.68: a hash of
the file's content; earlier versions its time stamp and size). Our compiled functions call
functions of other files, and numba links the callees' code into each caller's cached
object: after an edit of `kernels.py` alone the cached callers in `integrators`,
`lockstep`, `envs.control_step` and `agents` would keep running the old physics. They also freeze
module constants (`scene.P_A`, ...) as they compile.

So on import, every module of the package gets a digest of its own source and of every
module it imports from the package, directly or not. A module whose digest changed since
the stamp was written has its cache files removed; the others keep theirs. An upgrade, or
a ``git pull``, that changes one kernel file then recompiles what depends on it and nothing
else: a change to `envs/control_step.py` recompiles only the environment's step, one to
`kernels.py` everything compiled, since everything calls it (tests/test_cache.py).

Another package whose compiled functions call the kernels (`agents.control`'s look-ahead)
calls `refresh` for its own tree on its import, naming this package's tree as one it
depends on: its modules' digests then cover the kernels they import, and this module
names no package above it.

A tree that can be imported under two names (the repository's `agents/`: `agents` from a
clone, `saddle_agents` once installed) passes the name it was imported by: numba's cached
code names its module, and loads it by that name, so code cached under one name fails in a
process that cannot import the other (a console script, after ``python train.py``). Its
caches go whenever the name changes; recompiling them takes a second or two.

Trees that cannot be written (numba then caches elsewhere, and an upgrade rewrites every
file, which numba notices by itself) are skipped.
"""

from __future__ import annotations

import ast
import hashlib
import json
from collections.abc import Sequence
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1]  # saddle_env/
# Where a tree's stamp is kept, inside the tree: the digests its `refresh` last saw.
_STAMP_FILE = Path("__pycache__") / "numba-sources.json"
# The stamp's key for the import graph it was computed from (`_graph`); every other key is a
# module's digest (a stamp written before the graph was kept has no such key).
_GRAPH_KEY = "(import graph)"
# The stamp's key for the name the tree's modules were last imported by (`refresh`'s
# ``import_name``).
_NAME_KEY = "(import name)"


def _module_name(path: Path, tree: Path) -> str:
    rel = path.relative_to(tree.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _sources(trees: Sequence[Path]) -> dict[str, Path]:
    """Module name -> file, for every module of the trees (packages' folders)."""
    out = {}
    for tree in trees:
        if tree.is_dir():
            for p in tree.rglob("*.py"):
                if "__pycache__" not in p.parts:
                    out[_module_name(p, tree)] = p
    return out


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The modules of the trees that ``name`` imports, absolute or relative. (Python also
    runs the packages' ``__init__`` on the way; they hold no compiled code and are not
    counted, or every module would depend on everything ``saddle_env/__init__`` imports.)"""
    is_pkg = path.name == "__init__.py"
    package = name if is_pkg else name.rpartition(".")[0]
    found: set[str] = set()
    try:
        tree = ast.parse(path.read_bytes())
    except (SyntaxError, ValueError):
        return found
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name in modules)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                root = ".".join(base + ([node.module] if node.module else []))
            else:
                root = node.module or ""
            for a in node.names:
                # ``from pkg import mod`` is the submodule; ``from pkg import name`` the
                # package's ``__init__`` (which re-exports from its own imports)
                sub = f"{root}.{a.name}"
                if sub in modules:
                    found.add(sub)
                elif root in modules:
                    found.add(root)
    found.discard(name)
    return found


def _graph(modules: dict[str, Path], known: dict) -> dict:
    """Each module's own digest and the modules it imports (`_imports`), parsing only the
    files whose content changed since ``known`` (the same record from the stamp): parsing
    every file was a large part of each ``import saddle_env``. A new
    or removed module re-parses them all (it can change what an import names)."""
    names = hashlib.sha256("\n".join(sorted(modules)).encode()).hexdigest()
    reuse = known.get("modules") == names
    files = {}
    for m, p in modules.items():
        own = hashlib.sha256(p.read_bytes()).hexdigest()
        seen = known.get("files", {}).get(m) if reuse else None
        if seen and seen[0] == own:
            files[m] = seen
        else:
            files[m] = [own, sorted(_imports(m, p, modules))]
    return {"modules": names, "files": files}


def digests(graph: dict | None = None) -> dict[str, str]:
    """Module name -> digest of its source and of every source it depends on (from
    ``graph``, a `_graph` record; by default made afresh)."""
    # The graph's own module list: walking the source tree again would repeat `refresh`'s walk.
    files = (graph or _graph(_sources([PACKAGE]), {}))["files"]
    direct = {m: files[m][1] for m in files}
    own = {m: files[m][0] for m in files}
    out = {}
    for m in files:
        seen, todo = {m}, [m]
        while todo:
            for dep in direct[todo.pop()]:
                if dep not in seen:
                    seen.add(dep)
                    todo.append(dep)
        h = hashlib.sha256()
        for dep in sorted(seen):
            h.update(f"{dep}:{own[dep]}\n".encode())
        out[m] = h.hexdigest()
    return out


def _cache_files(path: Path) -> list[Path]:
    """numba's cache files for the functions of one source file
    (``__pycache__/<stem>.<function>-<line>.py<ver>.nbi`` / ``.nbc``)."""
    cache = path.parent / "__pycache__"
    stem = "__init__" if path.name == "__init__.py" else path.stem
    return [f for pattern in (f"{stem}.*.nbi", f"{stem}.*.nbc") for f in cache.glob(pattern)]


def refresh(tree: Path = PACKAGE, depends_on: Sequence[Path] = (),
            import_name: str | None = None) -> list[str]:
    """Drop the cache files of every module of ``tree`` whose sources changed since the
    tree's stamp was written, counting the sources it imports from the trees of
    ``depends_on`` too, and of all its modules if ``import_name`` (the name the tree is
    imported by now) is not the one the stamp holds; return those modules' names (empty if
    nothing was dropped)."""
    stamp_path = tree / _STAMP_FILE
    try:
        try:
            stamp = json.loads(stamp_path.read_text())
        except (OSError, ValueError):
            stamp = {}
        stamp = stamp if isinstance(stamp, dict) else {}
        known = stamp.get(_GRAPH_KEY, {})
        renamed = stamp.get(_NAME_KEY) != import_name
        before = {} if renamed else {m: d for m, d in stamp.items()
                                     if m not in (_GRAPH_KEY, _NAME_KEY)}
        modules = _sources([tree, *depends_on])
        graph = _graph(modules, known)
        own = {m for m, p in modules.items() if tree in p.parents}
        now = {m: d for m, d in digests(graph).items() if m in own}
        if before == now and known == graph and not renamed:
            return []
        stale = sorted(m for m in now if before.get(m) != now[m])
        for m in stale:
            for f in _cache_files(modules[m]):
                f.unlink(missing_ok=True)
        stamp_path.parent.mkdir(exist_ok=True)
        named = {} if import_name is None else {_NAME_KEY: import_name}
        stamp_path.write_text(json.dumps({**now, _GRAPH_KEY: graph, **named}, indent=0,
                                         sort_keys=True))
        return stale
    except OSError:  # read-only install: numba keeps its cache elsewhere
        return []


def clear(trees: Sequence[Path] = (PACKAGE,)) -> None:
    """Remove the in-tree cache files of ``trees`` (what a fresh install starts from)."""
    for tree in trees:
        if tree.is_dir():
            for pattern in ("*.nbi", "*.nbc"):
                for f in tree.rglob(pattern):
                    f.unlink(missing_ok=True)
