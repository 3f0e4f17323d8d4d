"""saddle_env._cache drops numba cache files when any compiled-code source changes."""

from __future__ import annotations

from saddle_env import _cache


def _tree(tmp_path, monkeypatch):
    pkg = tmp_path / "saddle_env"
    (pkg / "__pycache__").mkdir(parents=True)
    (pkg / "_kernels.py").write_text("x = 1\n")
    other = tmp_path / "agents"
    (other / "__pycache__").mkdir(parents=True)
    (other / "baselines.py").write_text("import numba\n")
    (other / "training.py").write_text("print('no compiled code')\n")
    monkeypatch.setattr(_cache, "_PACKAGE", pkg)
    monkeypatch.setattr(_cache, "_TREES", [pkg, other])
    monkeypatch.setattr(_cache, "_STAMP", pkg / "__pycache__" / "numba-sources.sha256")
    return pkg, other


def _cached(*dirs):
    for d in dirs:
        (d / "__pycache__" / "f-1.py311.nbi").write_text("index")
        (d / "__pycache__" / "f-1.py311.1.nbc").write_text("code")


def _count(*dirs):
    return sum(len(list((d / "__pycache__").glob("*.nb?"))) for d in dirs)


def test_cache_survives_unchanged_sources_and_goes_when_a_kernel_file_changes(tmp_path,
                                                                             monkeypatch):
    pkg, other = _tree(tmp_path, monkeypatch)
    assert _cache.refresh()  # no stamp yet: start clean
    _cached(pkg, other)
    assert not _cache.refresh() and _count(pkg, other) == 4
    (other / "training.py").write_text("print('edited, still no compiled code')\n")
    assert not _cache.refresh() and _count(pkg, other) == 4
    (pkg / "_kernels.py").write_text("x = 2\n")  # a callee changed: callers' caches are stale
    assert _cache.refresh() and _count(pkg, other) == 0
    _cached(pkg, other)
    (other / "baselines.py").write_text("import numba  # edited\n")
    assert _cache.refresh() and _count(pkg, other) == 0
