"""saddle_env.iontrap: Paul and RRF traps through the project's integrators, their linear
theory checked against simulation, and the ball → ion map (docs/iontrap.md)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from saddle_env import METHODS, Scene
from saddle_env import kernels as K
from saddle_env.compilation.specialise import FULL_KERNELS_ENV, specialise
from saddle_env.iontrap import (
    Q_MAX,
    PaulTrap,
    RRFTrap,
    _q_max,
    ball_to_ion,
    eigenfrequency_mismatch,
    floquet_multipliers,
    lab_rest_state,
    linear_ball_vs_ion,
    mathieu_first_region,
    max_rel_diff,
    paper_analogy_ion,
    simulate_ion,
)
from saddle_env.linear import critical_omega, eigenfrequencies
from saddle_env.omega import OmegaProfile
from saddle_env.simulate import SimulationError, drive_row

G, A = 9.8, 0.159
KAPPA = 2 * G / A  # the saddle's field strength per unit mass


# ------------------------------------------------------------------------------------------
# Parameters
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kwargs, match", [
    ({"omega": 0.0}, "omega must be > 0"),
    ({"omega": -3.0}, "omega must be > 0"),
    ({"omega": math.nan}, "omega must be finite"),
    ({"omega": "fast"}, "omega must be a real number"),
    ({"omega": True}, "omega must be a real number"),
    ({"omega": 1e12}, "omega must lie within"),
    ({"kappa": math.inf}, "kappa must be finite"),
    ({"kappa": 1e30}, "kappa must lie within"),
    ({"omega_B": None}, "omega_B must be a real number"),
    ({"kappa_t": math.nan}, "kappa_t must be finite"),
    ({"r0": 0.0}, "r0 must be > 0"),
    ({"r0": math.nan}, "r0 must be > 0"),
    ({"r0": "1 cm"}, "r0 must be a real number"),
])
def test_rrf_rejects_bad_parameters(kwargs, match):
    with pytest.raises(ValueError, match=match):
        RRFTrap(**kwargs)


@pytest.mark.parametrize("kwargs, match", [
    ({"omega": 0.0}, "omega must be > 0"),
    ({"kappa": -1.0}, "kappa must be >= 0"),
    ({"kappa_dc": math.inf}, "kappa_dc must be finite"),
    ({"phase": math.nan}, "phase must be finite"),
    ({"r0": -0.01}, "r0 must be > 0"),
])
def test_paul_rejects_bad_parameters(kwargs, match):
    with pytest.raises(ValueError, match=match):
        PaulTrap(**kwargs)


def test_other_bad_inputs():
    with pytest.raises(ValueError, match="e_over_m must be non-zero"):
        RRFTrap.from_voltages(20.0, 0.0, 100.0, 0.01)
    with pytest.raises(ValueError, match="r0 must be > 0"):
        PaulTrap.from_voltages(20.0, 1e5, 100.0, 0.0)
    with pytest.raises(ValueError, match="d .* is needed"):
        RRFTrap.from_voltages(20.0, 1e5, 100.0, 0.01, Vt=5.0)
    with pytest.raises(ValueError, match="state must be 4 finite numbers"):
        simulate_ion(RRFTrap(), [0.001, 0.0, 0.0], 1.0)
    with pytest.raises(ValueError, match="state must be 4 finite numbers"):
        simulate_ion(RRFTrap(), [math.nan, 0.0, 0.0, 0.0], 1.0)
    with pytest.raises(ValueError, match="t_end must be > 0"):
        simulate_ion(RRFTrap(), [0.001, 0.0, 0.0, 0.0], -1.0)
    with pytest.raises(ValueError, match="method must be one of"):
        simulate_ion(RRFTrap(), [0.001, 0.0, 0.0, 0.0], 1.0, method="euler")
    with pytest.raises(ValueError, match="trap must be an RRFTrap or a PaulTrap"):
        simulate_ion(Scene(), [0.001, 0.0, 0.0, 0.0], 1.0)
    with pytest.raises(ValueError, match="trap must be a PaulTrap"):
        floquet_multipliers(RRFTrap())
    with pytest.raises(ValueError, match="kappa_dc must be 0"):
        PaulTrap(kappa_dc=1.0).critical_omega()
    with pytest.raises(ValueError, match=r"\|q\| must be <= 1000"):
        mathieu_first_region(1e4)
    with pytest.raises(ValueError, match="scene must be a saddle_env.Scene"):
        paper_analogy_ion("saddle", 20.0)
    # a spin so large that B and D have the same sign: no ion has such equations
    with pytest.raises(ValueError, match="no RRF ion matches"):
        ball_to_ion(Scene(R=0.02), 30.0, spin_z=2000.0)


def test_from_voltages():
    em, V0, r0, B, Vt, d = 2.4e6, 50.0, 0.005, 0.01, 2.0, 0.01
    t = RRFTrap.from_voltages(1e6, em, V0, r0, B=B, Vt=Vt, d=d)
    assert t.kappa == pytest.approx(em * V0 / r0 ** 2)
    assert t.omega_B == pytest.approx(em * B) and t.kappa_t == pytest.approx(em * Vt / d ** 2)
    assert t.r0 == r0
    p = PaulTrap.from_voltages(1e6, em, V0, r0, U0=3.0)
    assert p.mathieu() == pytest.approx((4 * em * 3.0 / r0 ** 2 / 1e12, 2 * em * V0 / r0 ** 2 / 1e12))


# ------------------------------------------------------------------------------------------
# The compiled rates and the integrator registry
# ------------------------------------------------------------------------------------------
def test_rates_are_the_papers_comp2_and_the_flapping_quadrupole():
    rng = np.random.default_rng(1)
    trap = RRFTrap(omega=17.0, kappa=90.0, omega_B=6.0, kappa_t=-11.0)
    M = trap.abcd().matrix()
    paul = PaulTrap(omega=23.0, kappa=80.0, kappa_dc=7.0, phase=0.4)
    prof_r = drive_row(OmegaProfile(trap.omega))
    prof_p = drive_row(OmegaProfile(paul.omega), theta0=paul.phase)
    dy = np.empty(K.STATE_WIDTH)
    for _ in range(20):
        z = rng.normal(size=4) * [1e-3, 1e-3, 1e-2, 1e-2]
        y = np.concatenate([z, [0.0]])
        t = rng.uniform(0, 5)
        assert K.rhs(trap.model_code, trap.params(), prof_r, t, y, dy, True) == math.inf
        np.testing.assert_allclose(dy[:4], M @ z, rtol=1e-13, atol=1e-16)
        K.rhs(paul.model_code, paul.params(), prof_p, t, y, dy, False)
        k = paul.kappa_dc + paul.kappa * math.cos(paul.omega * t + paul.phase)
        np.testing.assert_allclose(dy[:4], [z[2], z[3], -k * z[0], k * z[1]], rtol=1e-12)


@pytest.mark.parametrize("method", sorted(METHODS))
def test_every_registered_method_integrates_an_ion(method):
    """The exact solution of Eq. (comp2) is a matrix exponential; each method of the registry
    converges to it (fixed step for rk4, adaptive for the others)."""
    from scipy.linalg import expm

    trap = RRFTrap(omega=20.0, kappa=KAPPA, omega_B=3.0, kappa_t=-5.0)
    z0 = np.array([1e-3, -5e-4, 2e-3, 0.0])
    kw = {"dt": 1e-3} if not METHODS[method].adaptive else {"rtol": 1e-9}
    tr = simulate_ion(trap, z0, 2.0, dt_out=0.5, method=method, **kw)
    exact = expm(trap.abcd().matrix() * 2.0) @ z0
    err = np.abs(tr.state[-1, :2] - exact[:2]).max() / 1e-3
    assert err < (1e-6 if method == "rk4" else 1e-7), err
    assert method in tr.settings


def test_an_ion_runs_on_the_ion_traps_own_compiled_loop_as_on_the_full_kernels(monkeypatch):
    """`simulate_ion` compiles the integrator's loop for the ion trap alone (or takes it
    from the install's build): each trap's trajectory, escape included, is the full
    kernels' to the last bit."""
    from saddle_env import integrators

    runs = {}
    for full in ("0", "1"):
        monkeypatch.setenv(FULL_KERNELS_ENV, full)
        runs[full] = [simulate_ion(trap, [1e-3, -5e-4, 2e-3, 0.0], 2.0, dt_out=0.05)
                      for trap in (RRFTrap(omega=20.0, kappa=KAPPA, omega_B=3.0, kappa_t=-5.0),
                                   PaulTrap(omega=40.0),
                                   RRFTrap(omega=5.0, kappa=KAPPA, r0=0.01))]
    assert runs["1"][2].event is not None                      # the runaway escapes
    for own, full in zip(runs["0"], runs["1"]):
        np.testing.assert_array_equal(own.state, full.state)
        assert own.event == full.event
    monkeypatch.setenv(FULL_KERNELS_ENV, "0")
    assert specialise((RRFTrap().model_code,), False, integrators) is not integrators


