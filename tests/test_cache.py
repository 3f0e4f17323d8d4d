"""saddle_env.compilation.cache drops the numba cache files of exactly the modules whose sources, or
the sources they import, changed: an upgrade that changes one kernel file recompiles only what
depends on it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

from saddle_env.compilation import cache as _cache


def _tree(tmp_path, monkeypatch):
    """A package with the real import structure in miniature: kernels <- integrators <-
    envs.control_step, a module nothing compiled imports, and agents/mpc importing the kernels."""
    pkg = tmp_path / "saddle_env"
    (pkg / "envs").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from . import integrators\nfrom .envs import control_step\n")
    (pkg / "scene.py").write_text("P_A = 0\n")
    (pkg / "kernels.py").write_text("from .scene import P_A\nx = 1\n")
    (pkg / "integrators.py").write_text("from .kernels import x\n")
    (pkg / "linear.py").write_text("import math\n")
    (pkg / "envs" / "__init__.py").write_text("")
    (pkg / "envs" / "control_step.py").write_text("from .. import kernels as K\n"
                                                  "from ..integrators import x\n")
    other = tmp_path / "agents"
    other.mkdir()
    (other / "mpc.py").write_text("import numba\nfrom saddle_env.kernels import x\n")
    return pkg, other


def _refresh(pkg, other):
    """What the two imports do: the package's refresh, then the other tree's, which names
    the package as a tree it depends on (as `agents.control` does)."""
    return _cache.refresh(pkg) + _cache.refresh(other, depends_on=[pkg])


def _cached(path):
    """Fake numba cache files for one function of the source file ``path``."""
    cache = path.parent / "__pycache__"
    cache.mkdir(exist_ok=True)
    (cache / f"{path.stem}.f-1.py311.nbi").write_text("index")
    (cache / f"{path.stem}.f-1.py311.1.nbc").write_text("code")


def _modules(stale):
    """The stale modules other than packages (an ``__init__`` holds no compiled code, and
    the package's imports everything)."""
    return set(stale) - {"saddle_env", "saddle_env.envs"}


def _has_cache(path):
    return len(list((path.parent / "__pycache__").glob(f"{path.stem}.*.nb?"))) == 2


def test_dependencies_follow_the_imports(tmp_path, monkeypatch):
    pkg, other = _tree(tmp_path, monkeypatch)
    mods = _cache._sources([pkg, other])
    deps = {m: _cache._imports(m, p, mods) for m, p in mods.items()}
    assert deps["saddle_env.kernels"] == {"saddle_env.scene"}
    assert deps["saddle_env.envs.control_step"] == {"saddle_env.kernels", "saddle_env.integrators"}
    assert deps["agents.mpc"] == {"saddle_env.kernels"}
    # the package __init__ is not a dependency of its modules (it imports everything)
    assert "saddle_env" not in set().union(*deps.values())


def test_a_changed_file_drops_only_its_own_and_its_dependents_caches(tmp_path, monkeypatch):
    pkg, other = _tree(tmp_path, monkeypatch)
    files = {name: pkg / name for name in ("kernels.py", "integrators.py", "linear.py")}
    files["step"] = pkg / "envs" / "control_step.py"
    files["mpc"] = other / "mpc.py"
    assert _refresh(pkg, other)  # no stamp yet: every module is new
    for f in files.values():
        _cached(f)
    assert _refresh(pkg, other) == [] and all(_has_cache(f) for f in files.values())

    # The environment's step changes: only its own cache goes.
    files["step"].write_text(files["step"].read_text() + "y = 2\n")
    assert _modules(_refresh(pkg, other)) == {"saddle_env.envs.control_step"}
    assert not _has_cache(files["step"])
    assert all(_has_cache(f) for k, f in files.items() if k != "step")

    # A module nothing compiled imports: nobody else's cache goes.
    _cached(files["step"])
    files["linear.py"].write_text("import math  # edited\n")
    assert _modules(_refresh(pkg, other)) == {"saddle_env.linear"}
    assert all(_has_cache(f) for k, f in files.items() if k != "linear.py")

    # The kernels change: every module that imports them, directly or not, recompiles.
    _cached(files["linear.py"])
    files["kernels.py"].write_text("from .scene import P_A\nx = 2\n")
    assert _modules(_refresh(pkg, other)) == {"saddle_env.kernels", "saddle_env.integrators",
                                              "saddle_env.envs.control_step", "agents.mpc"}
    assert _has_cache(files["linear.py"])
    assert not any(_has_cache(f) for k, f in files.items() if k != "linear.py")

    # A constant module the kernels freeze (scene.py): the same.
    for f in files.values():
        _cached(f)
    (pkg / "scene.py").write_text("P_A = 1\n")
    assert "saddle_env.integrators" in _refresh(pkg, other)
    assert not _has_cache(files["integrators.py"]) and _has_cache(files["linear.py"])


def test_another_tree_is_refreshed_only_by_its_own_call(tmp_path, monkeypatch):
    """The package's refresh reads no tree but its own (it names no package above it); the
    other tree's call, naming the package as a dependency, drops its stale caches."""
    pkg, other = _tree(tmp_path, monkeypatch)
    _refresh(pkg, other)
    _cached(other / "mpc.py")
    (pkg / "kernels.py").write_text("from .scene import P_A\nx = 2\n")
    assert "agents.mpc" not in _cache.refresh(pkg) and _has_cache(other / "mpc.py")
    assert _cache.refresh(other, depends_on=[pkg]) == ["agents.mpc"]
    assert not _has_cache(other / "mpc.py")


def test_a_tree_imported_under_another_name_drops_its_caches(tmp_path, monkeypatch):
    """numba's cached code loads its module by the name it was compiled under: a tree
    imported by another name than its stamp's (`agents` from a clone, `saddle_agents`
    installed) drops all its caches, once; the same name again keeps them."""
    pkg, other = _tree(tmp_path, monkeypatch)
    _cache.refresh(pkg)
    assert _cache.refresh(other, depends_on=[pkg], import_name="agents") == ["agents.mpc"]
    _cached(other / "mpc.py")
    assert _cache.refresh(other, depends_on=[pkg], import_name="agents") == []
    assert _has_cache(other / "mpc.py")
    assert _cache.refresh(other, depends_on=[pkg], import_name="saddle_agents") == ["agents.mpc"]
    assert not _has_cache(other / "mpc.py")
    _cached(other / "mpc.py")
    assert _cache.refresh(other, depends_on=[pkg], import_name="saddle_agents") == []
    assert _has_cache(other / "mpc.py")


def test_only_a_changed_file_is_parsed_again_and_its_new_imports_count(tmp_path, monkeypatch):
    """The stamp keeps the import graph: an import parses no file whose content it knows
    (parsing all of them was a third of ``import saddle_env``), and a file whose imports
    changed is parsed again, so the modules it now depends on make it stale."""
    pkg, _ = _tree(tmp_path, monkeypatch)
    _cache.refresh(pkg)
    parsed = []
    parse = _cache._imports
    monkeypatch.setattr(_cache, "_imports", lambda m, p, mods: parsed.append(m) or parse(m, p, mods))
    assert _cache.refresh(pkg) == [] and parsed == []
    (pkg / "linear.py").write_text("import math\nfrom .integrators import x\n")
    assert _modules(_cache.refresh(pkg)) == {"saddle_env.linear"}
    assert parsed == ["saddle_env.linear"]
    _cached(pkg / "linear.py")
    (pkg / "kernels.py").write_text("from .scene import P_A\nx = 2\n")
    assert "saddle_env.linear" in _cache.refresh(pkg) and not _has_cache(pkg / "linear.py")
    (pkg / "new.py").write_text("")  # a new module: every file parsed again
    parsed.clear()
    _cache.refresh(pkg)
    assert len(parsed) == len(_cache._sources([pkg]))


def test_touching_a_file_keeps_the_stamp_valid(tmp_path, monkeypatch):
    """A new time stamp with the same content (a reinstall, a checkout) drops nothing here;
    numba itself recompiles that one file's functions, whose index holds the stamp."""
    pkg, _ = _tree(tmp_path, monkeypatch)
    _cache.refresh(pkg)
    _cached(pkg / "integrators.py")
    os.utime(pkg / "kernels.py", (1, 1))
    assert _cache.refresh(pkg) == [] and _has_cache(pkg / "integrators.py")
    assert json.loads((pkg / _cache._STAMP_FILE).read_text())["saddle_env.integrators"]


_TWO_FILES = {
    "a.py": """
        import numba
        @numba.njit(cache=True)
        def f(x):
            return x + 1.0
        """,
    "b.py": """
        import numba
        @numba.njit(cache=True)
        def g(x):
            return x * 2.0
        """,
    "run.py": """
        import a, b
        a.f(1.0); b.g(1.0)
        print(a.f.stats.cache_hits.total(), b.g.stats.cache_hits.total())
        """,
}


@pytest.mark.slow
def test_numba_recompiles_only_the_changed_file(tmp_path):
    """What the layer above relies on: numba keys each file's cache on that file's own
    source (numba 0.68: a hash of its content, formerly its time stamp and size), so a
    changed file leaves the other file's cached functions loading, and a touched one (same
    content, new time stamp: a reinstall) leaves its own loading too."""
    for name, src in _TWO_FILES.items():
        (tmp_path / name).write_text(textwrap.dedent(src))

    def hits():
        out = subprocess.run([sys.executable, "run.py"], cwd=tmp_path, check=True,
                             capture_output=True, text=True).stdout.split()
        return int(out[0]), int(out[1])

    assert hits() == (0, 0)  # compiled and cached
    assert hits() == (1, 1)  # both loaded
    st = (tmp_path / "a.py").stat()
    os.utime(tmp_path / "a.py", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert hits() == (1, 1)  # touched: still loaded
    with open(tmp_path / "a.py", "a") as f:
        f.write("# changed\n")
    assert hits() == (0, 1)  # a.py recompiled, b.py still loaded
