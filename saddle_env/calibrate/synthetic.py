"""Synthetic tracks: what a camera, a tachometer and an encoder would record of the simulated
rig, made by the environment itself (its exact camera latency, its motor), for checking a fit
on a scene whose parameters are known.

    >>> from saddle_env.calibrate.synthetic import synthetic_tracks
    >>> tracks, config = synthetic_tracks("SaddleTrap-Lab-v0", n_tracks=2, seconds=1.0,
    ...                                   drag_quadratic=0.3, obs_delay=0.03)

Each track is one episode of the level (its ball released as the level releases it), driven
by random commands held for ``hold`` seconds, observed in the laboratory frame at ``fps``
with the latency ``obs_delay``: the row stamped t holds the ball's centre at t − obs_delay
plus Gaussian camera noise, the voltage written at t (held to the next row) and the speed
and angle at t. Frames before t = obs_delay (which would show the ball before its release)
are left out.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..envs import control_step as S
from ..envs.config import EnvConfig
from ..envs.levels import get_level
from ..envs.saddle_trap import SaddleTrapEnv
from ..jobs.files import write_text_atomically
from .tracks import COLUMNS, Track, write_track

MAX_TRACKS = 1000


def synthetic_tracks(env_id: str = "SaddleTrap-Lab-v0", n_tracks: int = 3,
                     seconds: float = 2.0, fps: float = 120.0, *, seed: int = 0,
                     position_noise: float = 5e-4, omega_noise: float = 0.2,
                     theta_noise: float = 0.0, columns: Sequence[str] = ("omega", "voltage"),
                     hold: float = 0.25, action_range: tuple[float, float] = (-0.5, 0.2),
                     **options: Any) -> tuple[list[Track], EnvConfig]:
    """Tracks of ``n_tracks`` episodes of level ``env_id`` with ``options`` over its own, and
    the configuration that made them (the truth a fit should recover).

    Parameters
    ----------
    env_id
        A registered level; its ball, motor and latency unless ``options`` change them.
        The air draught and motor ripple are off unless given (a fit's model has neither), the
        ball's size is the fixed ``R`` (not drawn from ``ball_radii``).
    seconds, fps
        Each track's length [s] and frame rate [1/s] (1-10,000).
    position_noise, omega_noise, theta_noise
        The camera's [m] (Gaussian, per coordinate), the tachometer's [rad/s] and the
        encoder's [rad] noise.
    columns
        The optional columns to write, from ("omega", "voltage", "theta").
    hold, action_range
        The commands: uniform in ``action_range`` (the action, -1 to 1) held ``hold`` s each.

    Returns
    -------
    tracks : list of Track
        The tracks (``Track.source`` names the episode).
    config : EnvConfig
        The level's options that made them."""
    level = get_level(env_id)
    if not (isinstance(n_tracks, int) and 1 <= n_tracks <= MAX_TRACKS):
        raise ValueError(f"n_tracks must be an integer in [1, {MAX_TRACKS}], got {n_tracks!r}")
    if not (isinstance(fps, (int, float)) and 1.0 <= fps <= 10_000.0):
        raise ValueError(f"fps must be in [1, 10000] frames per second, got {fps!r}")
    if not (isinstance(seconds, (int, float)) and 3.0 / fps <= seconds <= 3600.0):
        raise ValueError(f"seconds must be in [3 / fps, 3600], got {seconds!r}")
    unknown = sorted(set(columns) - set(COLUMNS[3:]))
    if unknown:
        raise ValueError(f"columns must be drawn from {list(COLUMNS[3:])}, got {unknown}")
    for name, v in (("position_noise", position_noise), ("omega_noise", omega_noise),
                    ("theta_noise", theta_noise)):
        if not (isinstance(v, (int, float)) and 0.0 <= v < 1.0):
            raise ValueError(f"{name} must be in [0, 1), got {v!r}")
    lo, hi = action_range
    if not -1.0 <= lo <= hi <= 1.0:
        raise ValueError(f"action_range must satisfy -1 <= low <= high <= 1, got {action_range}")
    base = dict(level.options)
    kw: dict[str, Any] = {**base, "air_force": 0.0, "ripple_amp": 0.0, "ball_radii": None}
    kw.update(options)
    kw.update(control_period=1.0 / fps, obs_frame="lab", observe_velocity=False, obs_history=1,
              observe_angle=False, observe_command=False, position_noise=0.0,
              omega_noise=0.0, action_delay=0.0)
    config = EnvConfig.from_kwargs(**kw)
    if "voltage" in columns and config.action_mode != "voltage":
        raise ValueError(f"columns has 'voltage' but action_mode is {config.action_mode!r}: "
                         f"only a voltage-driven motor has a voltage to record")
    env = SaddleTrapEnv(**config.as_dict())
    rng = np.random.default_rng(seed)
    steps = int(round(seconds * fps))
    per_hold = max(1, int(round(hold * fps)))
    tracks = []
    for ep in range(n_tracks):
        obs, _ = env.reset(seed=int(rng.integers(2**31)))
        acts = np.repeat(rng.uniform(lo, hi, steps // per_hold + 2), per_hold)
        rows = []
        for i in range(steps + 1):
            b = env.engine.balls[0]
            volts = 0.5 * (float(np.float32(acts[i])) + 1.0) * config.voltage_max
            rows.append((b[S.B_TIME], obs[0] * config.rim_radius, obs[1] * config.rim_radius,
                         b[S.B_OMEGA], volts, b[S.B_THETA]))
            if i == steps:
                break
            obs, _, terminated, _, _ = env.step(np.array([acts[i]], np.float32))
            if terminated:   # the ball left: the track ends at its last frame on the saddle
                break
        data = np.array(rows)
        data = data[data[:, 0] >= config.obs_delay + 0.5 / fps]
        n = len(data)
        if n < 3:
            raise ValueError(f"episode {ep} lost its ball within {config.obs_delay:g} s: no "
                             f"track; choose action_range or omega0_range that keep it")
        x = data[:, 1] + rng.normal(0.0, position_noise, n) if position_noise else data[:, 1]
        y = data[:, 2] + rng.normal(0.0, position_noise, n) if position_noise else data[:, 2]
        extra = {}
        if "omega" in columns:
            extra["omega"] = data[:, 3] + rng.normal(0.0, omega_noise, n) if omega_noise \
                else data[:, 3]
        if "voltage" in columns:
            extra["voltage"] = data[:, 4]
        if "theta" in columns:
            extra["theta"] = data[:, 5] + rng.normal(0.0, theta_noise, n) if theta_noise \
                else data[:, 5]
        tracks.append(Track(data[:, 0], x, y, source=f"<synthetic {env_id} episode {ep}>",
                            **extra))
    env.close()
    # the configuration that made them, with the camera's and the tachometer's noise the
    # tracks carry (added here rather than by the environment, whose noise is off above)
    return tracks, replace(config, position_noise=position_noise, omega_noise=omega_noise)


__all__ = ["synthetic_tracks"]


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m saddle_env.calibrate.synthetic``."""
    ap = argparse.ArgumentParser(
        prog="python -m saddle_env.calibrate.synthetic",
        description="Write synthetic track files (one CSV per release) made by a level's "
                    "simulated rig with known parameters, to check saddle-fit on a scene "
                    "before fitting the real one. The parameters used are written to "
                    "truth.json beside the tracks.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("out", metavar="DIR", help="folder for release_NNN.csv and truth.json")
    ap.add_argument("--level", default="SaddleTrap-Lab-v0", metavar="ID", help="the level")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="options over the level's (the truth: R, obs_delay, motor_tau, ...)")
    ap.add_argument("--tracks", type=int, default=3, help="releases of the ball, 1-1000")
    ap.add_argument("--seconds", type=float, default=2.0, help="length of each track [s]")
    ap.add_argument("--fps", type=float, default=120.0, help="frame rate [1/s], 1-10,000")
    ap.add_argument("--position-noise", type=float, default=5e-4, metavar="M",
                    help="the camera's noise [m]")
    ap.add_argument("--omega-noise", type=float, default=0.2, metavar="RAD_S",
                    help="the tachometer's noise [rad/s]")
    ap.add_argument("--columns", default="omega,voltage",
                    help="optional columns to write, from omega, voltage, theta")
    ap.add_argument("--seed", type=int, default=0, help="random seed")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    from .cli import parse_set
    parser = build_parser()
    args = parser.parse_args(argv)
    columns = tuple(c.strip() for c in args.columns.split(",") if c.strip())
    try:
        tracks, config = synthetic_tracks(
            args.level, args.tracks, args.seconds, args.fps, seed=args.seed,
            position_noise=args.position_noise, omega_noise=args.omega_noise,
            columns=columns, **parse_set(args.set))
    except (ValueError, TypeError) as exc:
        parser.error(str(exc))
    out = Path(args.out)
    for i, t in enumerate(tracks):
        write_track(out / f"release_{i:03d}.csv", t,
                    comments=[f"synthetic: {args.level}, seed {args.seed}, episode {i}"])
    truth = {k: (list(v) if isinstance(v, tuple) else v) for k, v in config.as_dict().items()}
    truth["drag_quadratic"] = config.scene().drag_quadratic   # ball_density's, if it is set
    write_text_atomically(out / "truth.json", json.dumps(truth, indent=2) + "\n")
    print(f"wrote {len(tracks)} tracks ({sum(len(t) for t in tracks)} frames) and truth.json "
          f"to {out}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
