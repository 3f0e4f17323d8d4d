"""``import agents.seeds`` (the seed ranges, read by tools that simulate nothing) stays cheap:
it loads neither numba nor the simulator."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("numba", "saddle_env.integrators", "saddle_env.kernels", "gymnasium")


def test_importing_agents_seeds_loads_no_simulator():
    code = ("import json, sys; import agents.seeds; "
            f"print(json.dumps([m for m in {list(HEAVY)!r} if m in sys.modules]))")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, cwd=ROOT, timeout=120, check=True)
    assert json.loads(out.stdout) == []


def test_the_moved_names_still_answer_after_a_cheap_import():
    """agents/__init__ loads saddle_env._moved without saddle_env/__init__; a later
    ``import saddle_env`` reuses that module, and the old names of both packages still say
    where they went."""
    code = ("import importlib, agents.seeds, saddle_env, sys\n"
            "from saddle_env import _moved\n"
            "assert _moved is sys.modules['saddle_env._moved']\n"
            "finders = [f for f in sys.meta_path if isinstance(f, _moved._MovedFinder)]\n"
            "assert len(finders) == 1, finders\n"
            "for old in ('agents.mpc', 'saddle_env.files'):\n"
            "    try:\n"
            "        importlib.import_module(old)\n"
            "    except _moved.MovedModuleError as exc:\n"
            "        print(exc)\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines == [
        "agents.mpc has moved to agents.control.mpc: import agents.control.mpc, or run "
        "`python -m agents.control.mpc`",
        "saddle_env.files has moved to saddle_env.jobs.files: import saddle_env.jobs.files, or "
        "run `python -m saddle_env.jobs.files`"]
