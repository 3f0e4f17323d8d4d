"""``saddle-fit`` (also ``python -m saddle_env.calibrate``): fit the model's unknowns to measured
tracks and write the environment's options, the intervals and a plot (docs/how-to/calibrate.md).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

from ..envs.levels import LEVEL_IDS, get_level
from ..jobs.files import write_text_atomically
from ..jobs.signals import sigterm_interrupts
from .fit import FitResult, FitWarning, fit_tracks
from .model import PARAMETERS
from .tracks import TrackError, read_tracks

DEFAULT_LEVEL = "SaddleTrap-Lab-v0"


class _Parser(argparse.ArgumentParser):
    """Errors as one line and a hint, not the whole usage block."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n(see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``saddle-fit``."""
    ap = _Parser(
        prog="saddle-fit",
        description="Fit the simulator's unknowns (air drag, rolling resistance, friction, the "
                    "camera's latency, the motor, the axis offset) to tracked orbits of the "
                    "ball, by least squares with multiple shooting. Writes env_options.json "
                    "(options for gym.make, train.py --env-kwargs, saddle-eval --env-kwargs), "
                    "results.json (each value with its 95 % interval, residuals per track) "
                    "and orbits.png.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("tracks", nargs="+", metavar="TRACK",
                    help="track CSV files or run folders (every *.csv inside); the format is "
                         "docs/reference/tracks.md")
    ap.add_argument("--fit", required=True, metavar="NAMES",
                    help=f"comma-separated parameters to fit, from {', '.join(PARAMETERS)}; "
                         f"each track's start angle is fitted too when it has no theta column")
    ap.add_argument("--level", default=DEFAULT_LEVEL, metavar="ID",
                    help="the level whose options are the scene's known parameters and the "
                         "fitted ones' starting values")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="options over the level's (the rig's known values: a, R, contact, "
                         "voltage_max, ...), VALUE read as JSON where it parses")
    ap.add_argument("--drive", choices=("auto", "omega", "voltage"), default="auto",
                    help="the saddle's motion from the tachometer (omega) or through the motor "
                         "from the voltage; auto: omega when every track has it and no motor "
                         "parameter is fitted")
    ap.add_argument("--segment", type=float, default=0.15, metavar="S",
                    help="length of the shooting segments [s], 0.02-2")
    ap.add_argument("--position-noise", type=float, default=None, metavar="M",
                    help="the camera's noise [m] weighing the frames against the tachometer "
                         "(default: the level's position_noise, else 1 mm)")
    ap.add_argument("--omega-noise", type=float, default=None, metavar="RAD_S",
                    help="the tachometer's noise [rad/s] (default: the level's omega_noise, "
                         "else 0.2)")
    ap.add_argument("--max-iterations", type=int, default=50, metavar="N",
                    help="Jacobian evaluations at most, 1-1000")
    ap.add_argument("--out", default="fit", metavar="DIR",
                    help="folder for env_options.json, results.json and orbits.png")
    ap.add_argument("--no-plot", action="store_true", help="skip orbits.png")
    ap.add_argument("--quiet", action="store_true", help="no progress lines")
    return ap


def parse_set(items: Sequence[str]) -> dict[str, Any]:
    """``KEY=VALUE`` items; VALUE as JSON (numbers, null, lists) where it parses, else text."""
    out: dict[str, Any] = {}
    for item in items:
        key, eq, text = item.partition("=")
        if not eq or not key.strip():
            raise ValueError(f"--set items must look like KEY=VALUE, got {item!r}")
        try:
            value = json.loads(text)
        except ValueError:
            value = text
        if isinstance(value, list):
            value = tuple(value)
        out[key.strip()] = value
    return out


def _json_value(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return "inf" if v > 0 else ("-inf" if v < 0 else "nan")
    if isinstance(v, tuple):
        return list(v)
    return v


def write_outputs(result: FitResult, out: Path, level: str, command: str,
                  plot: bool = True) -> list[Path]:
    """env_options.json, results.json (and orbits.png): written whole or not at all."""
    out.mkdir(parents=True, exist_ok=True)
    options = {k: _json_value(v) for k, v in result.env_options.items()}
    written = [write_text_atomically(out / "env_options.json",
                                     json.dumps(options, indent=2) + "\n")]
    doc = {"level": level, "command": command, **result.as_dict()}
    written.append(write_text_atomically(out / "results.json",
                                         json.dumps(doc, indent=2, default=_json_value) + "\n"))
    if plot:
        from .plot import plot_fit
        written.append(plot_fit(result, out / "orbits.png", title=f"saddle-fit on {level}"))
    return written


def report(result: FitResult) -> str:
    """The table printed at the end."""
    lines = [f"{'parameter':<20} {'value':>12} {'95 % interval':>28}  unit"]
    for e in result.estimates.values():
        iv = f"[{e.low:.5g}, {e.high:.5g}]" if e.identifiable else "unidentifiable"
        lines.append(f"{e.name:<20} {e.value:>12.6g} {iv:>28}  {e.unit}")
    lines.append("")
    lines.append(f"{'track':<40} {'frames':>7} {'rms [mm]':>9}")
    for t in result.tracks:
        lines.append(f"{Path(t['source']).name:<40} {t['frames']:>7} {t['rms_m'] * 1e3:>9.3f}")
    noise = result.noise
    lines.append(f"noise from the residuals: camera {noise.get('position_m', math.nan) * 1e3:.3g} "
                 f"mm, tachometer {noise.get('omega_rad_s', math.nan):.3g} rad/s")
    lines.append(f"status: {result.status}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    say = (lambda _: None) if args.quiet else (lambda s: print(s, flush=True))
    try:
        level = get_level(args.level)
    except ValueError:
        parser.error(f"--level: unknown level {args.level!r}; the levels are {list(LEVEL_IDS)}")
    try:
        config = level.config(**parse_set(args.set))
    except (ValueError, TypeError) as exc:
        parser.error(f"--set: {exc}")
    try:
        tracks = read_tracks(args.tracks)
    except TrackError as exc:
        parser.error(str(exc))
    names = [n for n in args.fit.split(",") if n.strip()]

    try:
        # SIGTERM as Ctrl-C: the fit keeps its last values; a stop lost on the way is raised
        # again at the next iteration's line
        with sigterm_interrupts() as term, warnings.catch_warnings():
            warnings.simplefilter("ignore", FitWarning)   # printed by the fit itself

            def progress(line: str) -> None:
                term.raise_if_lost()
                say(line)

            result = fit_tracks(tracks, config, names, drive=args.drive, segment=args.segment,
                                position_noise=args.position_noise,
                                omega_noise=args.omega_noise,
                                max_iterations=args.max_iterations, progress=progress)
    except ValueError as exc:
        parser.error(str(exc))
    except KeyboardInterrupt:
        print("saddle-fit: interrupted before the first evaluation; nothing written",
              file=sys.stderr)
        return 130
    try:
        level.config(**result.env_options)   # what gym.make will be given
    except (ValueError, TypeError) as exc:
        print(f"saddle-fit: warning: the fitted options do not make a valid {args.level} "
              f"configuration ({exc}); results.json has the values", file=sys.stderr)
    command = "saddle-fit " + " ".join(sys.argv[1:] if argv is None else argv)
    written = write_outputs(result, Path(args.out), args.level, command, plot=not args.no_plot)
    print(report(result))
    if args.quiet:
        for w in result.warnings:
            print(f"warning: {w}")
    print("wrote " + ", ".join(str(p) for p in written))
    return 0 if result.status != "interrupted" else 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
