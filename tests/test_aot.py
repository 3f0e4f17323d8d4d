"""The ahead-of-time compiled kernels (saddle_env.compilation.aot,
saddle_env.coldstart.aot_build): a build is used only for the sources and platform it was built
from and for exactly its argument types, and (slow) a real build starts a fresh process's first step
of every level and first simulate
without compiling, bit for bit the JIT's, and retires itself when a source changes."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import compiled_in_fresh_process, gone_within

import saddle_env
from saddle_env import integrators as I
from saddle_env.coldstart import aot_build
from saddle_env.coldstart import precompile as pc
from saddle_env.compilation import aot as _aot
from saddle_env.compilation import specialise as S
from saddle_env.compilation.specialise import FULL_KERNELS_ENV, checked, specialise
from saddle_env.scene import ROLLING


@pytest.fixture
def fake_build(tmp_path, monkeypatch):
    """A build folder whose one 'module' is a Python file (the loader imports any module the
    manifest names): its `integrate_h` returns a marker. Yields the manifest writer."""
    (tmp_path / "fake.py").write_text("def integrate_h(*args):\n    return 'ahead'\n")
    monkeypatch.setattr(_aot, "AOT_DIR", tmp_path)
    monkeypatch.setattr(_aot, "_loaded", None)
    monkeypatch.setenv(_aot.AOT_ENV, "1")

    def write(**changes):
        manifest = {"sources": list(aot_build.SOURCES),
                    "digest": _aot.source_digest(aot_build.SOURCES), "platform": _aot.platform_tag(),
                    **_aot.machine(),
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
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.envs.control_step") == {}
    assert "in use (1 modules" in _aot.status()
    fake_build(digest="0" * 64)
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    assert "other sources" in _aot.status() and "precompile --aot" in _aot.status()
    fake_build(platform="cpython-27-win32")
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    assert "built for cpython-27-win32" in _aot.status()
    fake_build(cpu="i386")
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    assert "cpu 'i386'" in _aot.status()
    fake_build(features="+sse2")              # the same model, fewer instructions (a VM)
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    assert "CPU features" in _aot.status()
    fake_build(numba="0.1.0")                 # another compiler than the JIT beside it
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    assert "numba '0.1.0'" in _aot.status()
    fake_build()
    monkeypatch.setenv(_aot.AOT_ENV, "0")
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    assert "turned off" in _aot.status()


def test_a_build_for_the_level_runs_on_every_cpu_model_that_has_the_level():
    """`aot.unusable`, the decision itself: a build for x86-64-v3 on any model reporting
    the level's features, named; a build for a CPU model on that model and features only;
    either under the numba and llvmlite that built it only."""
    here = _aot.machine()
    level = {**here, "cpu": _aot.BASELINE, "features": _aot.LEVEL_FEATURES[_aot.BASELINE]}
    assert _aot.unusable(level, {**here, "cpu": "haswell", "features": HASWELL}) is None
    assert _aot.unusable(level, {**here, "cpu": "znver4", "features": ZNVER4}) is None
    assert _aot.unusable(level, {**here, "cpu": "sandybridge", "features": SANDYBRIDGE}) == (
        "this CPU (sandybridge) lacks avx2, bmi, bmi2, f16c, fma, lzcnt, movbe of the "
        "instruction-set level x86-64-v3 they were built for")
    hidden = HASWELL.replace("+fma", "-fma")           # a virtual machine that hides FMA
    assert "lacks fma of" in _aot.unusable(level, {**here, "cpu": "haswell", "features": hidden})
    assert "numba '0.1.0'" in _aot.unusable({**level, "numba": "0.1.0"}, here)
    model = {**here, "cpu": "haswell", "features": HASWELL}   # SADDLE_ENV_AOT_CPU=host
    assert _aot.unusable(model, {**here, "cpu": "haswell", "features": HASWELL}) is None
    assert "cpu 'haswell'" in _aot.unusable(model, {**here, "cpu": "znver4", "features": ZNVER4})
    assert "CPU features" in _aot.unusable(model, {**here, "cpu": "haswell", "features": hidden})


@pytest.mark.parametrize("model", ["znver4", "haswell", "sandybridge"])
def test_the_build_is_for_each_level_the_machine_has_else_for_the_machine(monkeypatch, model):
    """`aot.build_targets`: x86-64-v3, then x86-64-v4 on a machine with AVX-512 (not with
    ``baseline``); a machine below the baseline, another architecture or ``host`` builds
    for the machine's own model."""
    features = {"znver4": ZNVER4, "haswell": HASWELL, "sandybridge": SANDYBRIDGE}[model]
    here = {**_aot.machine(), "cpu": model, "features": features}
    monkeypatch.setattr(_aot, "machine", lambda: here)
    monkeypatch.delenv(_aot.AOT_CPU_ENV, raising=False)
    own = [{"cpu": model, "features": features}]
    v3, v4 = ({"cpu": lv, "features": _aot.LEVEL_FEATURES[lv]} for lv in ("x86-64-v3",
                                                                          "x86-64-v4"))
    x86 = os.uname().machine == "x86_64"
    want = {"znver4": [v3, v4], "haswell": [v3], "sandybridge": own}[model] if x86 else own
    assert _aot.build_targets() == want
    monkeypatch.setenv(_aot.AOT_CPU_ENV, "baseline")
    assert _aot.build_targets() == want[:1]
    monkeypatch.setenv(_aot.AOT_CPU_ENV, "host")
    assert _aot.build_targets() == own
    monkeypatch.setenv(_aot.AOT_CPU_ENV, "native")
    with pytest.raises(ValueError, match="SADDLE_ENV_AOT_CPU must be 'levels', 'baseline' or "
                                         "'host', got 'native'"):
        _aot.build_targets()


