"""The ahead-of-time compiled kernels (saddle_env._aot, saddle_env.aot_build): a build is used
only for the sources and platform it was built from and for exactly its argument types, and
(slow) a real build starts a fresh process's first step of every level and first simulate
without compiling, bit for bit the JIT's, and retires itself when a source changes."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import compiled_in_fresh_process

import saddle_env
from saddle_env import _aot
from saddle_env import _kernels as K
from saddle_env import integrators as I
from saddle_env import precompile as pc
from saddle_env.scene import ROLLING


@pytest.fixture
def fake_build(tmp_path, monkeypatch):
    """A build folder whose one 'module' is a Python file (the loader imports any module the
    manifest names): its `integrate_h` returns a marker. Yields the manifest writer."""
    (tmp_path / "fake.py").write_text("def integrate_h(*args):\n    return 'ahead'\n")
    monkeypatch.setattr(_aot, "AOT_DIR", tmp_path)
    monkeypatch.setattr(_aot, "_loaded", None)
    monkeypatch.setenv(_aot.DISABLE_ENV, "1")

    def write(**changes):
        manifest = {"digest": _aot.source_digest(), "platform": _aot.platform_tag(),
                    "cpu": _aot.host_cpu(),
                    "modules": [{"name": "fake", "file": "fake.py", "flags": ["ROLLING_ON"],
                                 "exports": {"saddle_env.integrators": ["integrate_h"]},
                                 "argtypes": {"saddle_env.integrators.integrate_h":
                                              ["int64", "array(float64, 1d, C)"]}}]}
        manifest.update(changes)
        (tmp_path / _aot.MANIFEST).write_text(json.dumps(manifest))
        monkeypatch.setattr(_aot, "_loaded", None)

    return write


def test_a_build_is_used_only_from_its_sources_and_on_its_platform_and_cpu(
        fake_build, monkeypatch):
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    assert "none built" in _aot.status()
    fake_build()
    found = _aot.compiled(("ROLLING_ON",), "saddle_env.integrators")
    assert list(found) == ["integrate_h"] and found["integrate_h"]() == "ahead"
    assert _aot.compiled(("SLIPPING_ON",), "saddle_env.integrators") == {}
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.envs._step") == {}
    assert "in use (1 modules" in _aot.status()
    fake_build(digest="0" * 64)
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    assert "other sources" in _aot.status() and "precompile --aot" in _aot.status()
    fake_build(platform="cpython-27-win32")
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    assert "built for cpython-27-win32" in _aot.status()
    fake_build(cpu="i386")
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    assert "built for the CPU i386" in _aot.status()
    fake_build()
    monkeypatch.setenv(_aot.DISABLE_ENV, "0")
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    assert "turned off" in _aot.status()


def test_the_digest_covers_every_source_of_the_package_and_its_environment(tmp_path):
    pkg = tmp_path / "pkg"
    shutil.copytree(Path(saddle_env.__file__).parent, pkg,
                    ignore=shutil.ignore_patterns("__pycache__", "_aot"))
    before = _aot.source_digest(pkg)
    assert before == _aot.source_digest()
    for rel in ("cli.py", "envs/engine.py"):  # not a kernel, but it picks their arguments
        path = pkg / rel
        text = path.read_text()
        path.write_text(text + "\n# edited\n")
        assert _aot.source_digest(pkg) != before
        path.write_text(text)
    assert _aot.source_digest(pkg) == before


def test_an_entry_point_is_used_for_its_own_argument_types_only(fake_build, monkeypatch):
    """`_kernels.checked`: an ahead-of-time entry point unboxes its arguments as the types
    it was built for without looking; other types go to the JIT copy."""
    fake_build()
    monkeypatch.delenv(K.FULL_KERNELS_ENV, raising=False)
    monkeypatch.setattr(K, "_variants", {})           # a first specialisation in this process
    space = K.specialise((ROLLING,), False, I)
    assert space.integrate_h() == "ahead"
    assert K.checked(space, "integrate_h", (0, np.zeros(3)))() == "ahead"
    for other in ((0, np.zeros(3, dtype=np.float32)), (0, np.zeros((3, 1))), (0.0, np.zeros(3)),
                  (0, np.zeros(6)[::2])):
        jit = K.checked(space, "integrate_h", other)
        assert jit is not space.integrate_h and jit.py_func.__name__ == "integrate_h"
    # what is not compiled ahead is the JIT copy, unchecked
    assert K.checked(space, "rhs", ()) is space.rhs


def test_aot_takes_no_targets(capsys):
    with pytest.raises(SystemExit):
        pc.main(["--aot", "simulate"])
    assert "give no targets" in capsys.readouterr().err


def test_the_engine_hands_the_compiled_step_the_types_it_was_checked_for():
    """The engine checks an entry point once, so it makes the caller's arrays the same types
    every call: float32 or list actions, int32 indices."""
    import gymnasium as gym

    env = gym.make("SaddleTrap-v0")
    env.reset(seed=0)
    engine = env.unwrapped.engine
    engine.reset(np.array([0], dtype=np.int32), [np.random.default_rng(0)])
    seen = []
    step = engine._S.step_scalar

    def spy(*args):
        seen.append((args[6].dtype, args[7].dtype))
        return step(*args)

    engine._entries["step_scalar"] = spy
    engine.step(np.zeros(1, dtype=np.float32), np.ones(1, dtype=np.int8),
                [np.random.default_rng(0)])
    engine.step([0.0], [True], [np.random.default_rng(0)])
    assert seen == [(np.float64, np.bool_)] * 2


_FIRST_CALLS = """
import json, numpy as np, gymnasium as gym, saddle_env as se
from saddle_env import _aot
out = {}
for lid in %r:
    env = gym.make(lid)
    obs, _ = env.reset(seed=3)
    rows = [obs.tolist() + [0.0, 0.0]]
    for k in range(150):
        obs, r, term, trunc, info = env.step(np.array([0.3 * np.sin(0.1 * k)]))
        rows.append(obs.tolist() + [r, info["time"]])
        if term or trunc:
            break
    out[lid] = rows
    vec = gym.make_vec(lid, num_envs=8)  # below 2 x LANES balls: SIMD blocks, one thread
    obs, _ = vec.reset(seed=5)
    rows = [obs.ravel().tolist()]
    for k in range(60):
        obs, r, term, trunc, info = vec.step(np.full((8, 1), 0.3 * np.sin(0.1 * k)))
        rows.append(obs.ravel().tolist() + r.tolist())
    out["vector " + lid] = rows
