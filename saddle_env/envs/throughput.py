"""Throughput of SaddleTrap-v0 against CartPole-v1, measured in the same run.

    python -m saddle_env.envs.throughput [--seconds S] [--num-envs N] [--sizes 16,64,...]
                                        [--out DIR] [--skip-cold] [--no-figure]

Measures the environments as users make them: the single env through ``gym.make`` (its
wrappers included) against CartPole-v1 through ``gym.make``, and the vector env through
``gym.make_vec(ID, num_envs=N)`` with Gymnasium's default vectorisation against
``gym.make_vec("CartPole-v1", num_envs=N)`` (Gymnasium's `CartPoleVectorEnv`), plus
SaddleTrap with its SIMD block path off (every ball through the scalar integrator), a sweep
over batch sizes, and the wall time from a fresh interpreter to the first ``step`` with warm
and cold numba caches.

The two environments of a comparison are timed in alternating rounds, and each one's rate
is its best round: other processes on the machine slow some rounds, and the best is the
closest to the machine's own speed. A round spans whole episodes' worth of steps (a vector
env's round is ``max_episode_steps`` steps, so it holds one reset of every ball), and the
steps run as a training loop runs them, resets included.

Writes to ``--out`` (default ``bench_results/env``), after every measurement so that Ctrl-C
keeps what was done: ``throughput.json`` (all figures, the ratios, the date and commit of
the run and the machine), ``batch_sizes.csv`` (the sweep) and ``throughput.png`` (the sweep
plotted; needs matplotlib).
"""

from __future__ import annotations

import argparse
import csv
import datetime
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
                 "cartpole_steps_per_s", "ratio")
SINGLE_ROUND_STEPS = 2000  # steps per timed round of a single env (several episodes)


class _Stepper:
    """An environment made as users make it, stepped in rounds of ``round_steps`` steps;
    ``per_step`` env-steps per `step` call."""

    def __init__(self, env, action, round_steps: int, per_step: int, resets: bool):
        self.env, self.action = env, action
        self.round_steps, self.per_step, self.resets = round_steps, per_step, resets
        self.made_as = str(env)
        env.reset(seed=0)
        env.step(action)  # the first step (compiled code loaded) is not timed

    def round(self) -> tuple[float, float]:
        """Run one round; return (env-steps, seconds)."""
        env, action = self.env, self.action
        start = time.perf_counter()
        if self.resets:
            for _ in range(self.round_steps):
                _, _, term, trunc, _ = env.step(action)
                if term or trunc:
                    env.reset()
        else:   # a vector env resets its balls itself
            for _ in range(self.round_steps):
                env.step(action)
        return self.round_steps * self.per_step, time.perf_counter() - start


def single_stepper(env_id: str) -> _Stepper:
    """``gym.make(env_id)``, wrappers included, stepped with a zero action."""
    env = gym.make(env_id)
    action = np.zeros(1, np.float32) if env_id.startswith("SaddleTrap") else 0
    return _Stepper(env, action, SINGLE_ROUND_STEPS, 1, resets=True)


def vector_stepper(env_id: str, num_envs: int, lockstep: bool = True) -> _Stepper:
    """``gym.make_vec(env_id, num_envs=num_envs)`` with Gymnasium's default vectorisation,
    stepped with zero actions; ``lockstep`` False turns SaddleTrap's SIMD blocks off."""
    env = gym.make_vec(env_id, num_envs=num_envs)
    if not lockstep:
        from .vector import SaddleTrapVectorEnv
        vec = env.unwrapped
        assert isinstance(vec, SaddleTrapVectorEnv)  # lockstep is SaddleTrap's switch
        vec.engine.lockstep = False  # every ball through integrate_h
    action = (np.zeros((num_envs, 1), np.float32) if env_id.startswith("SaddleTrap")
              else np.zeros(num_envs, dtype=np.int64))
    spec = gym.spec(env_id)
    return _Stepper(env, action, spec.max_episode_steps or 500, num_envs, resets=False)


