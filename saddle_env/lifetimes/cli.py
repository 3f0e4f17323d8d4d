"""``saddle-lifetimes``: predicted mean trapping times for releases like the lab's.

Its flags are a stable interface (other tools call it): ``--c-plus --c-minus --object
--diameter-mm --rps --releases --seed --tilt --json``. Bad input exits with status 2 and a
message naming the flag; any other error (a release that fails to integrate, a damaged
calibration file) exits 2 with a message naming it.
"""

from __future__ import annotations

import argparse
import json
import sys

from .model import DIAMETER_RANGE_MM, MAX_RELEASES, OBJECTS, predict_lifetimes


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``saddle-lifetimes``."""
    p = argparse.ArgumentParser(
        prog="saddle-lifetimes",
        description="Predict mean trapping times on a real rotating saddle z = c+ x^2 - c- y^2 "
                    "for releases at rest near the centre (the project's calibrated tilt, "
                    "launcher and dissipation; see the validation page).")
    p.add_argument("--c-plus", type=float, required=True, metavar="C",
                   help="curvature c+ of the rising direction [1/m], > 0 (a = 1/c+)")
    p.add_argument("--c-minus", type=float, required=True, metavar="C",
                   help="curvature c- of the falling direction [1/m], > 0 (b = 1/c-)")
    p.add_argument("--object", required=True, choices=OBJECTS,
                   help="'steel': a solid steel ball that rolls (needs --diameter-mm); 'ln2': "
                        "a liquid-nitrogen droplet, a frictionless point that evaporates")
    p.add_argument("--diameter-mm", type=float, metavar="D",
                   help=f"the steel ball's diameter [mm], {DIAMETER_RANGE_MM[0]:g}-"
                        f"{DIAMETER_RANGE_MM[1]:g} and small enough for the saddle's curvature")
    p.add_argument("--rps", type=float, nargs="+", required=True, metavar="F",
                   help="saddle speeds [revolutions per second], each > 0")
    p.add_argument("--releases", type=int, default=24, metavar="N",
                   help=f"releases simulated per speed, 2-{MAX_RELEASES} (default 24)")
    p.add_argument("--seed", type=int, default=0, metavar="S",
                   help="seed of the release points, saddle turns and evaporation (default 0)")
    p.add_argument("--tilt", type=float, metavar="RAD",
                   help="the saddle axis's tilt from the vertical [rad], overriding the "
                        "calibrated one; 0 is a level saddle")
    p.add_argument("--json", action="store_true",
                   help='print {"rps": [...], "mean_s": [...], "std_s": [...], "mean_s_95": '
                        '[[low, high], ...], "model": {...}}, model holding every parameter '
                        "used; mean_s_95 is a 95 %% interval of each mean (the releases' "
                        "sampling error and the calibration's uncertainty)")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.seed < 0:
        parser.error(f"--seed must be >= 0, got {args.seed}")
    try:
        pred = predict_lifetimes(args.c_plus, args.c_minus, args.object, args.rps,
                                 diameter_mm=args.diameter_mm, releases=args.releases,
                                 seed=args.seed, tilt=args.tilt)
    except ValueError as exc:  # the message names the parameter; give it the flag's name
        msg = str(exc)
        for name in ("c_plus", "c_minus", "diameter_mm", "rps", "releases", "tilt", "object"):
            msg = msg.replace(name, "--" + name.replace("_", "-"))
        parser.error(msg)
    except (RuntimeError, OSError, KeyError) as exc:
        # a release the integrator could not finish, or a damaged calibration file: not the
        # user's flags, but still a message and status 2, not a traceback
        parser.exit(2, f"{parser.prog}: error: {type(exc).__name__}: {exc}\n")
    if args.json:
        print(json.dumps(pred.as_json()))
        return 0
    print(f"{'rps':>7}  {'mean [s]':>9}  {'s.d. [s]':>9}  {'mean, 95 % [s]':>16}")
    for f, m, s, (lo, hi) in zip(pred.rps, pred.mean_s, pred.std_s, pred.mean_s_95):
        print(f"{f:7.3f}  {m:9.2f}  {s:9.2f}  {f'{lo:.2f}-{hi:.2f}':>16}")
    print(f"({args.releases} releases per speed; tilt {pred.model['tilt']:.4g} rad; "
          f"t_max {pred.model['t_max']:g} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
