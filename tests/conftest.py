import sys
from pathlib import Path

# Tests import their helpers and the independent reference model as plain modules.
sys.path.insert(0, str(Path(__file__).parent))

# Searches the tests trigger go to a temporary cache, never into the shipped
# agents/best_const.json (subprocesses inherit the variable).
import os  # noqa: E402
import tempfile  # noqa: E402

os.environ.setdefault("SADDLE_ENV_BEST_CONST_CACHE",
                      os.path.join(tempfile.mkdtemp(prefix="saddle-best-const-"),
                                   "best_const.json"))