def best_rates(steppers: list[_Stepper], seconds: float) -> list[float]:
    """Each stepper's best rate [env-steps/s] over rounds taken in turn (one round of each,
    then again) until every one has run ``seconds``, and at least one round each."""
    spent = [0.0] * len(steppers)
    best = [0.0] * len(steppers)
    while min(spent) < seconds or not all(best):
        for k, stepper in enumerate(steppers):
            steps, dt = stepper.round()
            spent[k] += dt
            best[k] = max(best[k], steps / dt)
    for stepper in steppers:
        stepper.env.close()
    return best


def _single_rates(seconds: float) -> tuple[float, float, str]:
    """(CartPole-v1, SaddleTrap-v0) steps per second through ``gym.make``, and how
    SaddleTrap was made."""
    cartpole, saddle = single_stepper("CartPole-v1"), single_stepper("SaddleTrap-v0")
    made_as = saddle.made_as
    rates = best_rates([cartpole, saddle], seconds)
    return rates[0], rates[1], made_as


def _vector_rates(num_envs: int, seconds: float) -> tuple[dict[str, float], str]:
    """The sweep row for ``num_envs``, and how SaddleTrap's vector env was made."""
    saddle = vector_stepper("SaddleTrap-v0", num_envs)
    made_as = saddle.made_as
    scalar = vector_stepper("SaddleTrap-v0", num_envs, lockstep=False)
    cartpole = vector_stepper("CartPole-v1", num_envs)
    rates = best_rates([saddle, scalar, cartpole], seconds)
    return {"num_envs": num_envs, "saddle_steps_per_s": rates[0],
            "saddle_scalar_steps_per_s": rates[1], "cartpole_steps_per_s": rates[2],
            "ratio": rates[0] / rates[2]}, made_as


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
        self.figures: dict[str, object] = {"date": _today(), "commit": _commit(), "machine": _machine()}
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


def _today() -> str:
    """The run's date (UTC), which the figure store's entries carry."""
    return datetime.datetime.now(datetime.timezone.utc).date().isoformat()


def _commit() -> str | None:
    """The commit of the code measured (a ``+`` when the work tree has changes), or None
    outside a git checkout."""
    here = Path(__file__).resolve().parent
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=here,
                             capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=here, capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    return rev + ("+" if dirty.strip() else "")


def _machine() -> dict[str, object]:
    """What the figures depend on: the interpreter, the CPUs and their load when the run
    began, numba's threads, Gymnasium's version and whether the install's ahead-of-time
    kernels run (else numba's JIT, compiled for this CPU)."""
    import numba

    from ..compilation import aot
    return {"python": platform.python_version(), "platform": platform.platform(),
            "cpus": os.cpu_count(), "load_average": list(os.getloadavg()),
            "numba_threads": numba.get_num_threads(), "gymnasium": gym.__version__,
            # the folder relative to the package: a results file names no local paths
            "kernels": aot.status().replace(str(aot.AOT_DIR), "saddle_env/_aot")}


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
    cartpole, saddle, made_as = _single_rates(args.seconds)
    res.set(cartpole_steps_per_s=cartpole, saddle_steps_per_s=saddle,
            single_ratio=saddle / cartpole, single_made_as=made_as)
    print(f"  {made_as}: {saddle:,.0f} steps/s; CartPole-v1 {cartpole:,.0f}/s; "
          f"ratio {saddle / cartpole:.2f}", flush=True)
    sizes = sorted(set(args.sizes) | {args.num_envs})
    for n in sizes:
        row, made_as = _vector_rates(n, args.seconds)
        res.add_row(row)
        print(f"vector env, {n} balls ({made_as}): SaddleTrap {row['saddle_steps_per_s']:,.0f}/s "
              f"(without SIMD blocks {row['saddle_scalar_steps_per_s']:,.0f}/s), "
              f"CartPoleVectorEnv {row['cartpole_steps_per_s']:,.0f}/s, ratio {row['ratio']:.2f}",
              flush=True)
        if n == args.num_envs:
            res.set(cartpole_vector_steps_per_s=row["cartpole_steps_per_s"],
                    saddle_vector_steps_per_s=row["saddle_steps_per_s"],
                    saddle_vector_scalar_steps_per_s=row["saddle_scalar_steps_per_s"],
                    vector_ratio=row["ratio"], vector_num_envs=n, vector_made_as=made_as)
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
    ap.add_argument("--seconds", type=float, default=3.0,
                    help="time each environment of a comparison runs, in alternating rounds")
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
