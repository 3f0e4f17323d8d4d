"""``saddle-reproduce``: regenerate the seed paper's figures and numbers from this model."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NoReturn

from .context import Context


def _figures() -> dict[str, tuple[Callable[[Context], None], str]]:
    """Figure name → (function, one-line description), in the paper's order.

    Imported lazily so that ``--help`` and flag errors do not pay for numba and scipy.
    """
    from .analogy_fig import fig_analogy
    from .damping_fig import fig_damping
    from .dynamics_figs import fig_feasible, fig_support, fig_trajectories, fig_trapping
    from .lifetimes_fig import fig_lifetimes
    from .theory_figs import fig_asymmetric, fig_critical, fig_eigen

    return {
        "trajectories": (fig_trajectories, "rolling/slipping orbits, precession, r(t) vs linear"),
        "eigen": (fig_eigen, "eigen-frequency loci vs Omega, Omega_crt marked"),
        "critical": (fig_critical, "Omega_crt vs R and a; Omega_crt^2 vs 1/(a-2R)"),
        "trapping": (fig_trapping, "simulated trapping time vs Omega, three balls"),
        "support": (fig_support, "support force vs time at Omega = 20, 30"),
        "feasible": (fig_feasible, "starting points that never detach, Omega = 35, 45"),
        "asymmetric": (fig_asymmetric, "stable band of Omega on an asymmetric saddle"),
        "analogy": (fig_analogy, "ball vs RRF ion and Paul trap: trajectories, thresholds"),
        "damping": (fig_damping, "growth rate vs Omega with air drag; the stable band moves"),
        "lifetimes": (fig_lifetimes, "real saddles: the lab's trapping times vs the calibration"),
    }


FIGURE_NAMES = ("trajectories", "eigen", "critical", "trapping", "support", "feasible",
                "asymmetric", "analogy", "damping", "lifetimes")


class _Parser(argparse.ArgumentParser):
    """Errors as one line and a hint (exit status 2), not the whole usage block."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n(see {self.prog} --help)\n")


def _names(value: str) -> list[str]:
    names = [v.strip() for v in value.split(",") if v.strip()]
    unknown = [n for n in names if n not in FIGURE_NAMES]
    if not names or unknown:
        raise argparse.ArgumentTypeError(
            f"unknown figure(s) {unknown or [value]}; choose from {', '.join(FIGURE_NAMES)}")
    return names


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``saddle-reproduce``."""
    ap = _Parser(
        prog="saddle-reproduce",
        description="Regenerate the seed paper's quantitative figures (PNG + CSV) and its key "
                    "numbers (summary.json) from this project's model. Figures: "
                    + ", ".join(FIGURE_NAMES) + ".",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("paper_figures"), metavar="DIR",
                    help="output folder (PNG, CSV, summary.json, cache/)")
    ap.add_argument("--quick", action="store_true",
                    help="small grids and short runs (under a minute; for CI)")
    ap.add_argument("--no-cache", action="store_true",
                    help="recompute sweeps even if cached results exist (they are rewritten)")
    ap.add_argument("--only", type=_names, default=None, metavar="NAME[,NAME]",
                    help="produce only these figures")
    ap.add_argument("--no-progress", action="store_true", help="hide the progress bars")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``saddle-reproduce``; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.out.exists() and not args.out.is_dir():
        parser.error(f"--out {args.out} exists and is not a folder")
    try:
        import matplotlib
        import tqdm  # noqa: F401
    except ImportError as exc:  # the plot extra is optional for the package itself
        print(f"saddle-reproduce: {exc.name} is needed: pip install 'saddle-env[plot]'",
              file=sys.stderr)
        return 1
    matplotlib.use("Agg")
    names = args.only or list(FIGURE_NAMES)
    ctx = Context(out=args.out, quick=args.quick, use_cache=not args.no_cache,
                  progress=not args.no_progress)
    ctx.out.mkdir(parents=True, exist_ok=True)
    figures = _figures()
    start = time.perf_counter()
    done: list[str] = []
    try:
        for k, name in enumerate(names, 1):
            t0 = time.perf_counter()
            print(f"[{k}/{len(names)}] {name}: {figures[name][1]} ...", file=sys.stderr,
                  flush=True)
            figures[name][0](ctx)
            done.append(name)
            print(f"[{k}/{len(names)}] {name} done in {time.perf_counter() - t0:.1f} s",
                  file=sys.stderr, flush=True)
    except KeyboardInterrupt:
        print(f"\nsaddle-reproduce: interrupted; finished figures kept in {ctx.out}: "
              f"{', '.join(done) or 'none'}", file=sys.stderr)
        return 130
    ctx.update_summary({"_timing": {"figures": done, "wall_s": time.perf_counter() - start,
                                    "quick": ctx.quick}})
    print(f"saddle-reproduce: {len(done)} figure(s) in {time.perf_counter() - start:.1f} s "
          f"-> {ctx.out}", file=sys.stderr)
    return 0
