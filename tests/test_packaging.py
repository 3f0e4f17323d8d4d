"""The package as pyproject.toml declares it: one version everywhere, the package list that the
folders hold, and the repository's ``agents/`` installed as ``saddle_agents`` so that it sits
beside OpenAI's Agents SDK (PyPI ``openai-agents``), which installs a top-level ``agents``.

The built wheel itself is checked away from the repository by ``.ci/check-wheel`` (CI)."""

from __future__ import annotations

import ast
import importlib.metadata
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import tomllib
from packaging.version import Version

import saddle_env

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
INSTALLED_NAME = "saddle_agents"  # the name agents/ installs under (pyproject.toml's package-dir)


def test_the_version_has_one_source():
    assert PYPROJECT["project"]["dynamic"] == ["version"]
    assert PYPROJECT["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "saddle_env.__version__"}
    Version(saddle_env.__version__)  # a PEP 440 version, or InvalidVersion
    citation = re.search(r"^version: (\S+)$", (ROOT / "CITATION.cff").read_text(), re.M)
    assert citation is not None and citation.group(1) == saddle_env.__version__


def test_the_installed_metadata_has_the_version():
    assert importlib.metadata.version("saddle-env") == saddle_env.__version__


def test_the_docs_show_the_version():
    sys.path.insert(0, str(ROOT / "docs"))
    try:
        import hooks
    finally:
        sys.path.remove(str(ROOT / "docs"))
    shown = hooks.expand("<!-- generated: version -->")
    assert f"saddle-env {saddle_env.__version__}" in shown
    for page in ("install.md", "index.md"):
        assert "<!-- generated: version -->" in (ROOT / "docs" / page).read_text(), page


def test_the_changelog_has_a_heading_per_version():
    headings = re.findall(r"^## \[([^\]]+)\](?: - (\d{4}-\d\d-\d\d))?$",
                          (ROOT / "CHANGELOG.md").read_text(), re.M)
    assert headings[0] == ("Unreleased", "")
    released = [Version(v) for v, _ in headings[1:]]
    assert released and all(date for _, date in headings[1:])
    assert released == sorted(released, reverse=True), "newest release first"
    assert all(v < Version(saddle_env.__version__) for v in released), \
        "the unreleased work carries a version above every release"


def test_the_python_versions_match():
    project = PYPROJECT["project"]
    tested = "3.11"  # .ci/run's python3
    assert project["requires-python"] == f">={tested}"
    assert f"Programming Language :: Python :: {tested}" in project["classifiers"]
    assert PYPROJECT["tool"]["mypy"]["python_version"] == tested


def test_the_urls_name_the_repository():
    urls = PYPROJECT["project"]["urls"]
    assert urls["Source"] == "https://github.com/saddle-env/saddle-env"
    assert all(u.startswith(urls["Source"]) for u in urls.values())


def test_the_package_list_is_the_folders():
    """pyproject.toml lists the packages by hand (a folder installed under another name cannot
    be found by setuptools' find): every folder with an ``__init__.py`` and the data folders."""
    listed = set(PYPROJECT["tool"]["setuptools"]["packages"])
    on_disk = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "saddle_env").rglob("__init__.py")}
    on_disk |= {".".join((INSTALLED_NAME, *p.parent.relative_to(ROOT / "agents").parts))
                for p in (ROOT / "agents").rglob("__init__.py")}
    on_disk |= {f"{INSTALLED_NAME}.hyperparams", f"{INSTALLED_NAME}.models"}
    assert listed == on_disk
    assert PYPROJECT["tool"]["setuptools"]["package-dir"] == {INSTALLED_NAME: "agents"}


def test_no_command_or_package_takes_the_name_agents():
    scripts = PYPROJECT["project"]["scripts"]
    assert not [s for s in scripts.values() if s.startswith("agents.")]
    assert [s for s in scripts.values() if s.startswith(f"{INSTALLED_NAME}.")]
    assert not [p for p in PYPROJECT["tool"]["setuptools"]["packages"]
                if p == "agents" or p.startswith("agents.")]


