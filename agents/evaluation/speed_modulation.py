"""What a policy does to the saddle's speed, episode by episode: its mean, spread and range,
the time spent below the rigid ball's threshold, the frequency it is swung at, and how much
of it follows the saddle's angle (a component at twice the angle, the saddle's own
symmetry), with how far the ball stays from the centre::

    python -m agents.evaluation.speed_modulation --policy agents/models/ppo_realsaddle.zip --episodes 4

The episodes are the level's test episodes from ``--seed`` (2,000,000 by default), run as
``saddle-eval`` runs them. The saddle's angle is the integral of its speed from the
episode's start: the angle's unknown start shifts the fitted phase, never the share of the
speed's variance the fit explains. Writes ``DIR/speed_modulation.json`` and prints a table.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..cli_args import resolve_env
from ..seeds import TEST_SEED

_FIELDS = ("omega_mean", "omega_std", "omega_p5", "omega_p95", "below_threshold",
           "peak_hz", "turning_hz", "twice_angle_amplitude", "twice_angle_r2",
           "twice_angle_phase_halves", "r_mean_mm", "r_p95_mm", "time_s")


def modulation(omega: np.ndarray, r: np.ndarray, dt: float, threshold: float) -> dict[str, Any]:
    """The statistics of one episode's speed trace ``omega`` [rad/s] and distance trace ``r``
    [m] sampled every ``dt`` [s] (NaN after the episode's end), ``threshold`` the rigid
    ball's critical speed [rad/s]."""
    live = np.isfinite(omega) & np.isfinite(r)
    w, rr = omega[live], r[live]
    if len(w) < 8:
        raise ValueError(f"an episode of {len(w)} samples is too short to analyse (at least 8)")
    angle = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * dt)])
    swing = w - w.mean()
    power = np.abs(np.fft.rfft(swing)) ** 2
    freqs = np.fft.rfftfreq(len(w), dt)
    basis = np.column_stack([np.ones_like(w), np.cos(2 * angle), np.sin(2 * angle)])
    coef, *_ = np.linalg.lstsq(basis, w, rcond=None)
    residual = w - basis @ coef
    half = len(w) // 2
    phases = [float(np.angle(np.sum(swing[s] * np.exp(-2j * angle[s]))))
              for s in (slice(0, half), slice(half, None))]
    return {"omega_mean": float(w.mean()), "omega_std": float(w.std()),
            "omega_p5": float(np.percentile(w, 5)), "omega_p95": float(np.percentile(w, 95)),
            "below_threshold": float(np.mean(w < threshold)),
            "peak_hz": float(freqs[1:][np.argmax(power[1:])]),
            "turning_hz": float(w.mean() / (2 * np.pi)),
            "twice_angle_amplitude": float(np.hypot(coef[1], coef[2])),
            "twice_angle_r2": float(1.0 - residual.var() / w.var()) if w.var() > 0 else 0.0,
            "twice_angle_phase_halves": phases,
            "r_mean_mm": float(1000 * rr.mean()), "r_p95_mm": float(1000 * np.percentile(rr, 95)),
            "time_s": float(dt * (len(w) - 1))}


def analyse(env_id: str, policy_spec: str, episodes: int, seed: int) -> list[dict[str, Any]]:
    """`modulation` of each of ``episodes`` test episodes of ``policy_spec`` on ``env_id``."""
    from ..control.controllers import critical_speed
    from ..control.rollout import policy_actor, run_episodes
    from .policies import load_policy

    level, config = resolve_env(env_id)
    steps = level.max_episode_steps
    policy = load_policy(policy_spec, config, max_episode_steps=steps)
    act, row_independent = policy_actor(policy)
    res = run_episodes(config, act, seed + np.arange(episodes), max_episode_steps=steps,
                       row_independent=row_independent, record=episodes)
    threshold = critical_speed(config)
    return [{"seed": seed + i, **modulation(res["trace_omega"][i], res["trace_r"][i],
                                            config.control_period, threshold)}
            for i in range(episodes)]


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m agents.evaluation.speed_modulation``."""
    p = argparse.ArgumentParser(prog="python -m agents.evaluation.speed_modulation",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--env", default="SaddleTrap-RealSaddle-v0", metavar="ID",
                   help="task level (default SaddleTrap-RealSaddle-v0)")
    p.add_argument("--policy", required=True, metavar="NAME_OR_PATH",
                   help="a baseline's name or a model file (as saddle-eval's --policy)")
    p.add_argument("--episodes", type=int, default=4, help="test episodes (default 4)")
    p.add_argument("--seed", type=int, default=TEST_SEED,
                   help=f"the first episode's seed (default {TEST_SEED:,}: the test set)")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="folder for speed_modulation.json (default: print only)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Analyse, print the table, write the file; exit 2 with a named message on bad input."""
    args = build_parser().parse_args(argv)
    if not 1 <= args.episodes <= 1000:
        print(f"--episodes must be in [1, 1000], got {args.episodes}", file=sys.stderr)
        return 2
    try:
        rows = analyse(args.env, args.policy, args.episodes, args.seed)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print("| seed | " + " | ".join(_FIELDS) + " |")
    print("|---" * (len(_FIELDS) + 1) + "|")
    for row in rows:
        cells = [", ".join(f"{v:.2f}" for v in row[k]) if isinstance(row[k], list)
                 else f"{row[k]:.2f}" for k in _FIELDS]
        print(f"| {row['seed']} | " + " | ".join(cells) + " |")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "speed_modulation.json").write_text(json.dumps(
            {"env_id": args.env, "policy": args.policy, "episodes": rows}, indent=1))
        print(f"wrote {out / 'speed_modulation.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
