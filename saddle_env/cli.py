"""``saddle-sim``: simulate one ball from the command line (CSV or JSON on stdout or a file)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from typing import NoReturn

from .integrators import METHODS
from .omega import OmegaProfile
from .scene import CONTACT_MODELS, Scene
from .simulate import (
    DEFAULT_METHOD,
    DEFAULT_RTOL,
    SimulationError,
    Trajectory,
    initial_state,
    simulate,
)

COLUMNS = ("t", "x", "y", "vx", "vy", "N_over_mg", "h")


class _Formatter(argparse.ArgumentDefaultsHelpFormatter):
    """Appends "(default: X)" unless the help already says what the default is, or there is
    none to show (None means "chosen for you", which the help explains)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None or "default" in (action.help or ""):
            return action.help
        return super()._get_help_string(action)


class _Parser(argparse.ArgumentParser):
    """Errors as one line and a hint, not the whole usage block."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n(see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``saddle-sim``."""
    d = Scene()
    ap = _Parser(
        prog="saddle-sim",
        description="Simulate a rigid ball on a rotating saddle z = x²/a − y²/b. "
                    "Positions and velocities are the contact point's, in metres and m/s, "
                    "in the frame rotating with the saddle. Ω(t) = W0 + WDOT·t + AMP·sin(F·t).",
        formatter_class=_Formatter)
    ap.add_argument("--contact", choices=CONTACT_MODELS, default="rolling", help="contact model")
    ap.add_argument("--a", type=float, default=d.a, help="saddle length a [m]")
    ap.add_argument("--b", type=float, default=None, help="saddle length b [m] (default: = a)")
    ap.add_argument("--R", type=float, default=d.R, help="ball radius [m] (ignored by point)")
    ap.add_argument("--alpha", type=float, default=d.alpha, help="I = alpha m R^2")
    ap.add_argument("--g", type=float, default=d.g, help="gravity [m/s^2]")
    ap.add_argument("--drilling-friction", type=float, default=0.0,
                    help="rate [1/s] at which the spin about the normal relaxes (rolling)")
    ap.add_argument("--drag-linear", type=float, default=d.drag_linear, metavar="K1",
                    help="linear air drag [1/s]: force/mass = -K1 u, u the centre's velocity "
                         "relative to the lab's still air")
    ap.add_argument("--drag-quadratic", type=float, default=d.drag_quadratic, metavar="K2",
                    help="quadratic air drag [1/m]: force/mass = -K2 |u| u")
    ap.add_argument("--rolling-resistance", type=float, default=d.rolling_resistance,
                    metavar="C_RR", help="rolling-resistance coefficient (rolling, coulomb): a "
                    "torque C_RR·R·N against the rolling")
    ap.add_argument("--mu", type=float, default=None, metavar="MU",
                    help="coulomb: kinetic friction coefficient (needed with --contact coulomb)")
    ap.add_argument("--mu-static", type=float, default=None, metavar="MU_S",
                    help="coulomb: static friction coefficient (>= --mu; default: = --mu)")
    ap.add_argument("--omega", type=float, default=20.0, metavar="W0", help="Ω at t=0 [rad/s]")
    ap.add_argument("--omega-rate", type=float, default=0.0, metavar="WDOT", help="dΩ/dt [rad/s^2]")
    ap.add_argument("--omega-amp", type=float, default=0.0, metavar="AMP", help="ripple amplitude [rad/s]")
    ap.add_argument("--omega-freq", type=float, default=0.0, metavar="F", help="ripple frequency [rad/s]")
    ap.add_argument("--x0", type=float, default=0.01, metavar="X", help="initial contact x [m]")
    ap.add_argument("--y0", type=float, default=0.0, metavar="Y", help="initial contact y [m]")
    ap.add_argument("--vx0", type=float, default=0.0, metavar="VX", help="initial vx [m/s], rotating frame")
    ap.add_argument("--vy0", type=float, default=0.0, metavar="VY", help="initial vy [m/s], rotating frame")
    ap.add_argument("--start", choices=("rotating-rest", "lab-rest"), default=None,
                    help="start at rest on the saddle or placed at rest in the lab "
                         "(overrides --vx0/--vy0)")
    ap.add_argument("--spin-n", type=float, default=0.0, metavar="W",
                    help="rolling, coulomb: spin about the normal relative to the saddle [rad/s]")
    ap.add_argument("--spin", type=float, nargs=3, default=None, metavar=("WX", "WY", "WZ"),
                    help="coulomb: the ball's angular velocity relative to the saddle, in its "
                         "axes [rad/s] (default: rolling without slip)")
    ap.add_argument("--rim", type=float, default=d.rim_radius, metavar="RADIUS",
                    help="rim radius [m] (inf: no rim)")
    ap.add_argument("--t-end", type=float, default=2.0, metavar="T", help="duration [s]")
    ap.add_argument("--dt-out", type=float, default=0.01, metavar="DT", help="output spacing [s]")
    ap.add_argument("--method", choices=sorted(METHODS), default=None,
                    help=f"integrator (default: {DEFAULT_METHOD}, adaptive)")
    ap.add_argument("--rtol", type=float, default=None, metavar="TOL",
                    help=f"adaptive tolerance (default {DEFAULT_RTOL:g})")
    ap.add_argument("--dt", type=float, default=None, help="fixed step [s] (fixed-step integration)")
    ap.add_argument("--format", choices=("csv", "json"), default="csv", help="output format")
    ap.add_argument("--output", default=None, metavar="FILE", help="output file (default: stdout)")
    return ap


