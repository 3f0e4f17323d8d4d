"""``saddle-bench``: work-precision benchmark of the simulator against scipy.

Writes, to ``--out DIR`` (default ``./bench_results``):

* ``bench.csv`` — one row per (model tier, solver, method, step or tolerance), appended as
  each completes (Ctrl-C keeps the finished rows);
* ``bench_single.png``, ``bench_batch.png`` — work-precision diagrams (wall time per
  simulated second against the maximum position error over the run), made from the CSV;
* ``summary.json`` — the issue's targets, the cheapest setting per error level and the peers;
* ``rounds.json`` — with compiled peers: the picked settings of the simulator and each peer
  timed again in alternating rounds (`core.rounds`), merged into the summary's ``peers``.

``saddle-bench --replot DIR/bench.csv`` rebuilds the figures and the summary from a CSV;
``saddle-bench --pilot-cost`` runs no sweep and writes ``DIR/pilot_cost.json``, what
``simulate(..., tol=...)``'s pilot costs against one run at its pick (`pilot.pilot_cost`).
See docs/accuracy.md for what is measured and how to read it.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import platform
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path

from ..accuracy import AccuracyWarning
from ..jobs.blas import limit_blas_threads
from .core import (
    COLUMNS,
    MODEL_TIERS,
    TIERS,
    Case,
    PeerCache,
    measure_jacobi,
    reference,
    rounds,
    tasks,
    warm_up,
)
from .peer import PeerModel
from .peers import BY_KEY, missing, parse_peers
from .report import Summary, merge_rounds, peer_comparison, plot, read_rows, summarize

# The alternating rounds' times of the peers and the simulator (`core.rounds`), beside bench.csv.
ROUNDS = "rounds.json"

__all__ = ["Case", "PeerModel", "main", "run"]


def _progress(items: list, quiet: bool):
    try:
        from tqdm import tqdm
    except ImportError:  # tqdm is in the plot/test extras; fall back to plain lines
        tqdm = None
    if quiet:
        return items, None
    if tqdm is None:
        return items, None
    bar = tqdm(items, desc="saddle-bench", unit="run", file=sys.stderr, dynamic_ncols=True)
    return bar, bar


def run(out: str | Path, quick: bool = False, tiers: Sequence[str] = TIERS,
        peers: bool | Sequence[str] = True,
        batch: bool = True, figures: bool = True, jacobi_periods: int | None = None,
        quiet: bool = False, case: Case | None = None) -> Summary:
    """Run the benchmark; return the summary (also written to ``out/summary.json``).
    ``peers``: True (all), False (none) or the peers' keys (`peers.parse_peers`)."""
    with warnings.catch_warnings():
        # The sweep runs deliberately coarse fixed steps: their AccuracyWarning is the point.
        warnings.simplefilter("ignore", AccuracyWarning)
        return _run(out, quick, tiers, peers, batch, figures, jacobi_periods, quiet, case)


