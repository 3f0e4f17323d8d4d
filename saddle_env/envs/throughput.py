"""Throughput of SaddleTrap-v0 against CartPole-v1, measured in the same run.

    python -m saddle_env.envs.throughput [--seconds S] [--num-envs N] [--sizes 16,64,...]
                                        [--out DIR] [--skip-cold] [--no-figure]

Measures steps per second through ``gym.make`` (wrappers included) for both environments,
vector-env steps per second for ``--num-envs`` balls against Gymnasium's own vectorised
CartPole (and SaddleTrap with its SIMD block path off, every ball through the scalar
integrator), a sweep over batch sizes, and the wall time from a fresh interpreter to the
first ``step`` with warm and cold numba caches.

Writes to ``--out`` (default ``bench_results/env``), after every measurement so that Ctrl-C
keeps what was done: ``throughput.json`` (all figures and the machine), ``batch_sizes.csv``
(the sweep) and ``throughput.png`` (the sweep plotted; needs matplotlib).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

# SaddleTrap-v0 is registered: importing this module ran saddle_env's __init__ first.

SWEEP_COLUMNS = ("num_envs", "saddle_steps_per_s", "saddle_scalar_steps_per_s",
                 "cartpole_steps_per_s")


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


def _vector_rate(env_id: str, num_envs: int, seconds: float, lockstep: bool = True) -> float:
    env = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point")
    if not lockstep:
        from .vector import SaddleTrapVectorEnv
        vec = env.unwrapped
        assert isinstance(vec, SaddleTrapVectorEnv)  # lockstep is SaddleTrap's switch
        vec.engine.lockstep = False  # every ball through integrate_h
    actions = (np.zeros((num_envs, 1), np.float32) if env_id.startswith("SaddleTrap")
               else np.zeros(num_envs, dtype=np.int64))
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


def _sizes(text: str) -> list[int]:
    try:
        sizes = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--sizes must be comma-separated integers, got {text!r}") from None
    if not sizes or min(sizes) < 1:
        raise argparse.ArgumentTypeError(f"--sizes must be positive integers, got {text!r}")
    return sizes


class _Results:
    """Figures written to disk as soon as they are measured."""

    def __init__(self, out: Path):
        out.mkdir(parents=True, exist_ok=True)
        self.out = out
        self.figures: dict[str, object] = {
            "machine": {"python": platform.python_version(), "platform": platform.platform(),
                        "cpus": os.cpu_count(), "numba_threads": _numba_threads()}}
        self.sweep: list[dict[str, float]] = []

    def set(self, **figures: object) -> None:
        self.figures.update(figures)
        self._write()

    def add_row(self, row: dict[str, float]) -> None:
        self.sweep.append(row)
        with open(self.out / "batch_sizes.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=SWEEP_COLUMNS)
            w.writeheader()
            w.writerows(self.sweep)
        self._write()

    def _write(self) -> None:
        data = dict(self.figures, batch_sizes=self.sweep)
        (self.out / "throughput.json").write_text(json.dumps(data, indent=2))


def _numba_threads() -> int:
    import numba
    return numba.get_num_threads()


def plot(sweep: list[dict[str, float]], path: Path) -> bool:
    """Env-steps per second against batch size; False if matplotlib is missing."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    n = [r["num_envs"] for r in sweep]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.loglog(n, [r["saddle_steps_per_s"] for r in sweep], "o-", label="SaddleTrap-v0")
    ax.loglog(n, [r["saddle_scalar_steps_per_s"] for r in sweep], "s--",
              label="SaddleTrap-v0, no SIMD blocks")
    ax.loglog(n, [r["cartpole_steps_per_s"] for r in sweep], "^:", label="CartPoleVectorEnv")
    ax.axhline(1e6, color="grey", lw=0.8)
    ax.set_xlabel("balls (num_envs)")
    ax.set_ylabel("env-steps per second")
    ax.set_title("Vector env throughput (same run)")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def run(args: argparse.Namespace) -> dict[str, object]:
    """Measure the environments' throughput as ``args`` asks; returns the results."""
    res = _Results(args.out)
    print("single env through gym.make ...", flush=True)
    cartpole = _single_rate("CartPole-v1", 0, args.seconds)
    saddle = _single_rate("SaddleTrap-v0", np.zeros(1, np.float32), args.seconds)
    res.set(cartpole_steps_per_s=cartpole, saddle_steps_per_s=saddle,
            single_ratio=saddle / cartpole)
    print(f"  CartPole-v1 {cartpole:,.0f}/s, SaddleTrap-v0 {saddle:,.0f}/s, "
          f"ratio {saddle / cartpole:.2f}", flush=True)
    sizes = sorted(set(args.sizes) | {args.num_envs})
    for n in sizes:
        row = {"num_envs": n,
               "saddle_steps_per_s": _vector_rate("SaddleTrap-v0", n, args.seconds),
               "saddle_scalar_steps_per_s": _vector_rate("SaddleTrap-v0", n, args.seconds,
                                                         lockstep=False),
               "cartpole_steps_per_s": _vector_rate("CartPole-v1", n, args.seconds)}
        res.add_row(row)
        print(f"vector env, {n} balls: SaddleTrap {row['saddle_steps_per_s']:,.0f}/s "
              f"(without SIMD blocks {row['saddle_scalar_steps_per_s']:,.0f}/s), "
              f"CartPoleVectorEnv {row['cartpole_steps_per_s']:,.0f}/s", flush=True)
        if n == args.num_envs:
            res.set(cartpole_vector_steps_per_s=row["cartpole_steps_per_s"],
                    saddle_vector_steps_per_s=row["saddle_steps_per_s"],
                    saddle_vector_scalar_steps_per_s=row["saddle_scalar_steps_per_s"],
                    vector_num_envs=n)
    if not args.no_figure and len(res.sweep) > 1 and plot(res.sweep, args.out / "throughput.png"):
        print(f"wrote {args.out / 'throughput.png'}", flush=True)
    import_s, step_s = first_step_times(cold=False)
    res.set(first_step_warm_s=step_s, import_make_reset_warm_s=import_s)
    print(f"first step, warm cache: {step_s:.3f} s (import+make+reset {import_s:.2f} s)",
          flush=True)
    if not args.skip_cold:
        import_s, step_s = first_step_times(cold=True)
        res.set(first_step_cold_s=step_s, import_make_reset_cold_s=import_s)
        print(f"first step, cold cache: {step_s:.2f} s (import+make+reset {import_s:.2f} s)",
              flush=True)
    return res.figures


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    ap = argparse.ArgumentParser(prog="python -m saddle_env.envs.throughput",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="timing window per measurement")
    ap.add_argument("--num-envs", type=int, default=1024, help="the headline batch size")
    ap.add_argument("--sizes", type=_sizes, default=[16, 64, 256, 1024, 4096],
                    help="batch sizes to sweep, comma-separated (default 16,64,256,1024,4096)")
    ap.add_argument("--out", type=Path, default=Path("bench_results/env"), metavar="DIR",
                    help="where to write throughput.json, batch_sizes.csv, throughput.png")
    ap.add_argument("--skip-cold", action="store_true", help="skip the cold-cache compile timing")
    ap.add_argument("--no-figure", action="store_true", help="skip throughput.png")
    args = ap.parse_args(argv)
    if not args.seconds > 0 or args.num_envs < 1:
        ap.error("--seconds must be > 0 and --num-envs >= 1")
    try:
        run(args)
    except KeyboardInterrupt:
        print(f"\ninterrupted: the figures measured so far are in {args.out}", file=sys.stderr)
        return 130
    print(f"wrote {args.out / 'throughput.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
