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

# The suite meets every set of contact models, and a per-scene copy of the compiled loop for
# each set cost its cold run about 70 CPU s (docs/coldstart.md): it runs the full kernels,
# compiled once. The tests of the copies themselves turn this off (monkeypatch.delenv).
os.environ.setdefault("SADDLE_ENV_FULL_KERNELS", "1")
