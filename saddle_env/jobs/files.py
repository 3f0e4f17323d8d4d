"""Result files written whole or not at all: each goes to a temporary file beside its place
and is renamed over it once complete (a rename within one folder is atomic), so a run
stopped by Ctrl-C, SIGTERM or a crash in the middle of a write leaves the previous file, or
none, and no half of one. The figures' outputs, the benchmark's and the leaderboard's
results and the best-constant cache are all written through here."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


@contextmanager
def atomic_open(path: str | Path, mode: str = "w") -> Iterator[Any]:
    """Open a temporary file next to ``path`` (``mode`` "w" or "wb"); rename it over
    ``path`` when the block ends normally, and delete it when the block raises."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    text_args: dict[str, Any] = {"newline": ""} if "b" not in mode else {}
    try:
        with os.fdopen(fd, mode, **text_args) as fh:
            yield fh
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; outputs are ordinary readable files
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_text_atomically(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` whole (`atomic_open`); return the path."""
    with atomic_open(path) as fh:
        fh.write(text)
    return Path(path)


__all__ = ["atomic_open", "write_text_atomically"]
