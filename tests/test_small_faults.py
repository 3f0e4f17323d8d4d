"""Small faults, each refused or fixed by name: an environment without gravity is refused as
``g`` (not blamed on the start position); a wheel is marked platform-specific only when it
holds the compiled modules of the ahead-of-time build (setup.py)."""

import importlib.util
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("g", [0, 0.0])
def test_no_gravity_is_refused_as_g_not_as_the_start(g):
    # it was reported as a start where N/mg <= 0, naming init_offset, init_speed and
    # omega0_range
    import gymnasium as gym

    import saddle_env  # noqa: F401  (registers the levels)
    from saddle_env.envs import EnvConfig

    with pytest.raises(ValueError, match=r"^g must be > 0 m/s\^2 in the environment, got 0"):
        EnvConfig(g=g)
    with pytest.raises(ValueError, match=r"^g must be > 0"):
        gym.make("SaddleTrap-v0", g=g)
    assert EnvConfig(g=1.0).g == 1.0   # weak gravity is a valid (slow) trap


# -- the wheel's platform tag ------------------------------------------------------------------

def _setup_module():
    """setup.py's commands and distribution class, without running setup()."""
    spec = importlib.util.spec_from_file_location("saddle_env_setup_tag", ROOT / "setup.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class _Wheel:
    """What bdist_wheel keeps of its decision: pure (any platform) or not."""

    def __init__(self, root_is_pure: bool):
        self.root_is_pure = root_is_pure


@pytest.mark.parametrize("outcome", ["built", "failed", "skipped"])
def test_a_wheel_is_platform_specific_only_with_compiled_modules(tmp_path, monkeypatch, outcome):
    setup = _setup_module()
    monkeypatch.setenv("SADDLE_ENV_AOT", "0" if outcome == "skipped" else "1")
    dist = setup.BinaryDistribution()
    # before the build: what bdist_wheel's finalize_options reads
    assert dist.has_ext_modules() is (outcome != "skipped")
    wheel = _Wheel(root_is_pure=not dist.has_ext_modules())
    dist.command_obj["bdist_wheel"] = wheel

    def build(root, env):
        if outcome == "built":
            (root / "saddle_env" / "_aot").mkdir(parents=True)
            (root / "saddle_env" / "_aot" / "k_rolling.so").write_text("built")
        return outcome == "built"

    monkeypatch.setattr(setup, "_run_build", build)
    (tmp_path / "saddle_env").mkdir()
    cmd = setup.build_aot(dist)
    cmd.build_lib, cmd.editable_mode = str(tmp_path), False
    cmd.run()
    assert dist.has_ext_modules() is (outcome == "built")
    assert wheel.root_is_pure is (outcome != "built")
    assert bool(cmd.get_outputs()) is (outcome == "built")


@pytest.mark.slow  # a wheel built from the tree: a few seconds
def test_a_wheel_without_the_build_is_pure_python(tmp_path):
    # setuptools builds in the tree: what it makes there that was not there before goes again
    made = [p for p in (ROOT / "build", ROOT / "saddle_env.egg-info") if not p.exists()]
    try:
        _wheel_without_the_build(tmp_path)
    finally:
        for path in made:
            shutil.rmtree(path, ignore_errors=True)


def _wheel_without_the_build(tmp_path):
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                           "--no-build-isolation", "-q", "-w", str(tmp_path), str(ROOT)],
                          env={**os.environ, "SADDLE_ENV_AOT": "0"},
                          capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stderr
    (wheel,) = tmp_path.glob("*.whl")
    assert wheel.name.endswith("-py3-none-any.whl"), wheel.name
    with zipfile.ZipFile(wheel) as z:
        assert not [n for n in z.namelist() if "/_aot/" in n]
        meta = next(n for n in z.namelist() if n.endswith(".dist-info/WHEEL"))
        assert "Root-Is-Purelib: true" in z.read(meta).decode()
