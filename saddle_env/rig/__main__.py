"""``python -m saddle_env.rig``: an exported policy, or a constant voltage, on a simulated rig
in real time, with the deadline summary at the end (the loop a real rig runs; see
docs/how-to/rig.md)."""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

from .clock import MonotonicClock, VirtualClock
from .loop import DEFAULT_LOST_AFTER, run
from .observe import constant_voltage
from .simulated import DEFAULT_LEVEL, SimulatedRig


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m saddle_env.rig``."""
    p = argparse.ArgumentParser(
        prog="python -m saddle_env.rig",
        description="Run a controller on a simulated rig (a level's physics in wall-clock "
                    "time, its camera's latency and its motor's lag) with the real-time loop "
                    "of saddle_env.rig: one track file per release of the ball, the period "
                    "timings and a summary of the deadlines missed, in --log-dir.")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--policy", metavar="DIR",
                      help="an exported policy folder (saddle-export); its level must drive the "
                           "motor by a voltage")
    what.add_argument("--voltage", type=float, metavar="V",
                      help="a constant voltage [V] instead of a policy")
    p.add_argument("--level", default=None,
                   help=f"the level to simulate (default: the policy's, or {DEFAULT_LEVEL})")
    p.add_argument("--seconds", type=float, default=10.0,
                   help="how long to run, in seconds of the loop's clock (default 10)")
    p.add_argument("--releases", type=int, default=None,
                   help="stop after this many releases of the ball (default: until --seconds)")
    p.add_argument("--frame-rate", type=float, default=200.0,
                   help="the simulated camera's frames per second (default 200)")
    p.add_argument("--seed", type=int, default=0, help="seeds the releases (default 0)")
    p.add_argument("--lost-after", type=float, default=DEFAULT_LOST_AFTER,
                   help="seconds of frames without the ball that end a release (default "
                        f"{DEFAULT_LOST_AFTER})")
    p.add_argument("--log-dir", default=None,
                   help="folder for the tracks, periods.tsv and summary.json (default: none "
                        "written)")
    p.add_argument("--virtual", action="store_true",
                   help="run on a virtual clock (as fast as the computer goes, no deadlines "
                        "at risk): for checking a controller, not its timing")
    return p


def _fmt(stats: dict[str, Any]) -> str:
    return ", ".join(f"{k} {v:.3f}" if v is not None else f"{k} -" for k, v in stats.items())


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    args = build_parser().parse_args(argv)
    if args.voltage is not None and not math.isfinite(args.voltage):
        raise SystemExit(f"--voltage must be a finite number of volts, got {args.voltage}")
    controller: Any
    level = args.level
    env_kwargs: dict[str, Any] = {}
    if args.policy is not None:
        from ..deploy import Controller

        controller = Controller.from_dir(args.policy)
        if level is None:
            level, env_kwargs = controller.spec.env_id, dict(controller.spec.env_kwargs)
    clock = VirtualClock() if args.virtual else MonotonicClock()
    try:
        rig = SimulatedRig(level or DEFAULT_LEVEL, frame_rate=args.frame_rate, seed=args.seed,
                           clock=clock, **env_kwargs)
    except ValueError as exc:
        raise SystemExit(f"python -m saddle_env.rig: {exc}") from None
    if args.voltage is not None:
        try:
            controller = constant_voltage(rig.config, args.voltage)
        except ValueError as exc:
            rig.close()
            raise SystemExit(f"--voltage: {exc}") from None
    print(f"{rig.config.obs_delay * 1e3:g} ms camera latency, {rig.frame_rate:g} frames/s, "
          f"period {rig.config.control_period * 1e3:g} ms; running {args.seconds:g} s"
          f"{' (virtual clock)' if args.virtual else ''}", flush=True)
    try:
        with rig:
            summary = run(rig, controller, args.seconds, releases=args.releases,
                          log_dir=args.log_dir, lost_after=args.lost_after,
                          progress=lambda line: print(line, flush=True))
    except KeyboardInterrupt:
        print("stopped; what ran is written" + (f" to {args.log_dir}" if args.log_dir else ""))
        return 130
    n = summary["periods"]
    print(f"{n} periods, {summary['misses']} deadlines missed "
          f"({summary['skipped_periods']} periods skipped); {len(summary['releases'])} "
          f"releases, kept {sum(r['seconds'] for r in summary['releases']):.2f} s")
    print(f"compute [ms]: {_fmt(summary['compute_ms'])}")
    print(f"lateness [ms]: {_fmt(summary['lateness_ms'])}")
    print(f"frame age [ms]: {_fmt(summary['frame_age_ms'])}")
    if args.log_dir:
        print(f"logs in {args.log_dir} (tracks: release_*.csv; saddle-fit reads them)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