def test_an_upper_level_build_is_used_where_the_cpu_has_the_level(fake_build, tmp_path,
                                                                   monkeypatch):
    """A build for x86-64-v4 (its own folder) is preferred on a CPU with AVX-512 while it
    is current; on a CPU without, or once it is not current, the baseline build serves."""
    fake_build(cpu=_aot.BASELINE, features=_aot.LEVEL_FEATURES[_aot.BASELINE])
    folder = tmp_path / "x86-64-v4"
    folder.mkdir()
    (folder / "fake.py").write_text("def integrate_h(*args):\n    return 'v4'\n")
    top = json.loads((tmp_path / _aot.MANIFEST).read_text())
    real = _aot.machine()

    def upper(host_features, **changes):
        manifest = {**top, "cpu": "x86-64-v4", "features": _aot.LEVEL_FEATURES["x86-64-v4"],
                    **changes}
        (folder / _aot.MANIFEST).write_text(json.dumps(manifest))
        monkeypatch.setattr(_aot, "machine", lambda: {**real, "features": host_features})
        monkeypatch.setattr(_aot, "_loaded", None)
        return _aot.compiled(("ROLLING_ON",), "saddle_env.integrators")["integrate_h"]()

    assert upper(ZNVER4) == "v4" and "x86-64-v4" in _aot.status()
    assert upper(ZNVER4.replace("+avx512dq", "-avx512dq")) == "ahead"  # one missing
    assert upper(HASWELL) == "ahead"
    assert upper(ZNVER4, digest="0" * 64) == "ahead"  # built from other sources
    assert upper(ZNVER4, numba="0.1.0") == "ahead"
    assert upper(ZNVER4, cpu="x86-64-v3") == "ahead"  # not the folder's level
    assert "x86-64-v4" not in _aot.status()
    monkeypatch.setenv(_aot.AOT_LEVEL_ENV, "x86-64-v3")          # the user caps the level
    assert upper(ZNVER4) == "ahead"
    monkeypatch.setenv(_aot.AOT_LEVEL_ENV, "x86-64-v4")
    assert upper(ZNVER4) == "v4"
    monkeypatch.setenv(_aot.AOT_LEVEL_ENV, "v4")
    with pytest.raises(ValueError, match="SADDLE_ENV_AOT_LEVEL must be one of x86-64-v3, "
                                         "x86-64-v4 \\(or unset\\), got 'v4'"):
        upper(ZNVER4)