def _run(out, quick, tiers, peers, batch, figures, jacobi_periods, quiet, case):
    from ..simulate import DEFAULT_METHOD, DEFAULT_RTOL

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if case is None:
        case = (Case(t_end=1.0, batch_n=128, batch_t_end=0.2) if quick else Case())
    csv_path = out / "bench.csv"
    blas = limit_blas_threads(1)
    warm_up(case)
    refs = {t: reference(case, t) for t in MODEL_TIERS if t == "rolling" or t in tiers}
    keys = tuple(peer_keys(peers))
    cache = PeerCache()
    todo = list(tasks(case, quick, tuple(tiers), keys, batch, cache))
    interrupted = False
    started = time.time()
    with open(csv_path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=COLUMNS)
        writer.writeheader()
        fh.flush()
        items, bar = _progress(todo, quiet)
        try:
            for desc, fn in items:
                if bar is not None:
                    bar.set_postfix_str(desc, refresh=False)
                elif not quiet:
                    print(f"saddle-bench: {desc}", file=sys.stderr)
                writer.writerow(fn(refs))
                fh.flush()
        except KeyboardInterrupt:
            interrupted = True
            print("\nsaddle-bench: interrupted; keeping the finished rows", file=sys.stderr)
        finally:
            if bar is not None:
                bar.close()
    extra: Summary = {}
    comparison = peer_comparison(read_rows(csv_path)) if not interrupted else {}
    if cache.solvers and comparison:
        if not quiet:
            print("saddle-bench: the picked settings again, in alternating rounds",
                  file=sys.stderr)
        timed = rounds(case, comparison, cache, n_rounds=3 if quick else 7)
        with open(out / ROUNDS, "w", encoding="utf-8") as fh:
            json.dump(timed, fh, indent=2)
    if jacobi_periods is None:
        jacobi_periods = 1000 if quick else 10_000
    if jacobi_periods and not interrupted:
        extra["target_jacobi"] = {"target": "relative drift <= 1e-9 over 1e4 saddle periods",
                                  **measure_jacobi(case, jacobi_periods)}
        extra["target_jacobi"]["met"] = bool(
            extra["target_jacobi"]["jacobi_drift_relative"] <= 1e-9 and jacobi_periods >= 10_000)
    import numba

    extra["machine"] = {"cpus": os.cpu_count(), "numba_threads": numba.get_num_threads(),
                        "python": platform.python_version(), "numpy": _version("numpy"),
                        "scipy": _version("scipy"), "numba": numba.__version__,
                        "platform": platform.platform()}
    extra["machine"]["blas_pinned_to_one_thread"] = blas
    extra["run"] = {"quick": quick, "interrupted": interrupted,
                    "wall_s": time.time() - started, "csv": str(csv_path)}
    extra["default"] = {"method": DEFAULT_METHOD, "rtol": DEFAULT_RTOL}
    extra["peers_run"] = {"asked": list(keys), "skipped": skipped_peers(keys),
                          "versions": peer_versions(keys)}
    return finish(csv_path, out, figures, extra)


def finish(csv_path: Path, out: Path, figures: bool, extra: Summary | None = None
           ) -> Summary:
    """Summary and figures from the CSV."""
    from ..simulate import DEFAULT_METHOD, DEFAULT_RTOL

    rows = read_rows(csv_path)
    summary = summarize(rows, extra)
    timed = csv_path.parent / ROUNDS  # written by `run` beside the CSV, kept by --replot
    if "peers" in summary and timed.is_file():
        merge_rounds(summary["peers"], json.loads(timed.read_text(encoding="utf-8")))
    if figures and rows:
        default = {"method": DEFAULT_METHOD, "rtol": DEFAULT_RTOL}
        summary["figures"] = [str(plot(rows, out, batch=False, default=default))]
        if any(math.isfinite(r["batch_us_per_ball_sim_s"]) for r in rows):
            summary["figures"].append(str(plot(rows, out, batch=True, default=default)))
    with open(out / "summary.json", "w", encoding="utf-8") as fh:
        json.dump(summary, fh, indent=2, default=_json_default)
    return summary


# What a run adds to its summary that its CSV does not hold: --replot keeps them.
RUN_FACTS = ("target_jacobi", "machine", "run", "default", "peers_run")


def _run_facts(run_dir: Path) -> Summary:
    """The run's own facts from the summary.json beside its CSV (empty if there is none)."""
    path = run_dir / "summary.json"
    if not path.is_file():
        return {}
    old = json.loads(path.read_text(encoding="utf-8"))
    return {k: old[k] for k in RUN_FACTS if k in old}


def _json_default(v: object) -> object:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return str(v)


def peer_keys(peers: bool | Sequence[str]) -> tuple[str, ...]:
    """The peers' keys ``run``'s ``peers`` argument names."""
    if peers is True:
        return parse_peers("all")
    if peers is False:
        return ()
    return parse_peers(",".join(peers))


