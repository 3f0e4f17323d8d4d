"""The project's modules import each other without a circle, and only down its layers
(`LAYERS`).

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


# The layers of the project, lowest first: a module may import from its own layer and the
# layers below it, never from one above (function-local imports included). An entry names a
# module or a package (and everything inside it); a module belongs to the longest entry that
# names it or a package around it. CONTRIBUTING.md ("The layers") shows this table to people.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("foundations: data, constants and files",
     ("saddle_env._moved", "saddle_env.scene", "saddle_env.jobs")),
    ("compilation: numba, the on-disk cache, the install's build loaded",
     ("saddle_env.compilation",)),
    ("the simulator: kernels, integrators, simulate, prediction",
     ("saddle_env.kernels", "saddle_env.omega", "saddle_env.linear",
      "saddle_env.rk", "saddle_env.integrators", "saddle_env.lockstep", "saddle_env.blockstep",
      "saddle_env.runner",
      "saddle_env.accuracy", "saddle_env.simulate", "saddle_env.prediction",
      "saddle_env.iontrap")),
    # the lab's data and the calibrated real-saddle model: SaddleTrap-RealSaddle-v0 is built
    # from them (issue 57); the calibration's tools stay with the tools
    ("the real-saddle model: the lab's data and the calibrated model",
     ("saddle_env.lifetimes",)),
    ("the environments", ("saddle_env.envs",)),
    ("saddle_env's public face", ("saddle_env",)),
    ("tools on the simulator and the environments",
     ("saddle_env.coldstart", "saddle_env.workprecision", "saddle_env.calibrate", "saddle_env.cli",
      "saddle_env.deploy", "saddle_env.reproduce", "saddle_env.rig",
      *(f"saddle_env.lifetimes.{m}" for m in ("cli", "coverage", "figure", "fit", "grid",
                                              "report", "sizes", "timing")))),
    ("agents: seeds, paths and shared command-line options",
     ("agents", "agents.seeds", "agents.paths", "agents.cli_args")),
    ("agents: controllers", ("agents.control",)),
    ("agents: evaluation", ("agents.evaluation",)),
    ("agents: training", ("agents.training",)),
    ("agents: the benchmark and the figure store",
     ("agents.benchmark", "agents.figures", "agents.remeasure")),
    ("the training script", ("train",)),
)


def layer_of(module: str, layers=LAYERS) -> int | None:
    """The rank of ``module``'s layer (0 is the lowest), or None if no entry names it."""
    best: tuple[int, int] | None = None  # (length of the entry, rank)
    for rank, (_, entries) in enumerate(layers):
        for entry in entries:
            if (module == entry or module.startswith(entry + ".")) \
                    and (best is None or len(entry) > best[0]):
                best = (len(entry), rank)
    return None if best is None else best[1]


def _named_imports(module: str, path: Path, modules: dict[str, Path]) -> list[tuple[str, int]]:
    """(project module, line) for every import statement of ``module``, at any depth: the
    module each statement names (``from pkg import sub`` names pkg.sub when it is a module,
    otherwise pkg itself). Unlike `import_graph`, an import of an enclosing package counts:
    ``import saddle_env`` inside saddle_env.compilation reads saddle_env's public face."""
    is_package = path.name == "__init__.py"
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(module, is_package, node)
            names = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base
                     for alias in node.names]
        else:
            continue
        targets = {t for name in names if (t := _target(name, modules)) not in (None, module)}
        out += [(target, node.lineno) for target in sorted(targets)]
    return out


def upward_imports(modules: dict[str, Path], layers=LAYERS) -> list[str]:
    """Every import from a lower layer into a higher one, as "file:line a -> b"."""
    wrong = []
    for module, path in modules.items():
        own = layer_of(module, layers)
        for target, line in _named_imports(module, path, modules):
            theirs = layer_of(target, layers)
            if own is not None and theirs is not None and theirs > own:
                wrong.append(f"{path.relative_to(path.parents[len(module.split('.')) - 1])}"
                             f":{line} {module} ({layers[own][0]}) -> {target} "
                             f"({layers[theirs][0]})")
    return wrong


def test_imports_point_only_down_the_layers():
    wrong = upward_imports(module_files())
    assert not wrong, "a lower layer imports a higher one:\n" + "\n".join(wrong)