def test_escape_at_r0_and_unstable_runaway():
    trap = RRFTrap(omega=0.5 * math.sqrt(KAPPA), kappa=KAPPA, r0=0.01)
    tr = simulate_ion(trap, [1e-3, 0, 0, 0], 20.0)
    assert tr.event == "escape" and 0 < tr.t_event < 20
    assert tr.r[-1] < 0.01
    with pytest.raises(SimulationError):
        simulate_ion(RRFTrap(omega=1.0, kappa=KAPPA), [1e-3, 0, 0, 0], 1e4, dt_out=None,
                     escape=False)


def test_lab_frame_views():
    rrf = RRFTrap(omega=10.0, kappa=50.0)
    s = lab_rest_state(rrf, 0.002, -0.001)
    assert s == pytest.approx([0.002, -0.001, -0.01, -0.02])
    tr = simulate_ion(rrf, s, 0.5, dt_out=0.25)
    th = rrf.omega * tr.t[-1]
    x, y = tr.state[-1, :2]
    assert tr.lab_xy()[-1] == pytest.approx([math.cos(th) * x - math.sin(th) * y,
                                              math.sin(th) * x + math.cos(th) * y])
    paul = PaulTrap(omega=30.0, kappa=KAPPA)
    assert lab_rest_state(paul, 0.001, 0.0) == pytest.approx([0.001, 0, 0, 0])
    tp = simulate_ion(paul, lab_rest_state(paul, 0.001, 0.0), 0.2, dt_out=0.1)
    assert np.array_equal(tp.lab_xy(), tp.state[:, :2])