def test_a_cpu_below_the_level_falls_back_to_the_jit_saying_so_once(fake_build, caplog,
                                                                     monkeypatch):
    from saddle_env.compilation import notice

    monkeypatch.setattr(notice, "_announced_no_build", False)
    # a level whose features include one this machine lacks
    fake_build(cpu=_aot.BASELINE, features=_aot.LEVEL_FEATURES[_aot.BASELINE] + ",+nosuchisa")
    with caplog.at_level("WARNING", logger="saddle_env"):
        assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
        assert "lacks nosuchisa of the instruction-set level x86-64-v3" in _aot.status()
        _aot._loaded = None                         # asked again: no second notice
        assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    said = [r.getMessage() for r in caplog.records if "are not used" in r.getMessage()]
    assert len(said) == 1 and "nosuchisa" in said[0] and "numba compiles" in said[0], said
    fake_build(cpu=_aot.BASELINE, features=_aot.LEVEL_FEATURES[_aot.BASELINE])
    found = _aot.compiled(("ROLLING_ON",), "saddle_env.integrators")  # at the level: used
    assert found["integrate_h"]() == "ahead"


def test_the_forwarders_cover_what_numbas_threading_layer_provides():
    """`aot_threads`: every name numba's parallel code calls has a hidden forwarder in the
    C shim, and numba's threading layer provides an address for each."""
    import re

    from llvmlite import binding as ll
    from numba.np.ufunc import parallel

    from saddle_env.compilation import aot_threads

    defined = re.findall(r"^HIDDEN [\w *]+?\b(\w+)\(", aot_threads.SHIM, re.M)
    assert defined == list(aot_threads.SYMBOLS)
    assert f"void *{aot_threads.TABLE}[{len(aot_threads.SYMBOLS)}];" in aot_threads.SHIM
    parallel._launch_threads()
    assert all(ll.address_of_symbol(name) for name in aot_threads.SYMBOLS)


def test_a_damaged_manifest_falls_back_to_the_jit(fake_build, tmp_path):
    fake_build()
    manifest = json.loads((tmp_path / _aot.MANIFEST).read_text())
    del manifest["modules"][0]["argtypes"]
    (tmp_path / _aot.MANIFEST).write_text(json.dumps(manifest))
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    assert "could be loaded" in _aot.status()
    (tmp_path / _aot.MANIFEST).write_text("[1, 2]")
    _aot._loaded = None
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    assert "none built" in _aot.status()


def test_the_digest_covers_every_source_of_the_package_and_its_environment(tmp_path):
    pkg = tmp_path / "pkg"
    shutil.copytree(Path(saddle_env.__file__).parent, pkg,
                    ignore=shutil.ignore_patterns("__pycache__", "_aot"))
    before = _aot.source_digest(aot_build.SOURCES, pkg)
    assert before == _aot.source_digest(aot_build.SOURCES)
    # not kernels, but one picks their arguments and one holds the build's exported callers
    for rel in ("cli.py", "envs/engine.py", "coldstart/aot_build.py"):
        path = pkg / rel
        text = path.read_text()
        path.write_text(text + "\n# edited\n")
        assert _aot.source_digest(aot_build.SOURCES, pkg) != before
        path.write_text(text)
    assert _aot.source_digest(aot_build.SOURCES, pkg) == before


@pytest.mark.parametrize("sources", [None, "envs", ["..", "envs"], ["/tmp"], [1]])
def test_a_manifest_without_its_source_folders_by_name_is_not_used(fake_build, sources):
    """The loader digests the folders the build's manifest names; a manifest that names
    none, or names a path out of the package, is a build from other sources."""
    fake_build(sources=sources)
    assert _aot.compiled(("ROLLING_ON",), "saddle_env.integrators") == {}
    assert "other sources" in _aot.status()


def test_an_entry_point_is_used_for_its_own_argument_types_only(fake_build, monkeypatch):
    """`specialise.checked`: an ahead-of-time entry point unboxes its arguments as the types
    it was built for without looking; other types go to the JIT copy."""
    fake_build()
    monkeypatch.delenv(FULL_KERNELS_ENV, raising=False)
    monkeypatch.setattr(S, "_variants", {})           # a first specialisation in this process
    space = specialise((ROLLING,), False, I)
    assert space.integrate_h() == "ahead"
    assert checked(space, "integrate_h", (0, np.zeros(3)))() == "ahead"
    for other in ((0, np.zeros(3, dtype=np.float32)), (0, np.zeros((3, 1))), (0.0, np.zeros(3)),
                  (0, np.zeros(6)[::2])):
        jit = checked(space, "integrate_h", other)
        assert jit is not space.integrate_h and jit.py_func.__name__ == "integrate_h"
    # what is not compiled ahead is the JIT copy, unchecked
    assert checked(space, "rhs", ()) is space.rhs