def skipped_peers(keys: Sequence[str]) -> dict[str, str]:
    """The asked peers that cannot run here, and why."""
    return {k: why for k in keys if k in BY_KEY and (why := missing(BY_KEY[k])) is not None}


def peer_versions(keys: Sequence[str]) -> dict[str, str]:
    """The installed version of each asked peer's package."""
    from importlib.metadata import PackageNotFoundError

    out = {}
    for k in keys:
        package = BY_KEY[k].solver if k in BY_KEY else "scipy"
        for name in (package, "jax") if package == "diffrax" else (package,):
            try:
                out[name] = _version(name)
            except PackageNotFoundError:
                pass
    return out


def _version(name: str) -> str:
    from importlib.metadata import version

    return version(name)


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m saddle_env.workprecision``."""
    ap = argparse.ArgumentParser(
        prog="saddle-bench",
        description="Work-precision benchmark: wall time per simulated second against the "
                    "maximum position error over a run, for each contact model, integrator "
                    "and tolerance/step, with scipy solve_ivp on a plain-numpy right-hand "
                    "side as the peer.")
    ap.add_argument("--out", default="bench_results", metavar="DIR",
                    help="output directory (CSV, PNG, summary.json)")
    ap.add_argument("--quick", action="store_true",
                    help="a small sweep over a 1 s run (for CI; about a minute)")
    ap.add_argument("--tiers", default=",".join(TIERS),
                    help="comma-separated subset of " + ",".join(TIERS))
    ap.add_argument("--peers", default="all", metavar="LIST",
                    help="the peers to run: all, compiled, scipy or none, or a comma-separated "
                         "list of plain (scipy on the plain-numpy model), "
                         + ", ".join(BY_KEY) + "; peers not installed are listed as skipped")
    ap.add_argument("--no-peers", action="store_true", help="run no peer (--peers none)")
    ap.add_argument("--no-batch", action="store_true", help="skip the batch timings")
    ap.add_argument("--no-figures", action="store_true", help="skip the PNG diagrams")
    ap.add_argument("--jacobi-periods", type=int, default=None, metavar="N",
                    help="saddle periods for the Jacobi-drift run (default 1e4; 1e3 with "
                         "--quick; 0 skips it)")
    ap.add_argument("--replot", default=None, metavar="CSV",
                    help="rebuild figures and summary.json from an existing bench.csv")
    ap.add_argument("--pilot-cost", action="store_true",
                    help="instead of the sweep: time simulate(..., tol=...)'s pilot against "
                         "one run at the setting it picks (OUT/pilot_cost.json)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    return ap


def _pilot_cost(out: Path) -> Summary:
    """``--pilot-cost``: the pilot's timings in ``out/pilot_cost.json``, one line each."""
    from .pilot import pilot_cost

    out.mkdir(parents=True, exist_ok=True)
    limit_blas_threads(1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)  # a coarse candidate's is expected
        result = pilot_cost()
    with open(out / "pilot_cost.json", "w", encoding="utf-8") as fh:
        json.dump(result, fh, indent=2)
    for tol, r in result["tols"].items():
        print(f"tol {tol} m: pilot {r['pilot_s'] * 1e3:.1f} ms, run {r['run_s'] * 1e3:.1f} ms "
              f"({r['ratio']:.1f}x); {r['picked']}")
    return result


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.pilot_cost:
        _pilot_cost(Path(args.out))
        return 0
    if args.replot is not None:
        csv_path = Path(args.replot)
        if not args.replot or not csv_path.is_file():
            ap.error(f"--replot: no such file {str(csv_path)!r}")
        out = Path(args.out) if args.out != "bench_results" else csv_path.parent
        out.mkdir(parents=True, exist_ok=True)
        summary = finish(csv_path, out, not args.no_figures, _run_facts(csv_path.parent))
    else:
        tiers = tuple(t.strip() for t in args.tiers.split(",") if t.strip())
        bad = [t for t in tiers if t not in TIERS]
        if bad or not tiers:
            ap.error(f"--tiers must be a comma-separated subset of {','.join(TIERS)}, got "
                     f"{args.tiers!r}")
        if args.jacobi_periods is not None and args.jacobi_periods < 0:
            ap.error("--jacobi-periods must be >= 0")
        try:
            peers = () if args.no_peers else parse_peers(args.peers)
        except ValueError as exc:
            ap.error(f"--{exc}")
        for key, why in skipped_peers(peers).items():
            print(f"saddle-bench: skipping peer {key}: {why}", file=sys.stderr)
        summary = run(args.out, quick=args.quick, tiers=tiers, peers=peers,
                      batch=not args.no_batch, figures=not args.no_figures,
                      jacobi_periods=args.jacobi_periods, quiet=args.quiet)
    print(_headline(summary))
    return 0


