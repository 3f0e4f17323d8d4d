"""Where one ball's time goes: the simulator's DOP853 against numbalsoda's, on the
benchmark's rolling ball at the tolerance both pick for a position error of 1e-9 m.

    python -m saddle_env.workprecision.profile [--rtol R] [--rounds N] [--out DIR]

Each solver's time per simulated second is split into the right-hand side (its calls, timed
alone in a compiled loop of the same number of calls), the stepping around them (the rest
of a run) and the fixed cost of a call from Python (a run of one step). The simulator counts
its right-hand-side calls; numbalsoda does not report them, so its count is scipy's DOP853
at the same tolerance on the same error test (the same method, so the same steps, within a
few). Needs the ``[peers]`` extra (numbalsoda). Writes ``bench_profile.json`` to ``--out``; the
accuracy page reads it. Timings are CPU time (`time.process_time`), best of ``--rounds``
alternating rounds, so other jobs on the machine slow them less.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..jobs.files import write_text_atomically
from .core import Case, best_of_rounds

CALLS = 200_000  # right-hand-side calls per timing of the right-hand side alone


def _our_rhs_loop():
    """A compiled loop of `kernels.rhs` calls on the simulator's own arrays (unmanaged, as
    the stepping loop passes them), each at a slightly different state."""
    import numba as nb

    from .. import kernels as K
    from ..compilation.jit import unmanaged

    @nb.njit
    def loop(n, model, p, prof, y, dy):
        p, prof, y, dy = unmanaged(p), unmanaged(prof), unmanaged(y), unmanaged(dy)
        acc = 0.0
        x0 = y[0]
        for i in range(n):
            y[0] = x0 + 1e-12 * i
            acc += K.rhs(model, p, prof, 1e-3 * i, y, dy, True) + dy[2]
        y[0] = x0
        return acc

    return loop


def _peer_rhs_loop():
    """The same loop over numbalsoda's right-hand side (the benchmark's equations, on the
    scaled state, as its ``cfunc`` computes them)."""
    import numba as nb

    from .equations import rolling_rates

    rates = nb.njit(rolling_rates(math.sqrt), inline="always")

    @nb.njit
    def loop(n, data, u):
        acc = 0.0
        for i in range(n):
            d = rates(data[0], data[1], data[2], data[3], data[4], data[5], 0.0,
                      (u[0] + 1e-12 * i) * data[6], u[1] * data[7], u[2] * data[8],
                      u[3] * data[9], u[4] * data[10])
            acc += d[2] / data[8] + d[0] / data[6]
        return acc

    return loop


def profile(rtol: float = 1e-10, rounds: int = 7) -> dict:
    """The split of one rolling ball's time, for the simulator and numbalsoda's DOP853."""
    from .. import kernels as K
    from ..integrators import state_scale
    from ..omega import OmegaProfile, drive_row
    from ..simulate import simulate
    from .peers import BY_KEY, Numbalsoda, build

    case = Case()
    sc = case.scene("rolling")
    s0 = case.state("rolling")
    grid = case.grid()
    peer = build(BY_KEY["numbalsoda-dop853"], sc, case.omega)
    kw: dict[str, Any] = dict(omega=case.omega, dt_out=case.dt_out, method="dop853", rtol=rtol)
    ours = simulate(sc, s0, case.t_end, **kw)
    # scipy's DOP853 on the same error test: its count of right-hand-side calls
    lean = build(BY_KEY["scipy-lean"], sc, case.omega)
    peer_evals = lean.single(s0, grid, rtol)[1]

    p, prof = sc.params(), drive_row(OmegaProfile(case.omega))
    y = np.zeros(K.STATE_WIDTH)
    y[: sc.state_size] = s0
    dy = np.zeros(K.STATE_WIDTH)
    our_loop, peer_loop = _our_rhs_loop(), _peer_rhs_loop()
    u = np.asarray(s0) / state_scale(p, sc.model_code)[: sc.state_size]
    assert isinstance(peer, Numbalsoda)
    data = peer.data  # numbalsoda's packed arguments
    first = np.array([0.0, case.dt_out])
    fns = {
        "ours": lambda: simulate(sc, s0, case.t_end, **kw),
        "ours_one_step": lambda: simulate(sc, s0, 1e-3, **kw),
        "ours_rhs": lambda: our_loop(CALLS, sc.model_code, p, prof, y, dy),
        "peer": lambda: peer.single(s0, grid, rtol),
        "peer_one_step": lambda: peer.single(s0, first * 1e-2, rtol),
        "peer_rhs": lambda: peer_loop(CALLS, data, u),
    }
    for fn in fns.values():  # compile
        fn()
    t = best_of_rounds(fns, rounds, clock=time.process_time)
    out: dict = {"rtol": rtol, "rounds": rounds, "t_end_s": case.t_end, "clock": "cpu"}
    for who, evals in (("ours", float(ours.stats.rhs_evaluations)), ("peer", peer_evals)):
        total = t[who] / case.t_end * 1e6                      # µs per simulated second
        fixed = t[f"{who}_one_step"] / case.t_end * 1e6
        rhs_ns = t[f"{who}_rhs"] / CALLS * 1e9
        rhs = evals * rhs_ns * 1e-3 / case.t_end
        out[who] = {"us_per_sim_s": total, "rhs_evals": evals, "rhs_ns_per_call": rhs_ns,
                    "rhs_us_per_sim_s": rhs, "call_us_per_sim_s": fixed,
                    "stepping_us_per_sim_s": total - rhs - fixed,
                    "stepping_ns_per_eval": (total - rhs - fixed) / evals * case.t_end * 1e3}
    out["ours"]["steps"] = int(ours.stats.steps)
    out["peer"]["label"] = "numbalsoda DOP853"
    out["peer_over_ours"] = out["peer"]["us_per_sim_s"] / out["ours"]["us_per_sim_s"]
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    ap = argparse.ArgumentParser(
        prog="python -m saddle_env.workprecision.profile",
        description="Where one rolling ball's time goes, the simulator's DOP853 against "
                    "numbalsoda's: right-hand side, stepping and the call from Python, per "
                    "simulated second (needs the [peers] extra).")
    ap.add_argument("--rtol", type=float, default=1e-10,
                    help="the tolerance both solvers run at (1e-10: each one's pick for a "
                         "position error of 1e-9 m)")
    ap.add_argument("--rounds", type=int, default=7, help="alternating rounds; each keeps its best")
    ap.add_argument("--out", type=Path, default=Path("bench_results/profile"),
                    help="folder for bench_profile.json")
    args = ap.parse_args(argv)
    if not 0 < args.rtol < 1:
        ap.error(f"--rtol must be in (0, 1), got {args.rtol}")
    if args.rounds < 1:
        ap.error(f"--rounds must be at least 1, got {args.rounds}")
    try:
        import numbalsoda  # noqa: F401
    except ImportError:
        ap.exit(2, "error: numbalsoda is not installed: pip install -e '.[peers]' (it needs "
                   "gfortran: apt-get install gfortran)\n")
    res = profile(args.rtol, args.rounds)
    res["date"] = time.strftime("%Y-%m-%d")
    args.out.mkdir(parents=True, exist_ok=True)
    write_text_atomically(args.out / "bench_profile.json", json.dumps(res, indent=2) + "\n")
    print(f"one rolling ball, rtol {args.rtol:g}, CPU µs per simulated second "
          f"(best of {args.rounds} rounds):")
    print(f"  {'':22s}{'total':>8s}{'rhs':>8s}{'stepping':>10s}{'call':>8s}"
          f"{'rhs calls':>11s}{'ns/rhs':>8s}{'ns/step/rhs':>13s}")
    for who, label in (("ours", "saddle_env DOP853"), ("peer", res["peer"]["label"])):
        r = res[who]
        print(f"  {label:22s}{r['us_per_sim_s']:8.1f}{r['rhs_us_per_sim_s']:8.1f}"
              f"{r['stepping_us_per_sim_s']:10.1f}{r['call_us_per_sim_s']:8.1f}"
              f"{r['rhs_evals']:11.0f}{r['rhs_ns_per_call']:8.1f}{r['stepping_ns_per_eval']:13.1f}")
    print(f"  numbalsoda's time over ours: {res['peer_over_ours']:.2f}")
    print(f"wrote {args.out / 'bench_profile.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