# ------------------------------------------------------------------------------------------
# Linear theory against simulation
# ------------------------------------------------------------------------------------------
def _grows(trap, t_end, factor=30.0):
    """Whether an ion released at (1, 1) mm at rest reaches factor × 1.5 mm within t_end."""
    kw = {f: getattr(trap, f) for f in trap.__dataclass_fields__ if f != "r0"}
    tr = simulate_ion(type(trap)(**kw, r0=factor * 1.5e-3), [1e-3, 1e-3, 0.0, 0.0], t_end,
                      dt_out=None)
    return tr.event == "escape"


@pytest.mark.parametrize("omega_B, kappa_t", [(0.0, 0.0), (6.0, -20.0), (-4.0, 3.0)])
def test_rrf_threshold_stable_unstable_pair(omega_B, kappa_t):
    base = RRFTrap(omega=20.0, kappa=KAPPA, omega_B=omega_B, kappa_t=kappa_t)
    wc = base.critical_omega()
    if omega_B == 0 and kappa_t == 0:
        assert wc == pytest.approx(math.sqrt(KAPPA))
    below = RRFTrap(omega=0.97 * wc, kappa=KAPPA, omega_B=omega_B, kappa_t=kappa_t)
    above = RRFTrap(omega=1.03 * wc, kappa=KAPPA, omega_B=omega_B, kappa_t=kappa_t)
    assert not below.is_stable() and above.is_stable()
    assert below.eigenfrequencies().imag.min() < -0.1
    assert np.abs(above.eigenfrequencies().imag).max() < 1e-9
    assert _grows(below, 20.0) and not _grows(above, 20.0)


def test_rrf_critical_omega_matches_the_quartic_on_a_grid():
    for wB, kt in [(0.0, 0.0), (6.0, -20.0), (-4.0, 3.0), (10.0, 0.0)]:
        t0 = RRFTrap(kappa=KAPPA, omega_B=wB, kappa_t=kt)
        wc = t0.critical_omega()
        for w in np.linspace(wc * 1.0001, wc * 5, 200):
            assert RRFTrap(omega=w, kappa=KAPPA, omega_B=wB, kappa_t=kt).is_stable()
        assert not RRFTrap(omega=wc * 0.9999, kappa=KAPPA, omega_B=wB, kappa_t=kt).is_stable()
    assert math.isnan(RRFTrap(kappa=KAPPA, omega_B=0.0, kappa_t=5.0).critical_omega())