for contact in ("rolling", "slipping", "coulomb"):
    scene = se.Scene(contact=contact, mu=0.3) if contact == "coulomb" else se.Scene(contact=contact)
    state = se.initial_state(scene, x=0.001, y=0.001, start="lab-rest", omega=30.0)
    out[contact] = se.simulate(scene, state, t_end=2.0, omega=30.0, dt_out=0.01).y.tolist()
print(json.dumps({"status": _aot.status(), "runs": out}))
"""


@pytest.mark.slow
def test_a_build_starts_every_level_and_simulate_without_compiling_bit_for_bit(tmp_path):
    """Build into a copy of the package; a fresh process on the build's cache then takes
    every level's first steps and a first simulate of each contact model from the build,
    compiling only a few small helpers called from Python, with the JIT's results
    to the last bit; an edited source retires the build."""
    from saddle_env.envs import LEVEL_IDS

    shutil.copytree(Path(saddle_env.__file__).parent, tmp_path / "saddle_env",
                    ignore=shutil.ignore_patterns("__pycache__", "_aot"))
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": str(tmp_path)}
    env.pop("SADDLE_ENV_FULL_KERNELS", None)            # the per-scene copies, as users run
    env.pop(_aot.DISABLE_ENV, None)
    done = subprocess.run([sys.executable, "-m", "saddle_env.precompile", "--aot"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=1200)
    assert done.returncode == 0, done.stderr
    manifest = json.loads((tmp_path / "saddle_env" / "_aot" / _aot.MANIFEST).read_text())
    assert {tuple(m["flags"]) for m in manifest["modules"]} == {
        ("ROLLING_ON",), ("SLIPPING_ON",), ("COULOMB_ON",), ("ROLLING_ON", "SLIPPING_ON")}

    code = _FIRST_CALLS % (list(LEVEL_IDS),)
    # the empty cache of a fresh install: only the build's modules
    fresh = {**env, "NUMBA_CACHE_DIR": str(tmp_path / "empty")}
    compiled = compiled_in_fresh_process(code, fresh, cwd=str(tmp_path))
    entry_points = ("place", "step_scalar", "step_serial", "integrate_h", "_step_range_scalar",
                    "_step_range")
    assert compiled[-1] == "<lambda>" and not set(compiled) & set(entry_points), compiled
    assert len(set(compiled) - {"<lambda>"}) <= 15, compiled  # small helpers called from Python

    def run(aot: str) -> dict:
        out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path,
                             env={**env, _aot.DISABLE_ENV: aot}, capture_output=True,
                             text=True, timeout=900)
        assert out.returncode == 0, out.stderr[-2000:]
        return json.loads(out.stdout.strip().splitlines()[-1])

    ahead, jit = run("1"), run("0")
    assert ahead["status"].startswith("ahead-of-time kernels in use (4 modules")
    assert jit["status"].startswith("no ahead-of-time kernels: turned off")
    assert ahead["runs"].keys() == jit["runs"].keys()
    for key in jit["runs"]:
        assert np.array_equal(np.array(ahead["runs"][key]), np.array(jit["runs"][key])), key

    engine = tmp_path / "saddle_env" / "envs" / "engine.py"
    engine.write_text(engine.read_text() + "\n# an edit after the build\n")
    stale = run("1")
    assert "built from other sources" in stale["status"]
    for key in jit["runs"]:
        assert np.array_equal(np.array(stale["runs"][key]), np.array(jit["runs"][key])), key
