"""The static checks, run as part of the test command so that CI runs them: ruff over the
repository and mypy over the targets that pyproject.toml's ``[tool.mypy]`` names (``files``),
each with zero findings. The same checks run locally through .pre-commit-config.yaml.

Each tool runs from the repository root with this interpreter (``python -m ruff``,
``python -m mypy``), so the versions the ``test`` extra installed are the ones used. The
test skips, saying which, only where a tool is not installed. mypy keeps its cache in
``.mypy_cache`` at the root (measured on the 2-core machine over saddle_env and agents: 48 s
without it, 1.3 s with it; ruff 0.5 s); in a read-only checkout both caches go to the
temporary folder instead."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _check(tool: str, *args: str) -> None:
    if importlib.util.find_spec(tool) is None:
        pytest.skip(f"{tool} is not installed (pip install -e '.[test]' brings it)")
    cache: list[str] = []
    if not os.access(ROOT, os.W_OK):  # a read-only checkout: cache outside it
        cache = ["--cache-dir", str(Path(tempfile.gettempdir()) / f"saddle-env-{tool}-cache")]
    proc = subprocess.run([sys.executable, "-m", tool, *args, *cache], cwd=ROOT,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True,
                          timeout=900)
    assert proc.returncode == 0, (
        f"{' '.join([tool, *args])} found problems (exit code {proc.returncode}):\n"
        f"{proc.stdout}{proc.stderr}")


def test_ruff_finds_nothing():
    _check("ruff", "check", ".")


# Slow (CI's slow step runs it): a fresh clone has no mypy cache, and 48 s of the default
# suite's three minutes is too much for a check that pre-commit also runs before each commit.
@pytest.mark.slow
def test_mypy_finds_nothing():
    _check("mypy")  # the targets and the settings: pyproject.toml, [tool.mypy]
