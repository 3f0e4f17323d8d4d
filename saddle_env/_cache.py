"""Keep numba's on-disk cache honest in a source tree that is being edited.

numba checks a cached function against its *own* source file only. Our kernels inline
functions from other files (the rates of `_kernels` into `integrators`, `lockstep`,
`envs._step` and the baselines), so after an edit of `_kernels.py` alone the cached callers
would keep running the old physics — tests included. On import, a digest of every source
file that holds compiled code is compared with the one stored beside the cache; when they
differ, the package's in-tree cache files are removed and numba recompiles.

Installed copies are unaffected in practice: an upgrade rewrites every file, which numba
notices by itself. Trees that cannot be written (numba then caches elsewhere) are skipped.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent
# Packages whose compiled functions call into saddle_env's kernels.
_TREES = [_PACKAGE, _PACKAGE.parent / "agents"]
_STAMP = _PACKAGE / "__pycache__" / "numba-sources.sha256"


def _sources() -> list[Path]:
    """Every module of saddle_env (kernels freeze its constants too) and the modules of the
    other trees that compile code."""
    out = [p for p in _PACKAGE.rglob("*.py") if "__pycache__" not in p.parts]
    for tree in _TREES[1:]:
        if tree.is_dir():
            out += [p for p in tree.rglob("*.py")
                    if "__pycache__" not in p.parts and b"numba" in p.read_bytes()]
    return sorted(out)


def source_digest() -> str:
    h = hashlib.sha256()
    for path in _sources():
        h.update(str(path.relative_to(_PACKAGE.parent)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def refresh() -> bool:
    """Drop stale cache files if the sources changed since they were written; True if dropped."""
    try:
        digest = source_digest()
        if _STAMP.is_file() and _STAMP.read_text() == digest:
            return False
        clear()
        _STAMP.parent.mkdir(exist_ok=True)
        _STAMP.write_text(digest)
        return True
    except OSError:  # read-only install: numba keeps its cache elsewhere
        return False


def clear() -> None:
    """Remove the in-tree cache files (what a fresh install starts from)."""
    for tree in _TREES:
        if tree.is_dir():
            for pattern in ("*.nbi", "*.nbc"):
                for f in tree.rglob(pattern):
                    f.unlink(missing_ok=True)
