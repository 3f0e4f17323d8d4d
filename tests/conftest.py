import sys
from pathlib import Path

# Tests import their helpers and the independent reference model as plain modules.
sys.path.insert(0, str(Path(__file__).parent))

# Searches the tests trigger go to a temporary cache, never into the shipped
# agents/best_const.json (subprocesses inherit the variable).
import atexit  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402

if "SADDLE_ENV_BEST_CONST_CACHE" not in os.environ:
    _cache_dir = tempfile.mkdtemp(prefix="saddle-best-const-")
    atexit.register(shutil.rmtree, _cache_dir, ignore_errors=True)   # no litter in /tmp
    os.environ["SADDLE_ENV_BEST_CONST_CACHE"] = os.path.join(_cache_dir, "best_const.json")

# The suite runs what users run: each scene's own compiled copy of the kernels, which the
# install's ahead-of-time build (saddle_env._aot) holds for the registered levels and each
# contact model, so where the build matches the sources (a fresh install, CI) most tests
# compile nothing and check the build itself; with edited sources the JIT compiles the
# copies. The tests that compare a copy with the full kernels set SADDLE_ENV_FULL_KERNELS=1
# themselves (monkeypatch.setenv). Until 2026-11-26 the suite ran the full kernels, which no
# build holds (docs/coldstart.md, "The test suite on the users' kernels").
os.environ.setdefault("SADDLE_ENV_FULL_KERNELS", "0")

# The few training runs with a closing comparison are seconds long: a compile-ahead process
# beside each (agents/compile_ahead.py) would only add its start-up. Its own tests turn it on.
os.environ.setdefault("SADDLE_ENV_COMPILE_AHEAD", "0")


# A cold run (CI's fresh clone) spends minutes compiling on one core while the other idles:
# a large session starts tests/warm_cache.py beside it, which compiles into the on-disk cache
# what the tests reach later. SADDLE_ENV_TEST_WARM=0 turns it off.
WARM_AFTER_TESTS = 500   # smaller sessions (one file, a -k selection) do without it
_warmer = []


def pytest_collection_finish(session):
    import subprocess
    import sys

    if (len(session.items) < WARM_AFTER_TESTS or os.environ.get("SADDLE_ENV_TEST_WARM") == "0"
            or session.config.getoption("collectonly")):
        return
    _warmer.append(subprocess.Popen(
        [sys.executable, str(Path(__file__).with_name("warm_cache.py"))],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))


def pytest_sessionfinish(session, exitstatus):
    for proc in _warmer:
        if proc.poll() is None:    # a short or failed session: what it finished stays cached
            proc.terminate()
            proc.wait(timeout=30)
