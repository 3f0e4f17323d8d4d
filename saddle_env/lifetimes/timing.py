"""How long one lifetime curve takes, and what the integrator's tolerance buys.

``python -m saddle_env.lifetimes.timing`` simulates the curve the validation asks to be fast
(15 speeds × 24 releases of a 19 mm steel ball on the lab's P2 saddle, each until the ball
leaves or 120 s, the shipped calibration) at several relative tolerances, alternating them
over rounds, and prints each tolerance's median time as a ratio to the model's own (rtol
1e-7), with how far its mean lifetimes lie from the tightest tolerance's. Results go to
``--out`` as JSON.

``--first-call`` times instead what a user waits for first: the validation page's example
`predict_lifetimes` call in a fresh interpreter with an empty numba cache (a new temporary
``NUMBA_CACHE_DIR``), so only the install's ahead-of-time kernels can spare it a compile,
and prints the import's and the call's seconds and whether those kernels were in use.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ..jobs.files import write_text_atomically
from .model import load_calibration, release_times

SPEEDS = np.linspace(0.6, 3.0, 15)  # rev/s: below the threshold to well above it
TOLERANCES = (1e-6, 1e-7, 1e-8, 1e-10)
SADDLE = (2.67, 2.51)  # the lab's P2, c₊ and c₋ [1/m]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The parsed command line of ``python -m saddle_env.lifetimes.timing``."""
    p = argparse.ArgumentParser(prog="python -m saddle_env.lifetimes.timing",
                                description="Time one lifetime curve (15 speeds × 24 releases) "
                                            "at several integrator tolerances.")
    p.add_argument("--rounds", type=int, default=3, help="alternating rounds (>= 1)")
    p.add_argument("--releases", type=int, default=24, help="releases per speed (>= 1)")
    p.add_argument("--out", type=Path, default=Path("bench_results/lifetimes.json"),
                   help="JSON file for the results")
    p.add_argument("--first-call", action="store_true",
                   help="time a first predict_lifetimes in a fresh interpreter, empty numba "
                        "cache (print JSON; --out unused)")
    args = p.parse_args(argv)
    if args.rounds < 1 or args.releases < 1:
        p.error("--rounds and --releases must be >= 1")
    return args


# The validation page's example call, timed in a fresh interpreter.
_FIRST_CALL = """
import json, time
t0 = time.perf_counter()
from saddle_env.lifetimes import predict_lifetimes
from saddle_env.compilation import aot
t1 = time.perf_counter()
predict_lifetimes(2.67, 4.66, "steel", [1.3, 2.0], diameter_mm=19, releases=8)
t2 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "first_call_s": t2 - t1, "aot": aot.status()}))
"""


def first_call() -> dict[str, object]:
    """The seconds of a fresh interpreter's import and first `predict_lifetimes` call."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        out = subprocess.run([sys.executable, "-c", _FIRST_CALL], env=env, check=True,
                             capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    args = parse_args(argv)
    if args.first_call:
        print(json.dumps(first_call()))
        return 0
    model, _ = load_calibration()
    times: dict[float, list[float]] = {tol: [] for tol in TOLERANCES}
    means: dict[float, np.ndarray] = {}
    release_times(model.with_(t_max=1.0), *SADDLE, "steel", 19.0, SPEEDS[:1], 1, 0)  # compile
    for k in range(args.rounds):
        for tol in TOLERANCES:
            start = time.perf_counter()
            escapes = release_times(model.with_(rtol=tol), *SADDLE, "steel", 19.0, SPEEDS,
                                    args.releases, seed=0)
            times[tol].append(time.perf_counter() - start)
            means[tol] = escapes.mean(axis=1)
        print(f"round {k + 1}/{args.rounds} done", file=sys.stderr, flush=True)
    own: float | None = statistics.median(times[model.rtol]) if model.rtol in times else None
    ref = means[min(TOLERANCES)]
    rows = []
    for tol in TOLERANCES:
        median = statistics.median(times[tol])
        gap = float(np.max(np.abs(np.log(means[tol] / ref))))
        rows.append({"rtol": tol, "median_s": median,
                     "ratio_to_model_rtol": None if own is None else median / own,
                     "max_abs_log_mean_vs_tightest": gap})
        ratio = "" if own is None else f" ({median / own:.2f}× the model's)"
        print(f"rtol {tol:g}: {median:6.2f} s per curve{ratio}, mean lifetimes within "
              f"{100 * gap:.0f} % of the tightest tolerance's")
    write_text_atomically(args.out, json.dumps({
        "curve": f"{len(SPEEDS)} speeds x {args.releases} releases, 19 mm steel on P2, "
                 f"t_max {model.t_max:g} s", "rounds": args.rounds, "rows": rows,
        "command": "python -m saddle_env.lifetimes.timing"}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
