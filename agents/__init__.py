"""Controllers for the SaddleTrap task levels, and the tools that train, evaluate and benchmark
them. One package per job; each imports only from the ones before it:

1. `agents.seeds`, `agents.paths`, `agents.cli_args`: the seed ranges, where the files are,
   and what every command line shares;
2. `agents.control`: controllers with Stable-Baselines3's ``predict`` (constant speeds,
   the searched best constant, ``mpc``, the clairvoyant reference) and the seeded rollouts
   they are measured with;
3. `agents.evaluation`: policies by name or file, model files read as data, and
   ``saddle-eval``;
4. `agents.training`: the seam behind ``train.py``, its recipes and its back ends
   (`agents.training.backends`: SB3, SBX, RLlib);
5. `agents.benchmark`: the benchmark (``python -m agents.benchmark``), its report, the
   leaderboard, headroom, time to target, the training profile and shipping an agent.

``tests/test_imports.py`` holds the order. A module's old flat name (``agents.mpc``) fails
with a message naming its new place.
"""

import importlib.util
import sys
from pathlib import Path
from types import ModuleType


def _moved_names() -> ModuleType:
    """`saddle_env._moved` (standard library only), loaded from its file without running
    ``saddle_env/__init__``, which loads numba and the simulator: so ``import agents.seeds``
    stays cheap. Registered under its own name, so ``import saddle_env`` later reuses it."""
    name = "saddle_env._moved"
    if name in sys.modules:
        return sys.modules[name]
    package = importlib.util.find_spec("saddle_env")   # finds the package without importing it
    if package is None or not package.submodule_search_locations:
        raise ModuleNotFoundError("agents needs the saddle_env package", name="saddle_env")
    spec = importlib.util.spec_from_file_location(
        name, Path(package.submodule_search_locations[0]) / "_moved.py")
    assert spec is not None and spec.loader is not None  # a .py file path always has both
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


_moved = _moved_names()

# The old names under the name this package was imported by: `agents` in a source checkout,
# `saddle_agents` when installed (pyproject.toml says why).
_moved.announce({old.replace("agents", __name__, 1): new.replace("agents", __name__)
                 for old, new in {
    "agents.baselines": "agents.control (controllers, best_constant, mpc) and agents.evaluation.policies",
    "agents.controllers": "agents.control.controllers",
    "agents.rollout": "agents.control.rollout",
    "agents.best_constant": "agents.control.best_constant",
    "agents.mpc": "agents.control.mpc",
    "agents.clairvoyant": "agents.control.clairvoyant",
    "agents.policies": "agents.evaluation.policies",
    "agents.model_files": "agents.evaluation.model_files",
    "agents.literal_kwargs": "agents.evaluation.literal_kwargs",
    "agents.rllib_policy": "agents.evaluation.rllib_policy",
    "agents.runs": "agents.training.runs",
    "agents.recipes": "agents.training.recipes",
    "agents.schedules": "agents.training.schedules",
    "agents.shaping": "agents.training.shaping",
    "agents.warm_start": "agents.training.warm_start",
    "agents.imitation": "agents.training.imitation",
    "agents.compile_ahead": "agents.training.compile_ahead",
    "agents.run_report": "agents.training.run_report",
    "agents.sb3_backend": "agents.training.backends.sb3",
    "agents.sbx_backend": "agents.training.backends.sbx",
    "agents.rllib_backend": "agents.training.backends.rllib",
    "agents.benchmark_report": "agents.benchmark.report",
    "agents.leaderboard": "agents.benchmark.leaderboard",
    "agents.headroom": "agents.benchmark.headroom",
    "agents.time_to_target": "agents.benchmark.time_to_target",
    "agents.profile_training": "agents.benchmark.profile_training",
    "agents.rllib_benchmark": "agents.benchmark.rllib_throughput",
    "agents.ship": "agents.benchmark.ship",
}.items()})
