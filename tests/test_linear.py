"""Linear theory (paper Table I) against the exact model."""

import math

import numpy as np
import pytest
from helpers import fd_linearisation

from saddle_env import Scene
from saddle_env.linear import (
    abcd,
    critical_omega,
    eigenfrequencies,
    is_stable,
    mass_point_band,
    stable_band,
)

SCENES = [dict(contact="rolling"), dict(contact="rolling", R=0.033, alpha=2 / 3),
          dict(contact="slipping", R=0.03), dict(contact="point"),
          dict(contact="rolling", b=0.1), dict(contact="rolling", a=0.12, b=0.3, R=0.03),
          dict(contact="slipping", b=0.25, R=0.01)]


@pytest.mark.parametrize("kw", SCENES)
@pytest.mark.parametrize("omega, spin_z", [(23.0, 0.0), (30.0, 7.0), (9.0, -40.0)])
def test_finite_difference_linearisation_equals_table_I(kw, omega, spin_z):
    sc = Scene(**kw)
    M = fd_linearisation(sc, omega, spin_z)
    c = abcd(sc, omega, spin_z)
    expected = c.matrix()
    scale = np.abs(expected).max()
    assert np.allclose(M, expected, rtol=0, atol=2e-7 * scale), (M, expected)


def test_table_I_symmetric_closed_forms():
    # Table I verbatim for the symmetric saddle (R = 2 cm, α = 2/5, ω_z = 3)
    a, R, al, W, wz, g = 0.159, 0.02, 0.4, 30.0, 3.0, 9.8
    c = abcd(Scene(a=a, R=R, alpha=al, g=g), W, wz)
    assert c.A == pytest.approx(((a - 2 * R) * W**2 + 2 * al * R * wz * W - 2 * g) / ((1 + al) * (a - 2 * R)))
    assert c.B == pytest.approx(((2 + al) * (a + 2 * R) * W - 2 * al * R * wz) / ((1 + al) * (a + 2 * R)))
    assert c.C == pytest.approx(((a + 2 * R) * W**2 - 2 * al * R * wz * W + 2 * g) / ((1 + al) * (a + 2 * R)))
    assert c.D == pytest.approx((-(2 + al) * (a - 2 * R) * W - 2 * al * R * wz) / ((1 + al) * (a - 2 * R)))


def test_paper_critical_speed_14_07():
    sc = Scene(R=0.03)
    assert critical_omega(sc) == pytest.approx(14.07, abs=0.005)
    assert critical_omega(sc.with_(contact="slipping")) == critical_omega(sc)
    assert critical_omega(Scene(contact="point")) == pytest.approx(math.sqrt(2 * 9.8 / 0.159))


@pytest.mark.parametrize("contact", ["rolling", "slipping", "point"])
def test_eigenfrequencies_change_stability_at_critical_speed(contact):
    sc = Scene(contact=contact, R=0.03)
    wc = critical_omega(sc)
    assert is_stable(sc, wc * 1.001) and not is_stable(sc, wc * 0.999)
    below = eigenfrequencies(sc, wc * 0.99)
    above = eigenfrequencies(sc, wc * 1.01)
    assert below.imag.min() < -1e-3  # a growing mode
    assert np.allclose(above.imag, 0.0, atol=1e-9)
    # the symmetric saddle has no upper bound
    assert stable_band(sc, omega_max=500.0) == [(pytest.approx(wc, rel=1e-9), math.inf)]


def test_eigenfrequencies_solve_the_quartic():
    sc = Scene(R=0.025, b=0.14)
    c = abcd(sc, 17.0, 2.0)
    for w in eigenfrequencies(sc, 17.0, 2.0):
        assert abs(w**4 + (c.A + c.C + c.B * c.D) * w**2 + c.A * c.C) < 1e-9 * abs(c.A * c.C)


@pytest.mark.parametrize("a, b", [(0.159, 0.12), (0.2, 0.1), (0.159, 0.159), (0.1, 0.3),
                                  (0.2, 0.05), (0.25, 0.1)])
def test_mass_point_band_matches_closed_form(a, b):
    sc = Scene(contact="point", a=a, b=b)
    band = stable_band(sc, omega_max=400.0)
    closed = mass_point_band(a, b)
    if closed is None:  # a >= 3b
        assert band == []
        return
    low, high = closed
    assert len(band) == 1
    assert band[0][0] == pytest.approx(low, rel=1e-10)
    if math.isinf(high) or high > 400:
        assert band[0][1] == math.inf
    else:
        assert band[0][1] == pytest.approx(high, rel=1e-10)


def test_asymmetric_rigid_ball_band_has_an_upper_edge():
    sc = Scene(a=0.159, b=0.05, R=0.02, contact="slipping")
    (low, high), = stable_band(sc)
    assert low == pytest.approx(math.sqrt(2 * 9.8 / (0.159 - 0.04)), rel=1e-10)
    assert math.isfinite(high) and high > low
    assert is_stable(sc, 0.5 * (low + high)) and not is_stable(sc, high * 1.001)
    assert critical_omega(sc) == low


def test_rolling_ball_on_asymmetric_saddle_restabilises_at_high_speed():
    # The gyroscopic coupling of rolling (B, D) gives a second band at high speed.
    sc = Scene(a=0.159, b=0.05, R=0.005)
    bands = stable_band(sc, omega_max=2000.0)
    assert len(bands) == 2 and bands[1][1] == math.inf
    gap = 0.5 * (bands[0][1] + bands[1][0])
    assert not is_stable(sc, gap) and is_stable(sc, 2 * bands[1][0])
