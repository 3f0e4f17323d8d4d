"""The project's modules import each other without a circle.

Every import statement of ``saddle_env/**``, ``agents/**`` and ``train.py`` is read with
`ast`, function-local imports included (a local import only postpones a circle to run time;
it does not remove the knot a reader has to untie). An edge A → B means A imports B, or a
name from B, or B's package ``__init__`` runs first because A imports something inside the
package. A module reading from a package that encloses it (``from . import x`` inside the
package) adds no edge: that package's ``__init__`` is already running when the module is
imported.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("saddle_env", "agents")
SCRIPTS = ("train.py",)


def module_files(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name → file, for every module of the project."""
    out = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    for script in SCRIPTS:
        if (root / script).is_file():
            out[Path(script).stem] = root / script
    return out


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The absolute module an ``from ... import`` statement reads from."""
    if node.level == 0:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _target(name: str, modules: dict[str, Path]) -> str | None:
    """The project module ``name`` refers to (a module, or a name inside one), or None."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Module → the project modules it imports (every import statement, at any depth)."""
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for module, path in modules.items():
        is_package = path.name == "__init__.py"
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = _resolve(module, is_package, node)
                # "from pkg import sub" imports the submodule pkg.sub when there is one.
                names = [f"{base}.{alias.name}" for alias in node.names] + [base]
            for name in names:
                target = _target(name, modules)
                if target is None or target == module or module.startswith(target + "."):
                    continue  # a package enclosing the importer has already started running
                graph[module].add(target)
                # Importing pkg.sub runs pkg/__init__ first: an edge to every enclosing
                # package, unless the importer lives inside it (then it is already running).
                parent = target.rpartition(".")[0]
                while parent:
                    if parent in modules and not module.startswith(parent + ".") \
                            and parent != module:
                        graph[module].add(parent)
                    parent = parent.rpartition(".")[0]
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle (its modules, the first repeated at the end), or None."""
    WHITE, GREY, BLACK = 0, 1, 2
    colour = dict.fromkeys(graph, WHITE)
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        colour[node] = GREY
        stack.append(node)
        for nxt in sorted(graph[node]):
            if colour[nxt] == GREY:
                return stack[stack.index(nxt):] + [nxt]
            if colour[nxt] == WHITE:
                found = visit(nxt)
                if found:
                    return found
        stack.pop()
        colour[node] = BLACK
        return None

    for node in sorted(graph):
        if colour[node] == WHITE:
            found = visit(node)
            if found:
                return found
    return None


def test_no_import_circle():
    graph = import_graph(module_files())
    cycle = find_cycle(graph)
    assert cycle is None, "import circle: " + " -> ".join(cycle)


def test_the_graph_sees_local_and_relative_imports(tmp_path):
    """The checker finds a circle closed by a function-local relative import (the kind the
    old agents.baselines <-> agents.evaluation.evaluate and saddle_env.accuracy <-> simulate were)."""
    pkg = tmp_path / "agents"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from .b import g\n\ndef f():\n    return g()\n")
    (pkg / "b.py").write_text("def g():\n    from .a import f\n    return f\n")
    (pkg / "c.py").write_text("from . import a\n")
    graph = import_graph(module_files(tmp_path))
    assert graph["agents.a"] == {"agents.b"} and graph["agents.b"] == {"agents.a"}
    assert "agents.a" in graph["agents.c"]
    cycle = find_cycle(graph)
    assert cycle is not None and set(cycle) == {"agents.a", "agents.b"}


@pytest.mark.parametrize("importer, imported", [("agents.evaluation.evaluate", "agents.evaluation.policies"),
                                                ("saddle_env.simulate", "saddle_env.accuracy"),
                                                ("train", "agents.training.trainer")])
def test_the_graph_has_the_edges_it_should(importer, imported):
    """A checker that saw no imports would pass the first test trivially."""
    assert imported in import_graph(module_files())[importer]


# The rooms of `agents`, lowest first: a module may import from its own room and the rooms
# before it, never from a later one (agents/__init__.py says why each room is where it is).
AGENT_LAYERS = (("agents", "agents.seeds", "agents.paths", "agents.cli_args"),
                ("agents.control",), ("agents.evaluation",), ("agents.training",),
                ("agents.benchmark",))


def _layer(module: str) -> int | None:
    found = None
    for rank, prefixes in enumerate(AGENT_LAYERS):
        if any(module == p or (p != "agents" and module.startswith(p + ".")) for p in prefixes):
            found = rank
    return found


def test_the_agents_rooms_import_one_way():
    graph = import_graph(module_files())
    wrong = [f"{a} -> {b}" for a, targets in graph.items() for b in targets
             if _layer(a) is not None and _layer(b) is not None and _layer(b) > _layer(a)]
    assert not wrong, "a lower room of agents imports a higher one: " + ", ".join(wrong)
    physics_to_agents = [f"{a} -> {b}" for a, targets in graph.items() for b in targets
                         if a.startswith("saddle_env") and b.startswith("agents")]
    assert not physics_to_agents, ", ".join(physics_to_agents)


def test_the_layering_check_sees_an_upward_import():
    """The check above would pass trivially if `_layer` placed nothing."""
    assert _layer("agents.control.mpc") < _layer("agents.evaluation.policies") \
        < _layer("agents.training.backends.sb3") < _layer("agents.benchmark.leaderboard")
    assert _layer("agents.seeds") == 0 and _layer("agents.control") == 1


@pytest.mark.parametrize("folder, most", [("saddle_env", 15), *(
    (str(p.relative_to(ROOT)), 12) for p in sorted((ROOT / "agents").rglob("*"))
    if p.is_dir() and (p / "__init__.py").is_file())])
def test_a_folder_holds_few_modules(folder, most):
    modules = [p.name for p in (ROOT / folder).glob("*.py")]
    assert len(modules) <= most, f"{folder} holds {len(modules)} modules: {sorted(modules)}"


def test_no_module_is_over_900_lines():
    long = {str(p.relative_to(ROOT)): n for p in module_files().values()
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > 900}
    assert not long, long


@pytest.mark.parametrize("old, new", [("agents.leaderboard", "agents.benchmark.leaderboard"),
                                      ("agents.mpc", "agents.control.mpc"),
                                      ("saddle_env.precompile",
                                       "saddle_env.compilation.precompile"),
                                      ("saddle_env.files", "saddle_env.jobs.files")])
def test_an_old_module_name_says_where_the_module_went(old, new):
    import importlib
    import importlib.util

    import agents  # noqa: F401  (its __init__ names the moved modules)
    with pytest.raises(ModuleNotFoundError, match=f"{old} has moved to {new}"):
        importlib.import_module(old)
    assert importlib.util.find_spec(new) is not None


def test_every_moved_name_points_at_a_module():
    import importlib.util

    import agents  # noqa: F401
    from saddle_env import _moved
    finder = next(f for f in __import__("sys").meta_path if isinstance(f, _moved._MovedFinder))
    missing = [new for new in finder.moved.values()
               if " " not in new and importlib.util.find_spec(new) is None]
    assert not missing, missing