def test_a_threaded_entry_point_is_wired_before_use_or_left_to_the_jit(
        fake_build, monkeypatch):
    """`aot.prepare` through `specialise.checked`: an entry point the manifest lists as
    threaded has its module wired to numba's threading layer when first handed out; if the
    wiring fails, the JIT copy is handed out instead."""
    from saddle_env.compilation import aot_threads

    monkeypatch.delenv(FULL_KERNELS_ENV, raising=False)
    fake_build(modules=[{"name": "fake", "file": "fake.py", "flags": ["ROLLING_ON"],
                         "exports": {"saddle_env.integrators": ["integrate_h"]},
                         "argtypes": {"saddle_env.integrators.integrate_h":
                                      ["int64", "array(float64, 1d, C)"]},
                         "threaded": ["saddle_env.integrators.integrate_h"]}])
    wired = []
    monkeypatch.setattr(aot_threads, "wire", wired.append)
    monkeypatch.setattr(S, "_variants", {})
    space = specialise((ROLLING,), False, I)
    assert wired == []                                   # not before it is handed out
    assert checked(space, "integrate_h", (0, np.zeros(3)))() == "ahead"
    assert [Path(p).name for p in wired] == ["fake.py"]

    def fail(module_file):
        raise RuntimeError("numba's threading layer has no numba_parallel_for")

    monkeypatch.setattr(aot_threads, "wire", fail)
    jit = checked(space, "integrate_h", (0, np.zeros(3)))
    assert jit is not space.integrate_h and jit.py_func.__name__ == "integrate_h"


def test_aot_takes_no_targets(capsys):
    with pytest.raises(SystemExit):
        pc.main(["--aot", "simulate"])
    assert "give no targets" in capsys.readouterr().err


def test_the_engine_hands_the_compiled_step_the_types_it_was_checked_for():
    """The engine checks an entry point once (`_entry`), so it makes the caller's arrays the
    same types every call: float64 and bool vectors of one value per ball, whatever the
    caller passes (float32, a list, an (n, 1) array); a wrong count is refused."""
    import pickle

    import gymnasium as gym

    env = gym.make("SaddleTrap-v0")
    env.reset(seed=0)
    engine = env.unwrapped.engine
    engine.reset(np.array([0], dtype=np.int32), [np.random.default_rng(0)])
    seen = []
    step = engine._S.step_scalar

    def spy(*args):
        seen.append((args[6].dtype, args[6].shape, args[7].dtype, args[7].shape))
        return step(*args)

    engine._entries["step_scalar"] = spy
    rng = [np.random.default_rng(0)]
    engine.step(np.zeros(1, dtype=np.float32), np.ones(1, dtype=np.int8), rng)
    engine.step([0.0], [True], rng)
    engine.step(np.zeros((1, 1)), np.ones((1, 1), dtype=bool), rng)
    assert seen == [(np.float64, (1,), np.bool_, (1,))] * 3
    with pytest.raises(ValueError, match=r"actions must hold one value per ball \(1\)"):
        engine.step(np.zeros(2), [True], rng)
    twin = pickle.loads(pickle.dumps(engine))           # compiled code is found again
    assert twin._entries == {} and "_entries" not in engine.__getstate__()


