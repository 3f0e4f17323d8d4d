import os
import sys
from pathlib import Path

# Tests import their helpers and the independent reference model as plain modules.
sys.path.insert(0, str(Path(__file__).parent))

# The tests run the clone's own `agents` (installed, it is `saddle_agents`: pyproject.toml),
# however pytest is started and from whatever folder, and so do the programs they start.
_ROOT = str(Path(__file__).resolve().parents[1])
sys.path.insert(1, _ROOT)
os.environ["PYTHONPATH"] = os.pathsep.join(
    [_ROOT, *(p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p)])

# Searches the tests trigger go to a temporary cache, never into the shipped
# agents/control/best_const.json (subprocesses inherit the variable).
import atexit  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402

if "SADDLE_ENV_BEST_CONST_CACHE" not in os.environ:
    _cache_dir = tempfile.mkdtemp(prefix="saddle-best-const-")
    atexit.register(shutil.rmtree, _cache_dir, ignore_errors=True)   # no litter in /tmp
    os.environ["SADDLE_ENV_BEST_CONST_CACHE"] = os.path.join(_cache_dir, "best_const.json")

# The suite runs what users run: each scene's own compiled copy of the kernels, which the
# install's ahead-of-time build (saddle_env.compilation.aot) holds for the registered levels and
# each contact model, so where the build matches the sources (a fresh install, CI) most tests
# compile nothing and check the build itself; with edited sources the JIT compiles the
# copies. The tests that compare a copy with the full kernels set SADDLE_ENV_FULL_KERNELS=1
# themselves (monkeypatch.setenv). Until 2026-11-26 the suite ran the full kernels, which no
# build holds (docs/coldstart.md, "The test suite on the users' kernels").
os.environ.setdefault("SADDLE_ENV_FULL_KERNELS", "0")

# The few training runs with a closing comparison are seconds long: a compile-ahead process
# beside each (agents/training/compile_ahead.py) would only add its start-up. Its own tests turn it
# on.
os.environ.setdefault("SADDLE_ENV_COMPILE_AHEAD", "0")


# A cold run (CI's fresh clone) spends minutes compiling on one core while the other idles:
# a large session starts tests/warm_cache.py beside it, which compiles into the on-disk cache
# what the tests reach later. SADDLE_ENV_TEST_WARM=0 turns it off.
WARM_AFTER_TESTS = 500   # smaller sessions (one file, a -k selection) do without it
_warmer = []             # (the helper's process, the file it names its finished jobs in)

# Tests that need what the helper compiles, by the start of "file::test name" and the
# helper's job (warm_cache.JOBS, done in this order; the first match counts): where the
# suite first needs each (a cold run with numba's compile events, docs/coldstart.md). When
# the helper runs, these tests run last, in their own order, so that it has the rest of the
# suite's time to compile what they need; and each waits until the helper has finished its
# job, or has stopped, rather than compile the same kernels a second time beside it. On a
# warm cache the helper is through in a second or two and nothing waits.
WAIT_FOR_HELPER = (
    ("test_clairvoyant.py::", "threaded step"),
    ("test_coulomb.py::", "rolling resistance"),     # and the rolling and coulomb env before it
    ("test_env.py::", "full kernels"),
    ("test_integrators.py::", "full kernels"),
    ("test_iontrap.py::", "full kernels"),
    ("test_prediction.py::", "full kernels"),
    ("test_lockstep.py::", "storm threaded step"),
)
HELPER_WAIT_S = 600.0    # longer than any job; past it the test compiles for itself


def _helper_job(item) -> str | None:
    """The helper's job whose kernels the test ``item`` needs (None if none)."""
    test = f"{item.path.name}::{item.name}"
    return next((job for start, job in WAIT_FOR_HELPER if test.startswith(start)), None)


def _helper_wanted(config, items) -> bool:
    return (len(items) >= WARM_AFTER_TESTS and os.environ.get("SADDLE_ENV_TEST_WARM") != "0"
            and not config.getoption("collectonly"))


def pytest_collection_modifyitems(session, config, items):
    if _helper_wanted(config, items):
        items[:] = ([item for item in items if _helper_job(item) is None]
                    + [item for item in items if _helper_job(item) is not None])


def pytest_collection_finish(session):
    import subprocess
    import sys

    if not _helper_wanted(session.config, session.items):
        return
    done = Path(tempfile.mkdtemp(prefix="saddle-warm-")) / "done"
    done.touch()
    _warmer.append((subprocess.Popen(
        [sys.executable, str(Path(__file__).with_name("warm_cache.py")), str(done)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL), done))


def pytest_runtest_setup(item):
    job = _helper_job(item)
    if job is None or not _warmer:
        return
    import time

    proc, done = _warmer[0]
    deadline = time.monotonic() + HELPER_WAIT_S
    while proc.poll() is None and time.monotonic() < deadline:
        if job in done.read_text().splitlines():
            return
        time.sleep(0.05)


def pytest_sessionfinish(session, exitstatus):
    for proc, done in _warmer:
        if proc.poll() is None:    # a short or failed session: what it finished stays cached
            proc.terminate()
            proc.wait(timeout=30)
        shutil.rmtree(done.parent, ignore_errors=True)
