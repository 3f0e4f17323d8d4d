"""Modules that moved to another package: importing one by its old name, or running it with
``python -m``, fails with a message that names the new place, instead of numba's or
Python's bare "No module named ...". Nothing is re-exported under an old name: code keeps
one path per module."""

from __future__ import annotations

import importlib.abc
import sys
from collections.abc import Mapping


class MovedModuleError(ModuleNotFoundError):
    """A module asked for by a name it no longer has."""


class _MovedFinder(importlib.abc.MetaPathFinder):
    def __init__(self, moved: Mapping[str, str]):
        self.moved = dict(moved)

    def find_spec(self, fullname, path=None, target=None):
        new = self.moved.get(fullname)
        if new is None:
            return None
        raise MovedModuleError(
            f"{fullname} has moved to {new}: import {new}, or run `python -m {new}`",
            name=fullname)


def announce(moved: Mapping[str, str]) -> None:
    """Install a finder that names the new place of each old module name in ``moved``
    (old dotted name → new dotted name). Called by a package's ``__init__``."""
    for finder in sys.meta_path:
        if isinstance(finder, _MovedFinder):
            finder.moved.update(moved)
            return
    sys.meta_path.insert(0, _MovedFinder(moved))