_FIRST_CALLS = """
import json, numpy as np, gymnasium as gym, saddle_env as se
from saddle_env.compilation import aot as _aot
out = {}
for lid, options in [(lid, {}) for lid in %r] + [("SaddleTrap-v0", {"contact": "slipping"})]:
    name = " ".join([lid, *options.values()])
    env = gym.make(lid, **options)
    obs, _ = env.reset(seed=3)
    rows = [obs.tolist() + [0.0, 0.0]]
    for k in range(150):
        obs, r, term, trunc, info = env.step(np.array([0.3 * np.sin(0.1 * k)]))
        rows.append(obs.tolist() + [r, info["time"]])
        if term or trunc:
            break
    out[name] = rows
    vec = gym.make_vec(lid, num_envs=8, **options)  # below 2 x LANES balls: one thread
    obs, _ = vec.reset(seed=5)
    rows = [obs.ravel().tolist() + [0.0] * 8]
    for k in range(60):
        obs, r, term, trunc, info = vec.step(np.full((8, 1), 0.3 * np.sin(0.1 * k)))
        rows.append(obs.ravel().tolist() + r.tolist())
    out["vector " + name] = rows
    vec = gym.make_vec(lid, num_envs=128, **options)  # from 2 x LANES balls: numba's threads
    obs, _ = vec.reset(seed=7)
    rows = [obs.ravel().tolist() + [0.0] * 128]
    for k in range(20):
        obs, r, term, trunc, info = vec.step(np.full((128, 1), 0.3 * np.cos(0.1 * k)))
        rows.append(obs.ravel().tolist() + r.tolist())
    out["threaded vector " + name] = rows
for contact in ("rolling", "slipping", "coulomb"):
    scene = se.Scene(contact=contact, mu=0.3) if contact == "coulomb" else se.Scene(contact=contact)
    state = se.initial_state(scene, x=0.001, y=0.001, start="lab-rest", omega=30.0)
    out[contact] = se.simulate(scene, state, t_end=2.0, omega=30.0, dt_out=0.01).y.tolist()
    starts = np.array([state * (1.0 + 0.1 * i) for i in range(3)])
    batch = se.simulate_batch(scene, starts, t_end=1.0, omega=[28.0, 30.0, 32.0], dt_out=0.05)
    out["batch " + contact] = np.nan_to_num(batch.state, nan=-1.0).tolist()
    drives = np.zeros((3, 2, se.kernels.DRIVE_WIDTH))
    drives[:, :, 0] = [[28.0, 29.0], [30.0, 31.0], [32.0, 33.0]]
    pred = se.predict_batch(scene.model_code, np.repeat(scene.params()[None], 3, 0), starts,
                            drives, np.full((3, 2), 0.2), 0.02)  # mpc's look-ahead
    out["prediction " + contact] = np.nan_to_num(pred.state, nan=-1.0).tolist()
# a batch mixing the models a level draws (Storm's rolling and slipping balls)
scenes = [se.Scene(), se.Scene(contact="slipping"), se.Scene(contact="point")]
starts = np.zeros((3, 7))
for i, scene in enumerate(scenes):
    state = se.initial_state(scene, x=0.002, y=-0.001, start="lab-rest", omega=30.0)
    starts[i, :len(state)] = state
batch = se.simulate_batch(scenes, starts, t_end=1.0, omega=[28.0, 30.0, 32.0], dt_out=0.05)
out["batch mixed"] = np.nan_to_num(batch.state, nan=-1.0).tolist()
pred = se.predict_batch(np.array([sc.model_code for sc in scenes]),
                        np.array([sc.params() for sc in scenes]), starts, drives,
                        np.full((3, 2), 0.2), 0.02)
out["prediction mixed"] = np.nan_to_num(pred.state, nan=-1.0).tolist()
from saddle_env.iontrap import PaulTrap, RRFTrap, simulate_ion
for trap in (RRFTrap(omega=20.0, kappa=123.0, omega_B=3.0, kappa_t=-5.0),
             PaulTrap(omega=40.0)):
    ion = simulate_ion(trap, [1e-3, -5e-4, 2e-3, 0.0], 2.0, dt_out=0.05)
    out["ion " + type(trap).__name__] = ion.state.tolist()
print(json.dumps({"status": _aot.status(), "runs": out}))
"""