def test_mathieu_first_region():
    assert _q_max() == pytest.approx(Q_MAX, abs=1e-12)
    assert Q_MAX == pytest.approx(0.908046, abs=1e-6)  # the textbook value
    lo, hi = mathieu_first_region(0.0)
    assert lo == pytest.approx(0.0, abs=1e-12) and hi == pytest.approx(1.0)
    assert mathieu_first_region(-0.5) == mathieu_first_region(0.5)
    p = PaulTrap(omega=20.0, kappa=KAPPA, kappa_dc=3.0)
    assert p.mathieu() == pytest.approx((12.0 / 400.0, 2 * KAPPA / 400.0))


def test_paul_threshold_stable_unstable_pair():
    wc = PaulTrap(kappa=KAPPA).critical_omega()
    assert wc == pytest.approx(math.sqrt(2 * KAPPA / Q_MAX))
    below, above = PaulTrap(omega=0.98 * wc, kappa=KAPPA), PaulTrap(omega=1.02 * wc, kappa=KAPPA)
    assert not below.is_stable() and above.is_stable()
    # Floquet multipliers from simulation: |μ| = 1 inside the region, > 1 outside
    assert floquet_multipliers(below).max() > 1.1
    assert floquet_multipliers(above) == pytest.approx([1.0, 1.0], abs=1e-7)
    assert _grows(below, 20.0) and not _grows(above, 20.0)


def test_paul_dc_edge_of_the_first_region():
    """With a DC part the y axis (−a) closes the region first: at q = 0.5 the upper edge is
    a = −a_0(0.5) ≈ 0.1218."""
    W, q = 20.0, 0.5
    kappa = q * W * W / 2
    edge = -mathieu_first_region(q)[0]
    inside = PaulTrap(omega=W, kappa=kappa, kappa_dc=0.97 * edge * W * W / 4)
    outside = PaulTrap(omega=W, kappa=kappa, kappa_dc=1.03 * edge * W * W / 4)
    assert inside.is_stable() and not outside.is_stable()
    mi, mo = floquet_multipliers(inside), floquet_multipliers(outside)
    assert mi == pytest.approx([1.0, 1.0], abs=1e-7)
    assert mo[0] == pytest.approx(1.0, abs=1e-7) and mo[1] > 1.01  # y is the axis that goes


# ------------------------------------------------------------------------------------------
# The ball → ion map
# ------------------------------------------------------------------------------------------
def test_mass_point_is_an_rrf_ion_without_field():
    point = Scene(contact="point")
    m = ball_to_ion(point, 30.0)
    assert m.trap.kappa == pytest.approx(KAPPA) and m.trap.omega_B == 0
    assert m.trap.kappa_t == pytest.approx(0.0, abs=1e-12) and m.stretch == 1.0
    assert m.exact_unstretched
    assert m.trap.critical_omega() == pytest.approx(critical_omega(point))
    d, ion, lin = linear_ball_vs_ion(point, 30.0, [1e-3, 1e-3, 0.03, -0.03], t_end=10.0)
    assert ion.t[-1] == pytest.approx(10.0) and d < 1e-8, d


@pytest.mark.parametrize("contact", ["slipping", "rolling"])
def test_ball_with_no_relative_spin_maps_exactly(contact):
    sc = Scene(R=0.03, contact=contact)
    m = ball_to_ion(sc, 25.0)
    assert m.exact_unstretched
    al = sc.alpha if contact == "rolling" else 0.0
    assert m.trap.omega_B == pytest.approx(al * 25.0 / (1 + al))
    k = G * (1 / (A - 0.06) + 1 / (A + 0.06)) / (1 + al)
    assert m.trap.kappa == pytest.approx(k)
    assert m.trap.kappa_t == pytest.approx(G * (1 / (A + 0.06) - 1 / (A - 0.06)) / (1 + al))
    assert eigenfrequency_mismatch(sc, 25.0, m.trap) < 1e-13
    # the same thresholds: stable iff the ball is (the ion's field depends on Ω here)
    for w in np.linspace(5.0, 40.0, 71):
        assert ball_to_ion(sc, w).trap.is_stable() == (w > critical_omega(sc))
    d, _, _ = linear_ball_vs_ion(sc, 25.0, [1e-3, 1e-3, 0.0, 0.0], t_end=5.0)
    assert d < 1e-8


def test_asymmetric_saddle_maps_exactly_without_spin():
    sc = Scene(a=0.159, b=0.2, R=0.02)
    m = ball_to_ion(sc, 30.0)
    assert m.exact_unstretched
    assert eigenfrequency_mismatch(sc, 30.0, m.trap) < 1e-13


