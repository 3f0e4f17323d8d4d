"""Compile, beside a training run, what its closing comparison will need.

``train.py`` ends by comparing the agent with best-const and `mpc` on fresh episodes
(`agents.training.run_report.compare`). On a fresh install that comparison first compiles the vector
env's threaded step (200 balls step over threads, which training's smaller batches never
do) and `mpc`'s look-ahead for the level's contact models, after the main job's training
(how long that takes: docs/coldstart.md). `train` starts this module
in a second process as training begins, where the second core has room, and waits for it
before the comparison; with a warm cache it loads and exits in seconds.

    python -m agents.training.compile_ahead ENV_ID EPISODES MAX_EPISODE_STEPS [RUN_DIR]

It runs the comparison's two baselines for a few steps on the comparison's batch size, which
compiles (or loads) the same functions with the same signatures. Given the run's folder, it
then draws the learning curve's reference lines (best-const and `mpc` on the curve's own
episodes, `run_report.curve_references`) there, so the end of the run only checks that they
are for the curve's episode set and reads them: `mpc` on Capture's 256 validation episodes
is a long job for the second core. It starts only where that
cannot race the run's own work on shared files: a registered level as it is (no
``--env-kwargs``) whose best constant speed is already in the cache, so neither process
searches for it. ``SADDLE_ENV_COMPILE_AHEAD=0`` turns it off.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

OFF_ENV = "SADDLE_ENV_COMPILE_AHEAD"
STEPS = 3          # mpc's look-ahead first runs within its first steps
WAIT_S = 300.0     # the longest the comparison waits for it (then compiles by itself)
EPISODES_WAIT_S = 120.0   # the longest it waits for the run to write its curve's episode set


def start(settings: Any, run_dir: Path | None = None) -> subprocess.Popen | None:
    """The compile-ahead process for ``settings``' comparison, or None where it does not
    apply (no comparison, RLlib, options over the level, best-const not cached, turned off)."""
    from ..control.best_constant import cached_best_constant

    if (settings.compare_episodes <= 0 or settings.backend == "rllib" or settings.env_kwargs
            or os.environ.get(OFF_ENV, "1") == "0"):
        return None
    _, config = settings.environment()
    from ..control.best_constant import PAIRED_EPISODES

    steps = settings.max_episode_steps       # mpc's reference speed and the best-const row
    if cached_best_constant(config, max_episode_steps=steps) is None or \
            cached_best_constant(config, max_episode_steps=steps, paired=PAIRED_EPISODES) is None:
        return None
    return subprocess.Popen(
        [sys.executable, "-m", f"{__package__}.compile_ahead", settings.env_id,
         str(settings.compare_episodes), str(settings.max_episode_steps),
         *([str(run_dir)] if run_dir is not None else [])],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def finish(proc: subprocess.Popen | None, wait_s: float = WAIT_S) -> None:
    """Wait up to ``wait_s`` for ``proc`` (0: not at all), then stop it if it still runs."""
    if proc is None:
        return
    try:
        proc.wait(timeout=wait_s)
    except subprocess.TimeoutExpired:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def compile_comparison(env_id: str, episodes: int, max_episode_steps: int) -> None:
    """Step best-const and `mpc` as the comparison does, for `STEPS` steps."""
    from saddle_env.envs import get_level

    from ..control.rollout import policy_actor, run_episodes
    from ..evaluation.policies import load_policy
    from ..seeds import COMPARE_SEED

    config = get_level(env_id).config()
    seeds = [COMPARE_SEED + i for i in range(episodes)]
    for name in ("best-const", "mpc"):
        act, independent = policy_actor(load_policy(name, config,
                                                    max_episode_steps=max_episode_steps))
        run_episodes(config, act, seeds, max_episode_steps=STEPS, row_independent=independent)


def draw_curve_references(env_id: str, run_dir: Path, wait_s: float = EPISODES_WAIT_S) -> None:
    """The curve's reference lines in ``run_dir`` once the run has written its episode set
    (the selection does so as training starts); nothing if it does not within ``wait_s``."""
    import time

    from saddle_env.envs import get_level

    from .run_report import CURVE_EPISODES, reference_lines

    path = run_dir / CURVE_EPISODES
    end = time.monotonic() + wait_s
    while not path.is_file():
        if time.monotonic() > end:
            return
        time.sleep(0.5)
    reference_lines(run_dir, get_level(env_id).config(), env_id, strict=False)


def _exit_with_parent() -> None:
    """Exit when the process that started this one is gone: a run killed before its own
    SIGTERM handler is in place cannot stop this process, which would otherwise compile on
    for up to a minute with nobody to use it."""
    import threading
    import time

    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(0)

    threading.Thread(target=watch, daemon=True).start()


def main(argv: Sequence[str] | None = None) -> int:
    """Compile the comparison's kernels for ``ENV_ID EPISODES STEPS [RUN_DIR]``; returns 0."""
    env_id, episodes, steps, *run_dir = (argv if argv is not None else sys.argv[1:])
    _exit_with_parent()
    compile_comparison(env_id, int(episodes), int(steps))
    if run_dir:
        draw_curve_references(env_id, Path(run_dir[0]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
