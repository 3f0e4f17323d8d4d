"""Integrators: declared order, adaptive accuracy, event location."""

import math

import numpy as np
import pytest
from helpers import jit_copy

from saddle_env import METHODS, Scene, initial_state, simulate
from saddle_env.compilation.specialise import FULL_KERNELS_ENV, specialise
from saddle_env.integrators import EVENT_TIME_TOL


@pytest.fixture(scope="module")
def case():
    sc = Scene()
    s0 = initial_state(sc, 0.003, 0.002)
    # DOP853 at a step 20x below the smallest tested: its error is at roundoff level
    ref = simulate(sc, s0, 1.0, omega=20.0, dt_out=None, method="dop853", dt=5e-4, events=())
    return sc, s0, ref.state[-1]


STEPS = {"rk4": [0.02, 0.01, 0.005, 0.0025], "dopri5": [0.02, 0.01, 0.005, 0.0025],
         "dop853": [0.04, 0.02, 0.01]}


@pytest.mark.parametrize("name", sorted(METHODS))
def test_measured_order_matches_declared(case, name):
    sc, s0, exact = case
    errs = []
    for dt in STEPS[name]:
        tr = simulate(sc, s0, 1.0, omega=20.0, dt_out=None, method=name, dt=dt, events=())
        errs.append(np.max(np.abs(tr.state[-1, :2] - exact[:2])))
    order = np.polyfit(np.log(STEPS[name]), np.log(errs), 1)[0]
    assert abs(order - METHODS[name].order) < 0.6, (name, order, errs)


@pytest.mark.parametrize("name", ["dopri5", "dop853"])
def test_adaptive_error_follows_tolerance(case, name):
    sc, s0, exact = case
    errs = []
    for rtol in (1e-6, 1e-8, 1e-10):
        # max_step lifted so that the tolerance, not the step cap, sets the steps
        tr = simulate(sc, s0, 1.0, omega=20.0, dt_out=None, method=name, rtol=rtol,
                      events=(), max_step=1.0)
        errs.append(np.max(np.abs(tr.state[-1, :2] - exact[:2])))
    assert errs[2] < errs[1] < errs[0]
    assert errs[2] < 1e-9 * sc.a * 100


def test_registry_declares_orders():
    assert {n: m.order for n, m in METHODS.items()} == {"rk4": 4, "dopri5": 5, "dop853": 8}
    assert not METHODS["rk4"].adaptive and METHODS["dop853"].adaptive


def test_the_tableaus_are_scipys_to_the_bit():
    """dop853's coefficients are read from scipy's file without importing scipy.integrate,
    dopri5's from scipy's RK45 on first use: both exactly scipy's."""
    from scipy.integrate._ivp import dop853_coefficients as d853
    from scipy.integrate._ivp import rk

    n, m = d853.N_STAGES, METHODS["dop853"]
    for ours, theirs in ((m.C, d853.C[:n]), (m.A, d853.A[:n, :n]), (m.B, d853.B),
                         (m.E, d853.E5), (m.E3, d853.E3)):
        np.testing.assert_array_equal(ours, theirs)
    m = METHODS["dopri5"]
    np.testing.assert_array_equal(m.A[:, :5], rk.RK45.A)
    for ours, theirs in ((m.C, rk.RK45.C), (m.B, rk.RK45.B), (m.E, rk.RK45.E)):
        np.testing.assert_array_equal(ours, theirs)
    assert METHODS["dopri5"] is m and len(METHODS) == 3 and "euler" not in METHODS
    with pytest.raises(KeyError):
        METHODS["euler"]


def _detach_case():
    sc = Scene(R=0.033)
    return sc, initial_state(sc, 0.005, 0.005)


def test_detach_time_located_to_1e_9_s():
    sc, s0 = _detach_case()
    tight = simulate(sc, s0, 1.0, omega=30.0, rtol=1e-13)
    default = simulate(sc, s0, 1.0, omega=30.0)
    assert tight.event.kind == default.event.kind == "detach"
    assert abs(default.event.t - tight.event.t) <= 1e-9
    # N vanishes at the located time and is positive just before it
    ev = tight.event
    at = simulate(sc, s0, ev.t, omega=30.0, rtol=1e-13, dt_out=None, events=())
    before = simulate(sc, s0, ev.t - 1e-9, omega=30.0, rtol=1e-13, dt_out=None, events=())
    assert abs(at.N_over_mg[-1]) < 1e-6
    assert before.N_over_mg[-1] > 0
    assert np.allclose(at.state[-1], ev.state, rtol=0, atol=1e-9)


def test_fixed_step_event_uses_the_same_root_finder():
    sc, s0 = _detach_case()
    tight = simulate(sc, s0, 1.0, omega=30.0, rtol=1e-13)
    fixed = simulate(sc, s0, 1.0, omega=30.0, method="dop853", dt=2e-3)
    assert fixed.event.kind == "detach"
    assert abs(fixed.event.t - tight.event.t) < 1e-8