def unplaced(modules, layers=LAYERS) -> list[str]:
    """The modules no entry names: those of no entry, and those that fall only into their
    root package's entry (saddle_env's public face, agents' foundations) without being that
    package. They would escape `upward_imports`."""
    def named(m: str) -> bool:
        return any(m == e or m.startswith(e + ".") for _, es in layers for e in es if "." in e)

    return [m for m in modules if layer_of(m, layers) is None or ("." in m and not named(m))]


def test_every_module_has_a_layer():
    missing = unplaced(module_files())
    assert not missing, f"add these modules to a layer of LAYERS: {missing}"
    assert unplaced(["saddle_env.new", "agents.new", "agents.control.new", "elsewhere"]) \
        == ["saddle_env.new", "agents.new", "elsewhere"]


def test_the_layering_check_catches_an_upward_import(tmp_path):
    """A synthetic package: upward imports of every form (inside a function and relative,
    ``import`` of the package itself, ``from ... import`` at module level) are caught, and
    the downward and sideways ones are not."""
    pkg = tmp_path / "saddle_env"
    (pkg / "compilation").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from .compilation import jit\n")
    (pkg / "compilation" / "__init__.py").write_text("")
    (pkg / "compilation" / "jit.py").write_text("def f():\n    from .. import envs\n")
    (pkg / "compilation" / "ok.py").write_text("from . import jit\n")
    (pkg / "envs.py").write_text("from .compilation.jit import f\n"
                                 "from saddle_env.tool import t\n")
    (pkg / "tool.py").write_text("import saddle_env.envs\nt = 1\n")
    (pkg / "low.py").write_text("def g():\n    import saddle_env\n")
    layers = (("low", ("saddle_env.low",)), ("compilation", ("saddle_env.compilation",)),
              ("envs", ("saddle_env.envs",)), ("face", ("saddle_env",)),
              ("tools", ("saddle_env.tool",)))
    wrong = upward_imports(module_files(tmp_path), layers)
    assert sorted(wrong) == [
        "saddle_env/compilation/jit.py:2 saddle_env.compilation.jit (compilation) -> "
        "saddle_env.envs (envs)",
        "saddle_env/envs.py:2 saddle_env.envs (envs) -> saddle_env.tool (tools)",
        "saddle_env/low.py:2 saddle_env.low (low) -> saddle_env (face)"]


def test_agents_sit_above_the_physics_and_in_order():
    """The table itself: the check above would pass trivially if it placed nothing."""
    assert layer_of("saddle_env.compilation.cache") < layer_of("saddle_env.kernels") \
        < layer_of("saddle_env.envs.engine") < layer_of("saddle_env") \
        < layer_of("saddle_env.coldstart.precompile") < layer_of("agents.seeds")
    assert layer_of("agents.control.mpc") < layer_of("agents.evaluation.policies") \
        < layer_of("agents.training.backends.sb3") < layer_of("agents.benchmark.leaderboard") \
        < layer_of("train")
    assert layer_of("agents") == layer_of("agents.seeds")


def test_contributing_shows_the_layers_in_order():
    """CONTRIBUTING.md's "The layers" names every entry of `LAYERS` (in full or by its last
    part), each layer after the one below it."""
    text = (ROOT / "CONTRIBUTING.md").read_text(encoding="utf-8")
    section = text.split("## The layers\n", 1)[1].split("\n## ", 1)[0]

    def where(entry: str) -> int:
        spellings = [f"`{entry}`", f"`{entry.rpartition('.')[2]}`", f"`{entry}.py`"]
        found = [section.find(s) for s in spellings if s in section]
        assert found, f"CONTRIBUTING.md's layers do not name {entry}"
        return min(found)

    first = [min(where(e) for e in entries) for _, entries in LAYERS]
    assert first == sorted(first), [name for name, _ in LAYERS]


# saddle_env holds the simulator layer's modules, one job each (16 since the shared-step batch,
# `blockstep`, joined the one-step block, `lockstep`)
@pytest.mark.parametrize("folder, most", [("saddle_env", 16), *(
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
                                       "saddle_env.coldstart.precompile"),
                                      ("saddle_env.compilation.profile",
                                       "saddle_env.coldstart.profile"),
                                      ("saddle_env.files", "saddle_env.jobs.files"),
                                      ("saddle_env.bench", "saddle_env.workprecision"),
                                      ("saddle_env._kernels", "saddle_env.kernels"),
                                      ("saddle_env.envs._step", "saddle_env.envs.control_step")])
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
