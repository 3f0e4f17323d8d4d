"""Throughput of SaddleTrap-v0 against CartPole-v1, measured in the same run.

    python -m saddle_env.envs.benchmark [--seconds S] [--num-envs N] [--out FILE.json]

Reports steps per second through ``gym.make`` (wrappers included) for both, vector-env
steps per second for ``num_envs`` balls against Gymnasium's own vectorised CartPole, and
the wall time from a fresh interpreter to the first ``step`` with warm and cold numba caches.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import saddle_env  # noqa: F401  (registers SaddleTrap-v0)


def _single_rate(env_id: str, action, seconds: float) -> float:
    env = gym.make(env_id)
    env.reset(seed=0)
    env.step(action)
    n = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        _, _, term, trunc, _ = env.step(action)
        n += 1
        if term or trunc:
            env.reset()
    return n / (time.perf_counter() - start)


def _vector_rate(env_id: str, num_envs: int, actions, seconds: float,
                 lockstep: bool = True) -> float:
    env = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point")
    if not lockstep:
        env.unwrapped.engine.lockstep = False  # every ball through integrate_h
    env.reset(seed=0)
    env.step(actions)
    n = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        env.step(actions)
        n += 1
    return n * num_envs / (time.perf_counter() - start)


_FIRST_STEP = """
import time; t0 = time.perf_counter()
import gymnasium as gym, numpy as np, saddle_env
env = gym.make("SaddleTrap-v0"); env.reset(seed=0)
t1 = time.perf_counter(); env.step(np.zeros(1, np.float32)); t2 = time.perf_counter()
print(t1 - t0, t2 - t1)
"""


def first_step_times(cold: bool) -> tuple[float, float]:
    """(import+make+reset, first step) seconds in a fresh interpreter."""
    env = dict(os.environ)
    tmp = None
    if cold:
        # An empty numba cache directory forces compilation from scratch.
        tmp = tempfile.mkdtemp(prefix="numba-cold-")
        env["NUMBA_CACHE_DIR"] = tmp
    try:
        out = subprocess.run([sys.executable, "-c", _FIRST_STEP], capture_output=True, text=True,
                             env=env, check=True).stdout.split()
    finally:
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
    return float(out[0]), float(out[1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="timing window per measurement")
    ap.add_argument("--num-envs", type=int, default=1024)
    ap.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    ap.add_argument("--skip-cold", action="store_true", help="skip the cold-cache compile timing")
    args = ap.parse_args(argv)
    if args.seconds <= 0 or args.num_envs < 1:
        ap.error("--seconds must be > 0 and --num-envs >= 1")
    res: dict[str, float] = {}
    print("single env through gym.make ...", flush=True)
    res["cartpole_steps_per_s"] = _single_rate("CartPole-v1", 0, args.seconds)
    res["saddle_steps_per_s"] = _single_rate("SaddleTrap-v0", np.zeros(1, np.float32), args.seconds)
    res["single_ratio"] = res["saddle_steps_per_s"] / res["cartpole_steps_per_s"]
    print(f"  CartPole-v1 {res['cartpole_steps_per_s']:,.0f}/s, SaddleTrap-v0 "
          f"{res['saddle_steps_per_s']:,.0f}/s, ratio {res['single_ratio']:.2f}", flush=True)
    n = args.num_envs
    print(f"vector env, {n} copies ...", flush=True)
    res["cartpole_vector_steps_per_s"] = _vector_rate("CartPole-v1", n, np.zeros(n, dtype=np.int64),
                                                      args.seconds)
    res["saddle_vector_steps_per_s"] = _vector_rate("SaddleTrap-v0", n, np.zeros((n, 1), np.float32),
                                                    args.seconds)
    res["saddle_vector_scalar_steps_per_s"] = _vector_rate(
        "SaddleTrap-v0", n, np.zeros((n, 1), np.float32), args.seconds, lockstep=False)
    print(f"  CartPoleVectorEnv {res['cartpole_vector_steps_per_s']:,.0f}/s, SaddleTrap "
          f"{res['saddle_vector_steps_per_s']:,.0f}/s (without SIMD blocks "
          f"{res['saddle_vector_scalar_steps_per_s']:,.0f}/s)", flush=True)
    warm = first_step_times(cold=False)
    res["first_step_warm_s"], res["import_make_reset_warm_s"] = warm[1], warm[0]
    print(f"first step, warm cache: {warm[1]:.3f} s (import+make+reset {warm[0]:.2f} s)", flush=True)
    if not args.skip_cold:
        cold = first_step_times(cold=True)
        res["first_step_cold_s"], res["import_make_reset_cold_s"] = cold[1], cold[0]
        print(f"first step, cold cache: {cold[1]:.2f} s (import+make+reset {cold[0]:.2f} s)")
    if args.out:
        args.out.write_text(json.dumps(res, indent=2))
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
