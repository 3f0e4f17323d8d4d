"""Physics invariants of the exact model."""

import numpy as np
import pytest

from saddle_env import OmegaProfile, Scene, initial_state, simulate


@pytest.mark.parametrize("contact, start", [("rolling", "rotating-rest"),
                                            ("slipping", "rotating-rest"),
                                            ("point", "lab-rest")])
def test_jacobi_integral_conserved_over_100s(contact, start):
    sc = Scene(contact=contact)
    s0 = initial_state(sc, 0.003, 0.002, start=start, omega=20.0)
    tr = simulate(sc, s0, 100.0, omega=20.0, dt_out=0.01, rtol=1e-12)
    assert tr.event is None
    h = tr.h
    scale = abs(h[0]) if sc.radius > 0 else sc.g * sc.a
    drift = np.max(np.abs(h - h[0])) / scale
    assert drift <= 1e-10, drift
    # the orbit really moves (a conserved quantity of a ball at rest proves nothing)
    assert np.ptp(tr.x) > 1e-3


def test_jacobi_integral_conserved_with_spin_and_asymmetry():
    sc = Scene(b=0.12, R=0.025, alpha=2 / 3)
    s0 = initial_state(sc, 0.002, -0.003, 0.01, 0.0, spin_normal=4.0)
    tr = simulate(sc, s0, 30.0, omega=19.0, dt_out=0.01, rtol=1e-12)
    assert tr.event is None
    assert np.max(np.abs(tr.h - tr.h[0])) / abs(tr.h[0]) <= 1e-10


def test_jacobi_integral_changes_when_omega_does():
    # The Jacobi integral is not conserved under a speed ramp: a test that it is checked
    # for constant Ω only (otherwise the conservation test could pass vacuously).
    sc = Scene()
    s0 = initial_state(sc, 0.003, 0.002)
    tr = simulate(sc, s0, 2.0, omega=OmegaProfile(20.0, 3.0), rtol=1e-12)
    assert np.max(np.abs(tr.h - tr.h[0])) / abs(tr.h[0]) > 1e-4


@pytest.mark.parametrize("contact", ["rolling", "slipping", "point"])
def test_rest_at_saddle_point_is_an_equilibrium(contact):
    sc = Scene(contact=contact)
    prof = OmegaProfile(20, 1, 2, 3)
    tr = simulate(sc, initial_state(sc, 0.0, 0.0), 5.0, omega=prof)
    assert np.all(tr.state[:, :4] == 0.0)
    assert np.allclose(tr.N_over_mg, 1.0, rtol=0, atol=1e-15)
    if sc.rolling:
        # Nothing torques the ball about the vertical: its absolute spin stays 0, so its
        # spin relative to an accelerating saddle is Ω(0) - Ω(t) (the Ω̇ k term of Euler's law).
        assert np.allclose(tr.state[:, 4], prof(0.0) - prof(tr.t), rtol=0, atol=1e-9)


def test_drilling_friction_relaxes_the_normal_spin():
    sc = Scene(drilling_friction=2.0)
    s0 = initial_state(sc, 0.0, 0.0, spin_normal=5.0)
    tr = simulate(sc, s0, 2.0, omega=20.0, rtol=1e-12)
    # at the saddle point the normal is vertical, so w_z decays as exp(-2 t)
    assert np.allclose(tr.state[:, 4], 5.0 * np.exp(-2.0 * tr.t), rtol=1e-9)
    assert np.allclose(tr.state[:, :4], 0.0)


def test_slipping_ball_becomes_a_mass_point_as_R_vanishes():
    sp = Scene(contact="point")
    s0 = initial_state(sp, 0.002, 0.001, start="lab-rest", omega=25.0)
    ref = simulate(sp, s0, 1.0, omega=25.0, rtol=1e-12)
    gaps = []
    for R in (1e-3, 1e-4, 1e-5):
        sc = Scene(contact="slipping", R=R)
        tr = simulate(sc, initial_state(sc, 0.002, 0.001, start="lab-rest", omega=25.0), 1.0,
                      omega=25.0, rtol=1e-12)
        gaps.append(np.max(np.abs(tr.state[:, :2] - ref.state[:, :2])))
    # converges linearly in R
    assert gaps[1] == pytest.approx(gaps[0] / 10, rel=0.02)
    assert gaps[2] == pytest.approx(gaps[1] / 10, rel=0.02)


@pytest.mark.parametrize("contact", ["rolling", "slipping", "point"])
@pytest.mark.parametrize("theta0, sign", [(0.0, 1.0), (np.pi, -1.0)])
def test_lab_force_balances_gravity_on_a_still_saddle(contact, theta0, sign):
    # The surface slope 2x/a equals f/g at the equilibrium, for any ball radius (the offset
    # surface has the same slope): x = f a / (2 g). The force is fixed in the lab, so a
    # saddle turned by θ0 = π sees it along -x.
    from helpers import rhs
    sc = Scene(contact=contact)
    f = 0.4
    x_eq = sign * f * sc.a / (2 * sc.g)
    state = initial_state(sc, x_eq, 0.0)
    drive = [0.0, 0.0, 0.0, 0.0, 0.0, theta0, f, 0.0]
    assert np.allclose(rhs(sc, state, drive), 0.0, atol=1e-13)  # terms are O(g/R · slope) ~ 20
    off = initial_state(sc, 1.1 * x_eq, 0.0)
    assert np.sign(rhs(sc, off, drive)[2 if not sc.rolling else 3]) != 0


def test_simulate_applies_the_lab_force():
    sc = Scene(contact="point")
    x_eq = 0.3 * sc.a / (2 * sc.g)
    still = simulate(sc, initial_state(sc, x_eq, 0.0), 1.0, omega=0.0, force=(0.3, 0.0),
                     rtol=1e-12)
    assert np.allclose(still.x, x_eq, atol=1e-12) and np.allclose(still.y, 0.0, atol=1e-12)
    pushed = simulate(sc, initial_state(sc, 0.0, 0.0), 1.0, omega=0.0, force=(0.3, 0.0))
    assert pushed.x.max() > 1.5 * x_eq  # released from the centre it overshoots
    with pytest.raises(ValueError, match="force fx must be finite"):
        simulate(sc, initial_state(sc, 0.0, 0.0), 1.0, force=(np.nan, 0.0))