@pytest.fixture(scope="module")
def built_copy(tmp_path_factory):
    """A copy of the package with a build made in it (`precompile --aot`), as this machine's
    numba sees its CPU; the folder and the environment that imports the copy."""
    tmp_path = tmp_path_factory.mktemp("aot")
    shutil.copytree(Path(saddle_env.__file__).parent, tmp_path / "saddle_env",
                    ignore=shutil.ignore_patterns("__pycache__", "_aot"))
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": str(tmp_path)}
    for name in ("SADDLE_ENV_FULL_KERNELS", _aot.AOT_ENV, _aot.AOT_CPU_ENV,  # as users run
                 *_aot.CPU_VARIABLES):
        env.pop(name, None)
    done = subprocess.run([sys.executable, "-m", "saddle_env.coldstart.precompile", "--aot"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=2400)
    assert done.returncode == 0, done.stderr
    return tmp_path, env


@pytest.mark.slow
def test_a_build_starts_every_level_and_simulate_without_compiling_bit_for_bit(built_copy):
    """A fresh process on an empty cache takes, from the build, every level's first steps
    (single, vector on one thread and vector on numba's threads; and a slipping-only
    environment's, which no level draws), a first simulate, simulate_batch and
    predict_batch of each contact model, a batch mixing rolling and slipping balls and a
    first ion in each trap, compiling only a few small helpers called from Python, with
    the JIT's results to the last bit; an edited source retires the build."""
    from saddle_env.envs import LEVEL_IDS

    tmp_path, env = built_copy
    manifest = json.loads((tmp_path / "saddle_env" / "_aot" / _aot.MANIFEST).read_text())
    assert {tuple(m["flags"]) for m in manifest["modules"]} == {
        ("ROLLING_ON",), ("SLIPPING_ON",), ("COULOMB_ON",), ("ROLLING_ON", "SLIPPING_ON"),
        ("ION_ON",), ("ROLLING_ON", "RESIST_ON")}

    code = _FIRST_CALLS % (list(LEVEL_IDS),)
    # the empty cache of a fresh install: only the build's modules
    fresh = {**env, "NUMBA_CACHE_DIR": str(tmp_path / "empty")}
    compiled = compiled_in_fresh_process(code, fresh, cwd=str(tmp_path))
    entry_points = {"place", "step_scalar", "step_serial", "step_parallel", "integrate_h",
                    "_step_range_scalar", "_step_range", "integrate_batch",
                    "integrate_segments"}
    # a per-scene copy is named after its original: step_scalar__rolling
    assert compiled[-1] == "<lambda>", compiled
    assert not {name.split("__")[0] for name in compiled} & entry_points, compiled
    assert len(set(compiled) - {"<lambda>"}) <= 20, compiled  # small helpers called from Python

    def run(aot: str) -> dict:
        out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path,
                             env={**env, _aot.AOT_ENV: aot}, capture_output=True,
                             text=True, timeout=900)
        assert out.returncode == 0, out.stderr[-2000:]
        return json.loads(out.stdout.strip().splitlines()[-1])

    ahead, jit = run("1"), run("0")
    assert ahead["status"].startswith("ahead-of-time kernels in use (6 modules")
    assert jit["status"].startswith("no ahead-of-time kernels: turned off")
    builds = [ahead]
    upper = tmp_path / "saddle_env" / "_aot" / "x86-64-v4" / _aot.MANIFEST
    if upper.exists():                      # an AVX-512 machine: that build ran; now the other
        assert "x86-64-v4" in ahead["status"], ahead["status"]
        upper.rename(upper.with_suffix(".off"))
        try:
            builds.append(run("1"))
        finally:
            upper.with_suffix(".off").rename(upper)
        assert "x86-64-v4" not in builds[1]["status"], builds[1]["status"]
    for build in builds:
        assert build["runs"].keys() == jit["runs"].keys()
        for key in jit["runs"]:
            assert np.array_equal(np.array(build["runs"][key]), np.array(jit["runs"][key])), key

    engine = tmp_path / "saddle_env" / "envs" / "engine.py"
    source = engine.read_text()
    engine.write_text(source + "\n# an edit after the build\n")
    try:
        stale = run("1")
    finally:
        engine.write_text(source)                  # the build serves the next test again
    assert "built from other sources" in stale["status"]
    for key in jit["runs"]:
        assert np.array_equal(np.array(stale["runs"][key]), np.array(jit["runs"][key])), key


# What LLVM reports for two CPU models (numba's host features; abridged to the x86 ISA
# extensions): Haswell, the first at x86-64-v3, and Sandy Bridge, with AVX but below it.
ZNVER4 = (_aot.LEVEL_FEATURES[_aot.BASELINE]
          + ",+avx512f,+avx512vl,+avx512bw,+avx512cd,+avx512dq,+adx,+sha")
