"""What a user of the built wheel does first, run in a venv that has the wheel installed and no
source tree on its path (`.ci/check-wheel` sets that up; by hand: `python -I
.ci/wheel_smoke.py` from any folder but the repository's, with the wheel installed with its
`[train]` extra).

Checks, each failing with a message:

* saddle_env and saddle_agents are imported from the venv's site-packages, not a checkout;
* `saddle_env.__version__` is the installed distribution's version;
* the wheel installs no top-level `agents` (the name OpenAI's Agents SDK owns);
* every SaddleTrap id registered with Gymnasium makes, resets and steps to a finite
  observation inside its space;
* `saddle-eval`, the installed command, evaluates a shipped agent read from the package.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import math
import os
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

SHIPPED_AGENT = "ppo_capture"  # a shipped agent with normaliser statistics beside it
EVAL_EPISODES = 2


def check(ok: bool, what: str) -> None:
    if not ok:
        raise SystemExit(f"wheel check failed: {what}")
    print(f"ok  {what}", flush=True)


def main() -> None:
    site = Path(sysconfig.get_paths()["purelib"]).resolve()
    platsite = Path(sysconfig.get_paths()["platlib"]).resolve()

    import gymnasium as gym
    import numpy as np

    import saddle_agents
    import saddle_env

    for module in (saddle_env, saddle_agents):
        where = Path(module.__file__).resolve()
        check(where.is_relative_to(site) or where.is_relative_to(platsite),
              f"{module.__name__} comes from site-packages ({where})")
    installed = importlib.metadata.version("saddle-env")
    check(saddle_env.__version__ == installed,
          f"saddle_env.__version__ {saddle_env.__version__} is the installed version {installed}")
    dist_files = importlib.metadata.files("saddle-env") or []
    tops = {f.parts[0] for f in dist_files if len(f.parts) > 1 and f.parts[0] != ".."}
    check("agents" not in tops, f"no top-level `agents` in the wheel (it installs {sorted(tops)})")

    ids = sorted(k for k, spec in gym.registry.items()
                 if str(spec.entry_point).startswith("saddle_env"))
    check(sorted(ids) == sorted(saddle_env.envs.LEVEL_IDS) and len(ids) > 0,
          f"Gymnasium's registry holds the {len(ids)} levels")
    for env_id in ids:
        t0 = time.perf_counter()
        env = gym.make(env_id)
        obs, _ = env.reset(seed=0)
        for _ in range(3):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        env.close()
        check(bool(np.all(np.isfinite(obs))) and env.observation_space.contains(obs)
              and math.isfinite(reward),
              f"{env_id}: make, reset, 3 steps ({time.perf_counter() - t0:.1f} s)")

    models = Path(saddle_agents.__file__).parent / "models"
    model = models / f"{SHIPPED_AGENT}.zip"
    check(model.is_file() and (models / f"{SHIPPED_AGENT}.json").is_file(),
          f"the shipped agent {model.name} and its sidecar are in the package")
    check(importlib.util.find_spec("saddle_agents.training.recipes") is not None
          and (Path(saddle_agents.__file__).parent / "hyperparams" / "ppo.yml").is_file(),
          "the recipes (hyperparams/*.yml) are in the package")
    saddle_eval = Path(sys.executable).parent / "saddle-eval"
    t0 = time.perf_counter()
    out = subprocess.run([str(saddle_eval), "--policy", str(model), "--episodes",
                          str(EVAL_EPISODES), "--json", "--no-progress"],
                         capture_output=True, text=True, env={**os.environ, "PYTHONSAFEPATH": "1"})
    if out.returncode != 0:
        print(out.stdout, out.stderr, sep="\n", file=sys.stderr)
    check(out.returncode == 0, f"saddle-eval --policy {model.name} exits 0")
    table = json.loads(out.stdout)
    (row,) = table["policies"]
    time_kept = row["trapping_time"]["mean"]
    check(table["env_id"] == "SaddleTrap-Capture-v0" and table["episodes"] == EVAL_EPISODES
          and row["kind"] == "PPO" and 0.0 < time_kept <= table["episode_length_s"],
          f"saddle-eval ran {model.name} on its level's {EVAL_EPISODES} episodes: kept "
          f"{time_kept:.2f} s ({time.perf_counter() - t0:.1f} s)")
    print("wheel check passed", flush=True)


if __name__ == "__main__":
    main()
