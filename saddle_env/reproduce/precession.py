"""Measurements on simulated trajectories (precession of the secular orbit)."""

from __future__ import annotations

import math

import numpy as np

from ..linear import eigenfrequencies
from ..simulate import Trajectory


def linear_precession_rate(traj: Trajectory) -> float:
    """Precession rate [rad/s] of the secular orbit in the lab frame from linear theory:
    Ω − (ϖ₊ + ϖ₋)/2, whose leading term in g/(aΩ²) is the paper's g²/(2a²Ω³)."""
    pos = _positive_frequencies(traj)
    return traj.omega.w0 - 0.5 * (pos[0] + pos[1])


def _positive_frequencies(traj: Trajectory) -> np.ndarray:
    """The two positive eigen-frequencies ϖ₋ ≤ ϖ₊ (requires linear stability)."""
    w = eigenfrequencies(traj.scene, traj.omega.w0)
    if np.any(np.abs(w.imag) > 1e-9 * np.abs(w).max()):
        raise ValueError("the saddle speed is not linearly stable: no precessing orbit")
    return np.sort(w.real[w.real > 0])


def orientation_series(traj: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Orientation [rad] of the secular ellipse in the laboratory against time.

    At constant Ω the lab-frame motion is a slow (secular) ellipse plus a fast
    micro-motion at ~2Ω. The ellipse's orientation is the principal axis of the second
    moment of the lab-frame position over a sliding window one secular period long (which
    averages the micro-motion out), unwrapped modulo π. The secular period comes from linear
    theory: 2π / ((ϖ₊ − ϖ₋)/2). Returns (window-centre times, angles).
    """
    t = traj.t
    if not traj.omega.constant:
        raise ValueError("the orientation of the orbit needs a constant saddle speed")
    w = _positive_frequencies(traj)
    secular = 0.5 * (w[1] - w[0])
    if not secular > 0:
        raise ValueError("the linearised motion has no secular frequency at this speed")
    dt = t[1] - t[0]
    window = int(round(2 * math.pi / secular / dt))
    if len(t) < 3 * window:
        raise ValueError(f"the run must span at least three secular periods "
                         f"({3 * 2 * math.pi / secular:.3g} s); it spans {t[-1] - t[0]:.3g} s")
    xy = traj.lab_xy()
    hop = max(1, window // 8)
    centres, angles = [], []
    for i0 in range(0, len(t) - window, hop):
        seg = xy[i0:i0 + window]
        sxx, syy = np.mean(seg[:, 0] ** 2), np.mean(seg[:, 1] ** 2)
        sxy = np.mean(seg[:, 0] * seg[:, 1])
        angles.append(0.5 * math.atan2(2 * sxy, sxx - syy))
        centres.append(np.mean(t[i0:i0 + window]))
    # Orientation is defined modulo π: unwrap on the doubled angle.
    return np.asarray(centres), np.unwrap(2 * np.asarray(angles)) / 2


def precession_angle(traj: Trajectory, duration: float | None = None) -> float:
    """Measured precession of the orbit in the laboratory frame over ``duration`` [rad]:
    the slope of a straight-line fit of `orientation_series` against time, times
    ``duration`` (default: the run's length)."""
    centres, angles = orientation_series(traj)
    slope = np.polyfit(centres, angles, 1)[0]
    t = traj.t
    return float(slope * (t[-1] - t[0] if duration is None else duration))