def test_spin_makes_p_differ_from_q_exact_only_after_a_stretch():
    sc = Scene(R=0.02)
    m = ball_to_ion(sc, 30.0, spin_z=5.0)
    assert not m.exact_unstretched and m.stretch > 1.005
    assert m.ball.B != pytest.approx(-m.ball.D)
    assert eigenfrequency_mismatch(sc, 30.0, m.trap, 5.0) < 1e-13
    d_st, ion, lin = linear_ball_vs_ion(sc, 30.0, [1e-3, 1e-3, 0.0, 0.0], t_end=5.0, spin_z=5.0)
    assert d_st < 1e-8
    assert max_rel_diff(lin[:, :2], ion.state[:, :2]) > 1e-3  # unstretched: a visible gap


def test_paper_analogy_ion():
    for contact in ("point", "slipping"):
        sc = Scene(R=0.02, contact=contact)
        assert eigenfrequency_mismatch(sc, 30.0, paper_analogy_ion(sc, 30.0)) < 1e-13
    rolling = Scene(R=0.02)
    ion = paper_analogy_ion(rolling, 30.0)
    assert ion.omega_B == 0.0 and ion.abcd().B == 60.0
    assert 0.05 < eigenfrequency_mismatch(rolling, 30.0, ion) < 0.5
    assert paper_analogy_ion(rolling, 30.0, 5.0).omega_B == pytest.approx(
        2 * 0.4 * 0.02 / (0.159 + 0.04) * 5.0)


def test_paul_trap_is_not_the_rotating_saddle():
    """Same field strength κ = 2g/a: the flapping trap needs Ω ≥ sqrt(2/q_max)·Ω_crt."""
    wc = critical_omega(Scene(contact="point"))
    wp = PaulTrap(kappa=KAPPA).critical_omega()
    assert wp / wc == pytest.approx(math.sqrt(2 / Q_MAX))
    assert wp / wc == pytest.approx(1.4841, abs=1e-4)
    # between the two thresholds the rotating saddle traps and the Paul trap does not
    w = 0.5 * (wc + wp)
    assert RRFTrap(omega=w, kappa=KAPPA).is_stable() and not PaulTrap(omega=w, kappa=KAPPA).is_stable()
    assert eigenfrequencies(Scene(contact="point"), w).imag.min() > -1e-12


def test_rolling_ball_exact_model_follows_its_ion():
    """Nonlinear rolling ball (placed at rest in the laboratory at x = y = 1 mm) vs the mapped
    ion over 2 s: close (the gap is the saddle's nonlinearity), while the paper's analogy ion
    is off by about the orbit's size."""
    from saddle_env import simulate
    from saddle_env.reproduce.analogy_fig import _start

    sc = Scene(R=0.02)
    state, z0 = _start(sc)
    ball = simulate(sc, state, 2.0, omega=30.0)
    m = ball_to_ion(sc, 30.0)
    ion = simulate_ion(m.trap, m.ion_state(z0), 2.0)
    paper = simulate_ion(paper_analogy_ion(sc, 30.0), z0, 2.0)
    assert max_rel_diff(ball.centre[:, :2], ion.state[:, :2]) < 0.03
    assert max_rel_diff(ball.centre[:, :2], paper.state[:, :2]) > 0.3


# ------------------------------------------------------------------------------------------
# saddle-reproduce
# ------------------------------------------------------------------------------------------
def test_reproduce_only_analogy(tmp_path):
    from saddle_env.reproduce import main

    assert main(["--quick", "--only", "analogy", "--out", str(tmp_path), "--no-progress"]) == 0
    assert (tmp_path / "analogy.png").stat().st_size > 10_000
    assert (tmp_path / "analogy.csv").exists() and (tmp_path / "analogy_orbits.csv").exists()
    s = json.loads((tmp_path / "summary.json").read_text())["analogy"]
    assert s["masspoint_rrf_max_rel_diff"] < 1e-8
    assert s["rolling_eigenfrequency_mismatch"] > 0.05
    assert s["rolling_eigenfrequency_mismatch_best_ion"] < 1e-12
    assert s["paul_threshold"] == pytest.approx(s["omega_crt_mass_point"] * math.sqrt(2 / Q_MAX))
    assert abs(s["paul_threshold_first_stable_on_grid"] - s["paul_threshold"]) < 0.5