def test_escape_time_located_on_the_rim():
    sc = Scene(contact="point", rim_radius=0.05)
    s0 = initial_state(sc, 0.001, 0.001)
    tr = simulate(sc, s0, 10.0, omega=30.0, events=("escape",), rtol=1e-12)
    assert tr.event.kind == "escape"
    r = math.hypot(*tr.event.state[:2])
    assert r >= 0.05 and r - 0.05 < 1e-9
    loose = simulate(sc, s0, 10.0, omega=30.0, events=("escape",), rtol=1e-10)
    assert abs(loose.event.t - tr.event.t) < 1e-9
    assert EVENT_TIME_TOL <= 1e-11


def test_events_off_means_no_stop():
    sc, s0 = _detach_case()
    tr = simulate(sc, s0, 0.3, omega=30.0, events=())
    assert tr.event is None and tr.N_over_mg.min() < 0  # N < 0 is visible, not acted on


def test_a_dip_of_N_inside_one_step_is_not_stepped_over():
    # N < 0 from t = 0.2410 s to 0.3058 s. With fixed steps of 0.08 s the step ends 0.24 and
    # 0.32 both have N > 0; the stage points see the dip and the crossing is still found.
    sc, s0 = _detach_case()
    ends = simulate(sc, s0, 0.32, omega=30.0, method="dop853", dt=0.08, dt_out=0.08, events=())
    assert np.all(ends.N_over_mg > 0)
    tight = simulate(sc, s0, 1.0, omega=30.0, rtol=1e-13)
    # dt_out = dt: the default 0.01 s grid would cut the steps to 0.01 s (now a ValueError).
    coarse = simulate(sc, s0, 1.0, omega=30.0, method="dop853", dt=0.08, dt_out=0.08)
    assert coarse.event is not None and coarse.event.kind == "detach"
    assert abs(coarse.event.t - tight.event.t) < 1e-3


def test_a_copy_compiled_for_one_contact_model_steps_it_identically(monkeypatch):
    """`compilation.specialise`: the rolling-only loop (what `simulate` runs for a rolling ball:
    the install's ahead-of-time entry point where a build matches, else numba's JIT copy)
    gives the full loop's trajectory bit for bit, and a model it was not compiled for fails
    (NaN rates) instead of being stepped as another."""
    from saddle_env import integrators as I
    from saddle_env import kernels as K
    from saddle_env.scene import ROLLING, SLIPPING

    monkeypatch.delenv(FULL_KERNELS_ENV)          # the copies (the suite's default)
    scene = Scene(a=0.159, R=0.02, contact="rolling")
    p = scene.params()
    tab = METHODS["dopri5"].tableau
    ctl = I.step_control(0.0, 1e-9, 1e-9, 1e-3, I.EVENT_DETACH | I.EVENT_ESCAPE, 100_000)
    drive = np.zeros(K.DRIVE_WIDTH)
    drive[K.DRIVE_W0] = 30.0
    t_out = np.linspace(0.0, 0.5, 6)
    rolling = specialise((ROLLING,), False, I)
    assert rolling is not I and rolling.integrate_h is not I.integrate_h
    assert specialise((ROLLING,), False, I) is rolling  # made once
    # only compiled code calls a copy that is not an entry point: no wrapper for Python
    assert rolling.rhs.targetoptions.get("no_cpython_wrapper") is True
    assert rolling.error_norm.targetoptions.get("no_cpython_wrapper") is True  # tests no flag
    assert not jit_copy(rolling.integrate_h).targetoptions.get("no_cpython_wrapper", False)
    with pytest.raises(TypeError, match="only compiled code calls"):  # not a crash
        rolling.step_factor(1.0, 2.0)
    def padded(scene):  # a state row as the loop takes it (STATE_WIDTH slots)
        y = np.zeros(K.STATE_WIDTH)
        s = initial_state(scene, x=0.001, y=0.001, start="lab-rest", omega=30.0)
        y[:len(s)] = s
        return y

    runs = []
    for loop in (I.integrate_h, rolling.integrate_h):
        y = padded(scene)
        Y = np.zeros((len(t_out), K.STATE_WIDTH))
        res = loop(ROLLING, p, drive, y, 0.0, t_out, tab, ctl, I.state_scale(p, ROLLING), Y,
                   np.zeros(4, dtype=np.int64), 0.0, I.workspace(tab))
        runs.append((res.status, res.t_final, Y))
    assert runs[0][0] == runs[1][0] == I.STATUS_DONE
    assert runs[0][1] == runs[1][1]
    np.testing.assert_array_equal(runs[0][2], runs[1][2])
    slipping = Scene(a=0.159, R=0.02, contact="slipping")
    q = slipping.params()
    y = padded(slipping)
    res = rolling.integrate_h(SLIPPING, q, drive, y, 0.0, t_out, tab, ctl,
                              I.state_scale(q, SLIPPING), np.zeros((len(t_out), K.STATE_WIDTH)),
                              np.zeros(4, dtype=np.int64), 0.0, I.workspace(tab))
    assert res.status == I.STATUS_FAILED
    monkeypatch.setenv(FULL_KERNELS_ENV, "1")      # the switch: the full kernels, no copy
    assert specialise((ROLLING,), False, I) is I
