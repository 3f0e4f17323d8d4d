"""The docstrings are numpydoc as the API page renders it (mkdocstrings, docstring_style:
numpy): a parameter's ``name : type`` on one line and its description indented on the next.
The one-line form ``x, y : float — description`` put the description into the rendered
table's Type column; tests/test_docs_site.py checks the rendered page itself (slow)."""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# name(s) : type — description, all on one line
ONE_LINE_ENTRY = re.compile(r"^\s+[A-Za-z_]\w*(?:, [A-Za-z_]\w*)* : [^\n]*? — ", re.MULTILINE)


def _docstrings(path: Path):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                yield getattr(node, "name", path.stem), doc


def test_the_pattern_finds_the_one_line_form():
    assert ONE_LINE_ENTRY.search("\n    x, y : float — contact point [m].\n")
    assert not ONE_LINE_ENTRY.search("\n    x, y : float\n        Contact point [m] — here.\n")


def test_no_docstring_has_a_one_line_parameter_entry():
    found = []
    for folder in ("saddle_env", "agents"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for name, doc in _docstrings(path):
                found += [f"{path.relative_to(ROOT)}: {name}: {m.group(0).strip()}"
                          for m in ONE_LINE_ENTRY.finditer(doc)]
    assert not found, "write name : type, then the description indented below:\n" + \
        "\n".join(found)
