"""Where the agents' files live: the shipped models, the recipes, and (in a source checkout)
the repository's docs and benchmark results. Declared once so that every room of `agents`
finds them the same way."""

from __future__ import annotations

from pathlib import Path

AGENTS_DIR = Path(__file__).resolve().parent
MODELS_DIR = AGENTS_DIR / "models"  # the shipped agents and their sidecars
HYPERPARAMS_DIR = AGENTS_DIR / "hyperparams"  # the recipes, one YAML file per algorithm
# The repository around the package: only a source checkout (or an editable install) has
# these; the tools that write into them say so when they are missing.
REPO_ROOT = AGENTS_DIR.parent
DOCS_DIR = REPO_ROOT / "docs"
BENCHMARK_DATA = REPO_ROOT / "benchmark_data"