def run(args: argparse.Namespace) -> Trajectory:
    """The trajectory that the parsed command line ``args`` asks for."""
    scene = Scene(a=args.a, b=args.b, R=args.R, alpha=args.alpha, g=args.g,
                  contact=args.contact, rim_radius=args.rim,
                  drilling_friction=args.drilling_friction, drag_linear=args.drag_linear,
                  drag_quadratic=args.drag_quadratic, rolling_resistance=args.rolling_resistance,
                  mu=args.mu, mu_static=args.mu_static)
    profile = OmegaProfile(args.omega, args.omega_rate, args.omega_amp, args.omega_freq)
    state = initial_state(scene, args.x0, args.y0, args.vx0, args.vy0, start=args.start,
                          omega=profile, spin_normal=args.spin_n,
                          spin=None if args.spin is None else tuple(args.spin))
    return simulate(scene, state, args.t_end, omega=profile, dt_out=args.dt_out,
                    method=args.method, rtol=args.rtol, dt=args.dt)


def render(traj: Trajectory, fmt: str) -> str:
    """The trajectory as text in the format ``fmt`` (a table or JSON)."""
    if fmt == "json":
        return json.dumps(traj.as_dict()) + "\n"
    cols = [traj.t, traj.x, traj.y, traj.vx, traj.vy, traj.N_over_mg, traj.h]
    names: tuple[str, ...] = COLUMNS
    if traj.phase is not None:  # coulomb: the phase (0 stick, 1 slip) and the work
        assert traj.work is not None  # Trajectory.__post_init__ fills work
        cols += [traj.phase, traj.work]
        names += ("slipping", "work")
    lines = [f"# saddle-sim: {traj.scene}; integrator {traj.settings}"]
    for tr in traj.transitions:
        lines.append(f"# transition: {tr.phase} at t = {tr.t!r} s")
    if traj.event is not None:
        lines.append(f"# event: {traj.event.kind} at t = {traj.event.t!r} s")
    lines.append(",".join(names))
    lines += [",".join(repr(float(c[i])) for c in cols) for i in range(len(traj.t))]
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.rim is not None and math.isnan(args.rim):
        parser.error("--rim must be > 0 (or inf), got nan")
    try:
        traj = run(args)
    except ValueError as exc:
        parser.error(str(exc))  # exits with status 2
    except SimulationError as exc:
        print(f"saddle-sim: error: {exc}", file=sys.stderr)
        return 1
    text = render(traj, args.format)
    if args.output is None:
        sys.stdout.write(text)
    else:
        try:
            with open(args.output, "w", encoding="utf-8") as fh:
                fh.write(text)
        except OSError as exc:
            parser.error(f"--output: cannot write {args.output!r}: {exc.strerror}")
        ending = (f"{traj.event.kind} at t = {traj.event.t:.9f} s" if traj.event
                  else f"no event up to t = {args.t_end:g} s")
        low = f"; min N/mg = {traj.N_over_mg.min():.4f}" if len(traj.t) else ""
        print(f"saddle-sim: wrote {len(traj.t)} rows to {args.output}; {ending}{low}",
              file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