def _peer_lines(summary: Summary) -> list[str]:
    """The peers' table: per error level, ours and each peer's cheapest setting meeting it."""
    peers = summary.get("peers", {})
    lines = []
    for form, what in (("one_ball", "one rolling ball, µs per simulated second"),
                       ("batch", f"per ball in a batch of {peers.get('batch_n', 0):.0f} "
                                 f"(project on {peers.get('threads', 0):.0f} threads), µs per "
                                 "simulated second")):
        for name, level in peers.get(form, {}).items():
            lines.append(f"peers, {what}, error <= {name} m:")
            mine = level["project"]
            again = f"; rounds {mine['time_rounds']:.1f}" if "time_rounds" in mine else ""
            lines.append(f"  {'saddle_env ' + mine['label']:32s} {mine['time']:10.1f}  error "
                         f"{mine['error_m']:.1e} m at {mine['setting']:g}{again}")
            for key, r in level.items():
                if key in ("project", "fastest", "fastest_rounds"):
                    continue
                jit = (f"  (compile {r['compile_s']:.1f} s, not timed)"
                       if math.isfinite(r["compile_s"]) and r["compile_s"] > 0.05 else "")
                again = (f"; rounds {r['time_rounds']:.1f}, {r['time_vs_project_rounds']:.2f}x"
                         if "time_rounds" in r else "")
                lines.append(f"  {r['label']:32s} {r['time']:10.1f}  error {r['error_m']:.1e} m "
                             f"at rtol {r['setting']:g}  {r['time_vs_project']:.2f}x ours"
                             f"{again}{jit}")
    return lines


def _headline(summary: Summary) -> str:
    lines = []
    t1 = summary.get("target_speedup", {})
    if "speedup_cheapest_rows" in t1:
        lines.append(f"one rolling ball at <= 1e-9 m: {t1['ours']['us_per_sim_s']:.0f} µs per "
                     f"simulated second ({t1['ours']['label']} {t1['ours']['setting']:g}); scipy "
                     f"DOP853 {t1['scipy_dop853']['us_per_sim_s']:.0f} µs: "
                     f"{t1['speedup_cheapest_rows']:.0f}x (interpolated "
                     f"{t1['speedup_interpolated']:.0f}x)")
    t2 = summary.get("target_batch")
    if t2:
        lines.append(f"batch of {t2['batch_n']:.0f} rolling balls, rk4 dt = 1 ms: "
                     f"{t2['ball_steps_per_s']:.3g} ball-steps/s on {t2['threads']:.0f} threads")
    t3 = summary.get("target_jacobi")
    if t3:
        lines.append(f"Jacobi drift over {t3['periods']} saddle periods at rtol {t3['rtol']:g}: "
                     f"{t3['jacobi_drift_relative']:.2e} relative; centre off its offset "
                     f"surface by <= {t3['offset_surface_error_m']:.1e} m")
    lines += _peer_lines(summary)
    run = summary.get("peers_run", {})
    for key, why in run.get("skipped", {}).items():
        lines.append(f"peer {key} skipped: {why}")
    for f in summary.get("figures", []):
        lines.append(f"wrote {f}")
    return "\n".join(lines)
