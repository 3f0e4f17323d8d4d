"""Time-varying Ω: the rotating-frame model against an independent laboratory-frame one.

`reference_lab_frame` derives the motion in the inertial frame (a Lagrangian for the
slipping ball, Newton–Euler with the rolling constraint for the rolling ball), with no
centrifugal, Coriolis or Euler force anywhere; agreement at tight tolerance under a speed
ramp and ripple is what shows the rotating-frame Euler terms are right.
"""

import math

import numpy as np
import pytest
from helpers import assert_matches_lab_frame
from reference_lab_frame import simulate_lab_frame

from saddle_env import OmegaProfile, Scene, initial_state, simulate

PROFILE = OmegaProfile(18.0, 3.0, 2.5, 7.0, 0.4)  # ramp + ripple: Ω̇ up to 20 rad/s²


@pytest.mark.parametrize("contact, R, b, spin", [("rolling", 0.025, 0.21, 3.0),
                                                 ("rolling", 0.02, 0.159, 0.0),
                                                 ("slipping", 0.03, 0.12, 0.0),
                                                 ("point", 0.0, 0.2, 0.0)])
def test_rotating_frame_matches_lab_frame_under_changing_speed(contact, R, b, spin):
    sc = Scene(contact=contact, R=R if R > 0 else 0.02, b=b)
    # the mass point's trap is weak: a smaller start keeps its orbit bounded
    q0, v0 = ((0.004, -0.002), (0.01, 0.005)) if R > 0 else ((0.002, 0.001), (0.0, 0.0))
    s0 = initial_state(sc, *q0, *v0, spin_normal=spin)
    tr = simulate(sc, s0, 3.0, omega=PROFILE, dt_out=0.05, rtol=1e-13, events=())
    ref = simulate_lab_frame(contact, sc.a, sc.b, sc.radius, sc.alpha, sc.g, PROFILE,
                             PROFILE.rate_at, q0, v0, tr.t, spin_normal=spin,
                             rtol=1e-12, atol=1e-14)
    assert_matches_lab_frame(tr, ref, sc.rolling)
    assert np.allclose(tr.theta, ref["theta"], rtol=0, atol=1e-9)
    # the run really is driven: Ω changes by several rad/s and the ball moves
    assert np.ptp(PROFILE(tr.t)) > 5 and np.ptp(tr.x) > 1e-3


def test_euler_term_matters():
    # Dropping Ω̇ would be caught: the same run with the ripple removed from the rate only
    # (a model without the Euler force) drifts far beyond the tolerance above.
    sc = Scene(contact="slipping", R=0.03)
    q0, v0 = (0.004, -0.002), (0.01, 0.005)
    tr = simulate(sc, initial_state(sc, *q0, *v0), 2.0, omega=PROFILE, dt_out=0.05, rtol=1e-13,
                  events=())
    wrong = simulate_lab_frame("slipping", sc.a, sc.b, sc.R, sc.alpha, sc.g, PROFILE,
                               lambda t: 0.0 * t, q0, v0, tr.t, rtol=1e-12, atol=1e-14)
    right = simulate_lab_frame("slipping", sc.a, sc.b, sc.R, sc.alpha, sc.g, PROFILE,
                               PROFILE.rate_at, q0, v0, tr.t, rtol=1e-12, atol=1e-14)
    assert np.max(np.abs(tr.x - right["x"])) < 1e-9
    assert np.max(np.abs(right["x"] - wrong["x"])) > 1e-5


@pytest.mark.parametrize("contact", ["rolling", "slipping"])
def test_detach_time_against_the_independent_model(contact):
    # Event time located by the simulator; the lab-frame model's normal force at that time
    # must vanish (to the slope of N times 1e-9 s).
    sc = Scene(contact=contact, R=0.033)
    s0 = initial_state(sc, 0.005, 0.005)
    omega = OmegaProfile(26.0, 4.0)
    ev = simulate(sc, s0, 2.0, omega=omega).event
    assert ev is not None and ev.kind == "detach"
    h = 1e-6
    ts = np.array([0.0, ev.t - h, ev.t, ev.t + h])
    ref = simulate_lab_frame(contact, sc.a, sc.b, sc.R, sc.alpha, sc.g, omega, omega.rate_at,
                             (0.005, 0.005), (0.0, 0.0), ts, rtol=1e-13, atol=1e-15)
    n_before, n_at, n_after = ref["N_over_mg"][1:]
    slope = abs(n_after - n_before) / (2 * h)
    assert n_before > 0 > n_after
    assert abs(n_at) <= slope * 1e-9 + 1e-12, (n_at, slope)
    assert math.isfinite(slope) and slope > 0