def test_agents_imports_itself_relatively():
    """An absolute ``agents.`` import inside agents/ would load the wrong package once
    installed as saddle_agents (or OpenAI's ``agents`` beside it)."""
    absolute = []
    for path in sorted((ROOT / "agents").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0
                     else [])
            absolute += [f"{path.relative_to(ROOT)}:{node.lineno}" for n in names
                         if n == "agents" or n.startswith("agents.")]
    assert not absolute, "absolute imports of agents: " + ", ".join(absolute)


FOREIGN_AGENTS = '''
"""Stands in for OpenAI's Agents SDK, which installs a top-level package named agents."""
class Agent:
    pass
class Runner:
    pass
'''


def test_saddle_env_works_beside_a_foreign_top_level_agents(tmp_path):
    """The installed layout with another distribution's ``agents`` first on the path: both
    import, every module of saddle_agents imports under that name, and the commands' entry
    points resolve; nothing of ours lands under ``agents``."""
    foreign = tmp_path / "foreign"
    (foreign / "agents").mkdir(parents=True)
    (foreign / "agents" / "__init__.py").write_text(FOREIGN_AGENTS)
    ours = tmp_path / "site"
    ours.mkdir()
    (ours / "saddle_env").symlink_to(ROOT / "saddle_env")
    (ours / INSTALLED_NAME).symlink_to(ROOT / "agents")
    scripts = {name: target for name, target in PYPROJECT["project"]["scripts"].items()}
    code = textwrap.dedent(f"""
        import importlib, pkgutil, sys
        sys.path[:0] = [{str(foreign)!r}, {str(ours)!r}]
        import agents
        assert agents.__file__.startswith({str(foreign)!r}), agents.__file__
        import saddle_env, {INSTALLED_NAME}
        for info in pkgutil.walk_packages({INSTALLED_NAME}.__path__, "{INSTALLED_NAME}."):
            if not info.name.endswith(".__main__"):  # a __main__ runs its command
                importlib.import_module(info.name)
        for name, target in {scripts!r}.items():
            module, func = target.split(":")
            assert callable(getattr(importlib.import_module(module), func)), name
        import agents as again
        assert again is agents and hasattr(agents, "Runner")
        ours = sorted(m for m in sys.modules if m.startswith("agents."))
        assert not ours, ours
        print("both import")
    """)
    proc = subprocess.run([sys.executable, "-I", "-c", code], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip().endswith("both import")


@pytest.mark.parametrize("argv", [["--help"]])
def test_saddle_eval_runs_as_saddle_agents(tmp_path, argv):
    """``saddle-eval --help`` through the installed name, with a foreign ``agents`` first."""
    foreign = tmp_path / "foreign" / "agents"
    foreign.mkdir(parents=True)
    (foreign / "__init__.py").write_text(FOREIGN_AGENTS)
    ours = tmp_path / "site"
    ours.mkdir()
    (ours / "saddle_env").symlink_to(ROOT / "saddle_env")
    (ours / INSTALLED_NAME).symlink_to(ROOT / "agents")
    module, func = PYPROJECT["project"]["scripts"]["saddle-eval"].split(":")
    code = (f"import sys; sys.path[:0] = [{str(foreign.parent)!r}, {str(ours)!r}]; "
            f"sys.argv = ['saddle-eval', *{argv!r}]; "
            f"import importlib; importlib.import_module({module!r}).{func}()")
    proc = subprocess.run([sys.executable, "-I", "-c", code], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "--policy" in proc.stdout


def test_the_install_hint_fits_the_install(monkeypatch, tmp_path):
    from agents import cli_args, paths

    assert cli_args.install_hint("deploy") == 'pip install -e ".[deploy]"'   # this checkout
    monkeypatch.setattr(paths, "REPO_ROOT", tmp_path)   # as in site-packages: no pyproject.toml
    hint = cli_args.install_hint("deploy")
    assert hint.startswith('pip install --find-links DIST "saddle-env[deploy]"')
