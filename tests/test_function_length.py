"""Functions of one screen: no function or method in the packages is over MAX_LINES lines.

Counting rule: a function's length is ``end_lineno - lineno + 1`` of its ``ast`` node, from
its ``def`` line (decorators not counted) to its last line, docstring, comments and blank
lines inside it included. A nested function counts within its enclosing one and is also
measured on its own.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Every Python file outside tests/: the two packages (pyproject.toml's packages: saddle_env
# and agents, installed as saddle_agents) and the scripts (train.py, setup.py, the docs
# site's hooks, CI's wheel check).
SOURCES = ("saddle_env", "agents", "train.py", "setup.py", "docs/hooks.py", ".ci")
MAX_LINES = 100
def _files() -> list[Path]:
    out: list[Path] = []
    for name in SOURCES:
        path = ROOT / name
        out += sorted(path.rglob("*.py")) if path.is_dir() else [path]
    return out


def function_lengths(path: Path, root: Path = ROOT) -> dict[str, int]:
    """``"<path from root>::<Class.>name"`` → length in lines (the counting rule above)."""
    rel = path.relative_to(root).as_posix()
    out: dict[str, int] = {}

    def walk(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                assert child.end_lineno is not None
                out[f"{rel}::{prefix}{child.name}"] = child.end_lineno - child.lineno + 1
                walk(child, f"{prefix}{child.name}.")
            elif isinstance(child, ast.ClassDef):
                walk(child, f"{prefix}{child.name}.")
            else:
                walk(child, prefix)

    walk(ast.parse(path.read_text(encoding="utf-8")), "")
    return out


def _all_lengths() -> dict[str, int]:
    out: dict[str, int] = {}
    for path in _files():
        out.update(function_lengths(path))
    return out


def test_the_sources_are_found():
    lengths = _all_lengths()
    files = _files()
    assert len(files) > 100 and all(path.is_file() for path in files)
    assert "saddle_env/envs/config.py::EnvConfig.__post_init__" in lengths


def test_no_function_is_over_one_screen():
    too_long = {name: n for name, n in _all_lengths().items()
                if n > MAX_LINES}
    assert not too_long, (f"functions over {MAX_LINES} lines (split them into helpers of one "
                          f"purpose each): {too_long}")


def test_the_count_follows_the_rule(tmp_path):
    """The rule on a known function: def line to last line, docstring and blanks counted,
    decorator not; a nested function measured on its own too."""
    src = ('@staticmethod\n'
           'def outer():\n'
           '    """Doc."""\n'
           '\n'
           '    def inner():\n'
           '        return 1\n'
           '    return inner\n'
           'class C:\n'
           '    def m(self):\n'
           '        pass\n')
    path = tmp_path / "probe.py"
    path.write_text(src)
    assert function_lengths(path, tmp_path) == {"probe.py::outer": 6, "probe.py::outer.inner": 2,
                                                "probe.py::C.m": 2}