HASWELL = ("+64bit,+avx,+avx2,+bmi,+bmi2,+cmov,+crc32,+cx16,+cx8,+f16c,+fma,+fsgsbase,+fxsr,"
           "+invpcid,+lzcnt,+mmx,+movbe,+pclmul,+popcnt,+rdrnd,+sahf,+sse,+sse2,+sse3,+sse4.1,"
           "+sse4.2,+ssse3,+xsave,+xsaveopt,-avx512f,-avx512vl,-adx,-rdseed,-sha")
SANDYBRIDGE = ("+64bit,+avx,-avx2,-bmi,-bmi2,+cmov,+crc32,+cx16,+cx8,-f16c,-fma,+fxsr,-lzcnt,"
               "+mmx,-movbe,+pclmul,+popcnt,+sahf,+sse,+sse2,+sse3,+sse4.1,+sse4.2,+ssse3,"
               "+xsave,+xsaveopt,-avx512f")


@pytest.mark.slow
def test_a_build_for_the_level_runs_under_another_cpu_model_and_only_at_the_level(
        built_copy):
    """The build is made for x86-64-v3 (not this machine's model), a fresh process whose
    numba is told it runs on a Haswell takes a single and a 256-ball vector env's first
    steps from it compiling no entry point, and one told it runs on a Sandy Bridge (AVX,
    no AVX2) does not use it and says why once."""
    tmp_path, env = built_copy
    manifest = json.loads((tmp_path / "saddle_env" / "_aot" / _aot.MANIFEST).read_text())
    assert (manifest["cpu"], manifest["features"]) == (
        _aot.BASELINE, _aot.LEVEL_FEATURES[_aot.BASELINE])
    assert manifest["cpu"] != _aot.machine()["cpu"]
    here = _aot.machine()
    v4 = {**here, "cpu": "x86-64-v4", "features": _aot.LEVEL_FEATURES["x86-64-v4"]}
    upper = tmp_path / "saddle_env" / "_aot" / "x86-64-v4" / _aot.MANIFEST
    assert upper.exists() == (_aot.unusable(v4, here) is None)  # built where it can run
    code = ("import numpy as np, gymnasium as gym, saddle_env\n"
            "from saddle_env.compilation import aot\n"
            "env = gym.make('SaddleTrap-Gusty-v0'); env.reset(seed=0); env.step(np.zeros(1))\n"
            "vec = gym.make_vec('SaddleTrap-Gusty-v0', num_envs=256); vec.reset(seed=0)\n"
            "vec.step(np.zeros((256, 1)))\n"
            "assert aot.status().startswith('ahead-of-time kernels in use'), aot.status()\n"
            "assert 'x86-64-v4' not in aot.status(), aot.status()\n")
    haswell = {**env, "NUMBA_CACHE_DIR": str(tmp_path / "empty-haswell"),
               "NUMBA_CPU_NAME": "haswell", "NUMBA_CPU_FEATURES": HASWELL}
    compiled = compiled_in_fresh_process(code, haswell, cwd=str(tmp_path))
    assert compiled[-1] == "<lambda>", compiled
    firsts = {"place", "step_scalar", "step_serial", "step_parallel", "_step_range"}
    assert not {name.split("__")[0] for name in compiled} & firsts, compiled

    below = {**env, "NUMBA_CPU_NAME": "sandybridge", "NUMBA_CPU_FEATURES": SANDYBRIDGE}
    out = subprocess.run(
        [sys.executable, "-c", "import saddle_env, saddle_env.envs\n"
         "from saddle_env.compilation import aot, specialise as S\n"
         "from saddle_env.scene import ROLLING, SLIPPING\n"
         "S.specialise((ROLLING,), False, saddle_env.envs.control_step)\n"
         "S.specialise((SLIPPING,), False, saddle_env.envs.control_step)\n"
         "print(aot.status())"],
        cwd=tmp_path, env=below, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("no ahead-of-time kernels: this CPU (sandybridge) lacks "
                                 "avx2, bmi, bmi2, f16c, fma, lzcnt, movbe of the "
                                 "instruction-set level x86-64-v3"), out.stdout
    assert out.stderr.count("ahead-of-time kernels are not used") == 1, out.stderr


def _setup_commands():
    """setup.py's build commands, without running setup()."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "saddle_env_setup", Path(saddle_env.__file__).parents[1] / "setup.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("outcome", ["built", "failed", "skipped"])
def test_the_install_ships_a_new_build_or_none(tmp_path, monkeypatch, outcome):
    """setup.py's build_aot (a wheel's build folder): an earlier build and the build's caches
    never reach the wheel; a failed or skipped build leaves no modules and the install goes
    on."""
    from setuptools.dist import Distribution

    setup = _setup_commands()
    aot = tmp_path / "saddle_env" / "_aot"
    aot.mkdir(parents=True)
    (aot / "k_old.so").write_text("an earlier build")
    (tmp_path / "saddle_env" / "__pycache__").mkdir()

    def build(root, env):
        assert env["NUMBA_CACHE_DIR"] != os.environ.get("NUMBA_CACHE_DIR")
        assert env.get(_aot.AOT_CPU_ENV) is None           # a wheel's: the level's
        (root / "saddle_env" / "_aot").mkdir()
        (root / "saddle_env" / "_aot" / "k_rolling.so").write_text("built")
        (root / "saddle_env" / "envs" / "__pycache__").mkdir(parents=True)
        return outcome == "built"

    monkeypatch.setattr(setup, "_run_build", build)
    monkeypatch.setenv("SADDLE_ENV_AOT", "0" if outcome == "skipped" else "1")
    cmd = setup.build_aot(Distribution())
    cmd.build_lib, cmd.editable_mode = str(tmp_path), False
    cmd.run()
    shipped = sorted(p.name for p in aot.iterdir()) if aot.exists() else []
    assert shipped == (["k_rolling.so"] if outcome == "built" else [])
    assert [Path(p).name for p in cmd.get_outputs()] == shipped
    assert outcome == "skipped" or not list((tmp_path / "saddle_env").rglob("__pycache__"))


def test_an_editable_install_builds_for_its_own_cpu_and_a_wheel_for_the_level(tmp_path,
                                                                              monkeypatch):
    """An editable install's build is used only where it is made: it is compiled for the
    machine's CPU (`SADDLE_ENV_AOT_CPU=host`) unless the user says otherwise; a wheel's
    build is left to the default, the levels (`aot.build_targets`)."""
    from setuptools.dist import Distribution

    setup = _setup_commands()
    seen = []
    monkeypatch.setattr(setup, "_run_build",
                        lambda root, env: seen.append(env.get(_aot.AOT_CPU_ENV)) or False)
    monkeypatch.setenv("SADDLE_ENV_AOT", "1")
    monkeypatch.delenv(_aot.AOT_CPU_ENV, raising=False)
    for editable in (True, False):
        cmd = setup.build_aot(Distribution())
        cmd.build_lib, cmd.editable_mode = str(tmp_path), editable
        monkeypatch.setattr(setup, "__file__", str(tmp_path / "setup.py"))
        cmd.run()
    monkeypatch.setenv(_aot.AOT_CPU_ENV, "baseline")   # the user's choice wins
    cmd.editable_mode = True
    cmd.run()
    assert seen == ["host", None, "baseline"]


def test_a_build_that_overruns_is_stopped_with_its_workers(tmp_path, monkeypatch):
    """The time limit stops the build's whole process group (its worker processes too)."""
    setup = _setup_commands()
    pkg = tmp_path / "saddle_env" / "coldstart"
    pkg.mkdir(parents=True)
    (pkg.parent / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    pid_file = tmp_path / "worker.pid"
    (pkg / "precompile.py").write_text(
        "import subprocess, sys, time\n"
        "w = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])\n"
        f"open({str(pid_file)!r}, 'w').write(str(w.pid))\n"
        "time.sleep(60)\n")
    monkeypatch.setattr(setup, "BUILD_TIMEOUT_S", 1.5)
    assert setup._run_build(tmp_path, dict(os.environ)) is False
    worker = int(pid_file.read_text())
    assert gone_within(worker, 5), "the build's worker process outlived the time limit"
