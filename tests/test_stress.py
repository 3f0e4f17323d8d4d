"""Numerical stress suite: long horizons, extreme scenes, step-size abuse, property tests.

Long cases are marked ``slow`` (run with ``pytest -m slow``); the default run keeps the
10⁴-period rolling case, which takes under a second.
"""

import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares

from saddle_env import OmegaProfile, Scene, SimulationError, initial_state, simulate, simulate_batch
from saddle_env.accuracy import AccuracyWarning, jacobi_drift

# ----------------------------------------------------------------------------------------
# Long horizons: 10⁴ saddle periods at constant Ω
# ----------------------------------------------------------------------------------------
ACCURATE_RTOL = 1e-12
PERIODS = 10_000


def _distance_to_saddle(scene, c, guess):
    """Distance from point c to the surface z = x²/a − y²/b, by least squares on the foot
    point (independent of the simulator's chart c = o + R n) and the foot point itself."""
    def residual(q):
        return np.array([q[0], q[1], q[0] ** 2 / scene.a - q[1] ** 2 / scene.b]) - c

    sol = least_squares(residual, guess, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return float(np.linalg.norm(residual(sol.x))), sol.x


def _long_run(contact, start, periods, rtol=ACCURATE_RTOL, b=None):
    sc = Scene(contact=contact, b=b)
    omega = 20.0
    s0 = initial_state(sc, 0.005, 0.0025, start=start, omega=omega)
    t_end = periods * 2 * math.pi / omega
    tr = simulate(sc, s0, t_end, omega=omega, dt_out=t_end / 1000, rtol=rtol)
    assert tr.event is None
    assert np.ptp(tr.x) > 1e-3  # the orbit really moves
    return sc, tr


def _check_long_run(sc, tr, record_property, bound=1e-9):
    h = tr.h
    # relative to |h(0)| (≈ g R for a ball); the mass point's h(0) is ~0, so g·a there, as
    # in tests/test_invariants.py
    scale = abs(h[0]) if sc.radius > 0 else sc.g * sc.a
    rel = float(np.max(np.abs(h - h[0])) / scale)
    record_property("jacobi_drift_relative", rel)
    print(f"\n{sc.contact} (b = {sc.b}): {len(tr.t)} outputs over {tr.t[-1]:.0f} s: "
          f"Jacobi drift {rel:.2e} relative")
    assert rel <= bound
    # The centre stays on its offset surface: distance R from the saddle, foot point = the
    # contact point. Checked by an independent closest-point solve.
    worst_d, worst_foot = 0.0, 0.0
    for i in range(0, len(tr.t), 50):
        d, foot = _distance_to_saddle(sc, tr.centre[i], tr.state[i, :2])
        worst_d = max(worst_d, abs(d - sc.radius))
        worst_foot = max(worst_foot, float(np.hypot(*(foot - tr.state[i, :2]))))
    print(f"   centre off its offset surface by <= {worst_d:.1e} m; foot point within "
          f"{worst_foot:.1e} m of the contact point")
    assert worst_d < 1e-12
    assert worst_foot < 1e-9


def test_rolling_1e4_periods_jacobi_and_offset_surface(record_property):
    sc, tr = _long_run("rolling", "lab-rest", PERIODS)
    _check_long_run(sc, tr, record_property)


@pytest.mark.slow
@pytest.mark.parametrize("contact, b", [("slipping", None), ("point", None),
                                        ("rolling", 0.14), ("slipping", 0.14)])
def test_1e4_periods_other_models(contact, b, record_property):
    # measured: slipping 9.8e-10, point 5.1e-10, rolling (b = 0.14) 5.9e-10, slipping
    # (b = 0.14) 1.2e-9 — at the 1e-9 target, which is stated for the rolling ball
    sc, tr = _long_run(contact, "lab-rest", PERIODS, b=b)
    _check_long_run(sc, tr, record_property, bound=3e-9)


@pytest.mark.slow
def test_rolling_1e4_periods_at_the_default_setting(record_property):
    sc, tr = _long_run("rolling", "lab-rest", PERIODS, rtol=1e-10)
    h = tr.h
    drift = float(np.max(np.abs(h - h[0])) / abs(h[0]))
    print(f"\ndefault setting: Jacobi drift {drift:.2e} over 1e4 periods")
    assert drift < 1e-7


# ----------------------------------------------------------------------------------------
# Extreme scenes: correct results or a clear error, never NaN/inf
# ----------------------------------------------------------------------------------------
def _run_or_clear_error(scene, x, y, omega, t_end=1.0, start="lab-rest", **kw):
    """Simulate; return the trajectory (all outputs finite) or the clear error raised."""
    try:
        s0 = initial_state(scene, x, y, start=start, omega=omega)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", AccuracyWarning)
            tr = simulate(scene, s0, t_end, omega=omega, **kw)
    except (ValueError, SimulationError) as exc:
        assert str(exc) and "nan" not in str(exc).split(":")[0].lower()
        return exc
    for arr in (tr.state, tr.N_over_mg, tr.h, tr.centre):
        assert np.all(np.isfinite(arr))
    if tr.event is not None:
        assert np.all(np.isfinite(tr.event.state)) and 0 <= tr.event.t <= t_end
    return tr


A = 0.159


@pytest.mark.parametrize("omega", [0.0, 1e-3, 5.0, 14.0, 30.0, 60.0, 120.0, 200.0])
@pytest.mark.parametrize("contact", ["rolling", "slipping", "point"])
def test_omega_from_0_to_200(contact, omega):
    sc = Scene(contact=contact, R=0.02)
    out = _run_or_clear_error(sc, 0.004, 0.002, omega)
    assert not isinstance(out, Exception), out
    if omega == 0.0:
        # no rotation: the saddle point is unstable along y; the ball must leave it
        assert out.event is not None or np.abs(out.y[-1]) > 0.002


def test_ball_almost_as_large_as_the_curvature_allows():
    R = 0.999 * A / 2
    sc = Scene(R=R)
    # Ω_crt = sqrt(2g/(a − 2R)) ≈ 351 s⁻¹: at 20 the ball runs off; far above it is kept
    slow = _run_or_clear_error(sc, 1e-4, 0.0, 20.0)
    assert slow.event is not None
    fast = _run_or_clear_error(sc, 1e-5, 0.0, 500.0, t_end=0.2)
    assert not isinstance(fast, Exception)
    with pytest.raises(ValueError, match="R must satisfy"):
        Scene(R=A / 2)


@pytest.mark.parametrize("contact", ["rolling", "slipping"])
def test_tiny_ball_approaches_its_small_R_limit(contact):
    tiny = _run_or_clear_error(Scene(contact=contact, R=1e-6), 0.004, 0.002, 20.0)
    assert not isinstance(tiny, Exception) and tiny.event is None
    if contact == "slipping":
        # the slipping ball tends to the mass point linearly in R
        point = _run_or_clear_error(Scene(contact="point"), 0.004, 0.002, 20.0)
        tinier = _run_or_clear_error(Scene(contact=contact, R=1e-7), 0.004, 0.002, 20.0)
        d6 = np.max(np.abs(tiny.state[:, :2] - point.state[:, :2]))
        d7 = np.max(np.abs(tinier.state[:, :2] - point.state[:, :2]))
        assert d6 < 1e-5 and d7 / d6 == pytest.approx(0.1, rel=0.05)


@pytest.mark.parametrize("contact", ["rolling", "slipping", "point"])
def test_start_near_the_rim_escapes_cleanly(contact):
    sc = Scene(contact=contact, rim_radius=0.1)
    out = _run_or_clear_error(sc, 0.0999, 0.0, 20.0, start="rotating-rest")
    assert out.event is not None and out.event.kind in ("escape", "detach")
    if out.event.kind == "escape":
        assert math.hypot(*out.event.state[:2]) == pytest.approx(0.1, abs=1e-9)


@pytest.mark.parametrize("b, R", [(0.01, 0.004), (0.001, 0.0004), (10.0, 0.02), (1e3, 0.02)])
@pytest.mark.parametrize("contact", ["rolling", "slipping"])
def test_very_asymmetric_saddles(b, R, contact):
    sc = Scene(b=b, R=R, contact=contact)
    out = _run_or_clear_error(sc, 0.002, 0.001, 20.0)
    assert not isinstance(out, Exception), out


@pytest.mark.parametrize("g", [0.0, 1e-12, 1e-6])
@pytest.mark.parametrize("contact", ["rolling", "slipping", "point"])
def test_vanishing_gravity(g, contact):
    sc = Scene(g=g, contact=contact)
    out = _run_or_clear_error(sc, 0.004, 0.002, 20.0, start="rotating-rest")
    assert not isinstance(out, Exception), out
    # without gravity nothing holds the ball on a spinning saddle: it is flung off
    assert out.event is not None


def test_no_rim_runaway_is_followed_correctly_or_stopped_clearly():
    # Ω = 0, no rim: the ball rolls down the saddle's falling direction for ever. The run
    # is either followed (energy conserved while it speeds up) or stopped with a clear error.
    sc = Scene(rim_radius=math.inf)
    out = _run_or_clear_error(sc, 0.0, 0.001, 0.0, t_end=20.0, events=(),
                              start="rotating-rest", dt_out=0.1, rtol=1e-12)
    assert not isinstance(out, Exception), out
    assert abs(out.y[-1]) > 1.0 and jacobi_drift(out) < 1e-9
    stopped = _run_or_clear_error(sc, 0.0, 0.001, 0.0, t_end=20.0, events=(), max_steps=50)
    assert isinstance(stopped, SimulationError) and "max_steps" in str(stopped)


# ----------------------------------------------------------------------------------------
# Step-size abuse: detected and reported, not silently wrong
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("method, dt", [("rk4", 0.03), ("rk4", 0.5), ("dopri5", 0.05),
                                        ("dop853", 0.2), ("dop853", 2.0)])
@pytest.mark.parametrize("omega", [20.0, OmegaProfile(20.0, 2.0)])
def test_fixed_step_far_too_large_is_reported(method, dt, omega):
    sc = Scene()
    s0 = initial_state(sc, 0.005, 0.0025, start="lab-rest", omega=20.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            tr = simulate(sc, s0, 5.0, omega=omega, method=method, dt=dt, dt_out=None)
        except SimulationError:
            return  # reported as an error: fine
    flagged = [w for w in caught if issubclass(w.category, AccuracyWarning)]
    if flagged:
        return
    # Not flagged: then the run must actually be accurate to the step's own error scale.
    ref = simulate(sc, s0, 5.0, omega=omega, dt_out=None, rtol=1e-12)
    pytest.fail(f"{method} dt={dt} not reported; error "
                f"{np.max(np.abs(tr.state[-1, :2] - ref.state[-1, :2])):.2e} m")


def test_adaptive_run_with_a_huge_max_step_stays_accurate():
    # The error estimate controls adaptive steps; max_step only bounds them.
    sc = Scene()
    s0 = initial_state(sc, 0.005, 0.0025, start="lab-rest", omega=20.0)
    loose = simulate(sc, s0, 5.0, omega=20.0, rtol=1e-10, max_step=100.0, dt_out=0.1)
    ref = simulate(sc, s0, 5.0, omega=20.0, rtol=1e-13, dt_out=0.1)
    assert np.max(np.abs(loose.state[:, :2] - ref.state[:, :2])) < 1e-9


# ----------------------------------------------------------------------------------------
# Property tests over random valid scenes and states
# ----------------------------------------------------------------------------------------
@st.composite
def cases(draw):
    a = draw(st.floats(0.08, 0.3))
    b = draw(st.floats(0.08, 0.3))
    contact = draw(st.sampled_from(["rolling", "slipping", "point"]))
    R = draw(st.floats(0.001, 0.45)) * min(a, b)
    sc = Scene(a=a, b=b, R=R, alpha=draw(st.floats(0.2, 1.0)), contact=contact,
               rim_radius=draw(st.floats(0.03, 0.2)),
               drilling_friction=draw(st.sampled_from([0.0, 1.0])))
    omega = OmegaProfile(draw(st.floats(0.0, 60.0)), draw(st.floats(-5.0, 5.0)),
                         draw(st.floats(0.0, 2.0)), draw(st.floats(0.0, 20.0)))
    r = draw(st.floats(0.0, 0.9)) * sc.rim_radius
    phi = draw(st.floats(0.0, 2 * math.pi))
    start = draw(st.sampled_from(["rotating-rest", "lab-rest"]))
    s0 = initial_state(sc, r * math.cos(phi), r * math.sin(phi), start=start, omega=omega)
    return sc, s0, omega


PROPERTY = settings(max_examples=25, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])


def _sim(sc, s0, omega, t_end=0.5):
    return simulate(sc, s0, t_end, omega=omega, dt_out=0.05)


@PROPERTY
@given(cases())
def test_property_finite_and_repeatable(case):
    sc, s0, omega = case
    try:
        a = _sim(sc, s0, omega)
    except SimulationError:
        assume(False)  # a clear error is allowed (covered above); no NaN may come out
    b = _sim(sc, s0, omega)
    for arr in (a.state, a.N_over_mg, a.h):
        assert np.all(np.isfinite(arr))
    assert np.array_equal(a.state, b.state) and a.t.tobytes() == b.t.tobytes()
    assert (a.event is None) == (b.event is None)
    if a.event is not None:
        assert a.event.t == b.event.t and np.array_equal(a.event.state, b.event.state)


@PROPERTY
@given(st.lists(cases(), min_size=2, max_size=4))
def test_property_batch_equals_single(balls):
    scenes = [c[0] for c in balls]
    states = np.zeros((len(balls), 5))
    for i, (sc, s0, _) in enumerate(balls):
        states[i, : sc.state_size] = s0
    omegas = [c[2] for c in balls]
    res = simulate_batch(scenes, states, 0.5, omega=omegas, dt_out=0.05)
    for i, (sc, s0, om) in enumerate(balls):
        try:
            tr = _sim(sc, s0, om)
        except SimulationError:
            assert res.status[i] < 0
            continue
        n = len(tr.t)
        assert res.n_out[i] == n
        assert np.array_equal(res.state[i, :n, : sc.state_size], tr.state)
        if tr.event is not None:
            assert res.t_final[i] == tr.event.t
            assert np.array_equal(res.final_state[i, : sc.state_size], tr.event.state)


@PROPERTY
@given(cases())
def test_property_event_times_consistent_with_N(case):
    sc, s0, omega = case
    try:
        tr = _sim(sc, s0, omega, t_end=1.0)
    except SimulationError:
        assume(False)
    N = tr.N_over_mg
    g = sc.g if sc.g > 0 else 1.0
    # In contact at every output before the run ended (N >= 0 up to roundoff).
    assert np.all(N >= -1e-9), N.min()
    if tr.event is None:
        return
    t_e = tr.event.t
    if t_e == 0.0:
        # already detached/outside at the start: reported at once, with no outputs
        assert len(tr.t) == 0
        return
    assert t_e >= tr.t[-1]
    if tr.event.kind == "detach":
        # N vanishes at the located time (to the event-time tolerance) and is positive just
        # before it: a run stopping 1e-6 s earlier has no event.
        from saddle_env import kernels as K
        from saddle_env.simulate import drive_row

        y = np.zeros(K.STATE_WIDTH)
        y[: sc.state_size] = tr.event.state
        n_at = K.rhs(sc.model_code, sc.params(), drive_row(omega), t_e, y,
                     np.zeros(K.STATE_WIDTH), True)
        assert abs(n_at) / g < 1e-5, n_at
        if t_e > 1e-5:
            before = simulate(sc, s0, t_e - 1e-6, omega=omega, dt_out=None)
            assert before.event is None or before.event.kind != "detach"
    else:
        assert math.hypot(*tr.event.state[:2]) == pytest.approx(sc.rim_radius, abs=1e-8)


@pytest.mark.slow
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_property_many_examples(case):
    sc, s0, omega = case
    try:
        a = simulate(sc, s0, 2.0, omega=omega)
    except SimulationError:
        return
    assert np.all(np.isfinite(a.state)) and np.all(np.isfinite(a.N_over_mg))
    assert np.all(a.N_over_mg >= -1e-9)
