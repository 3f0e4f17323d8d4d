"""Air drag (Scene.drag_linear, Scene.drag_quadratic) and the bookkeeping of dissipated work.

Layers: the work integrated with the state closes the Jacobi integral's balance; the
rotating-frame model with drag agrees with the independent laboratory-frame reference
model; the linearisation with drag equals finite differences of the exact model, and the
nonlinear motion follows it — including the slow growth by which drag drives a rolling
ball out of a trap the drag-free model keeps for ever (dissipation-induced instability).
"""

import math

import gymnasium as gym
import numpy as np
import pytest
from helpers import assert_matches_lab_frame, batch_and_singles, centre_state, fd_linearisation
from reference_lab_frame import simulate_lab_frame

from saddle_env import OmegaProfile, Scene, initial_state, simulate
from saddle_env import kernels as K
from saddle_env.linear import (
    damped_band,
    growth_rate,
    is_stable,
    linear_trajectory,
    stable_band,
    system_matrix,
)


def _random_scene(rng, contact, drag=True):
    kw = {"contact": contact, "a": rng.uniform(0.12, 0.2), "b": rng.uniform(0.12, 0.2),
          "R": rng.uniform(0.008, 0.03), "alpha": rng.choice([0.4, 2 / 3])}
    if drag:
        kw.update(drag_linear=rng.uniform(0.0, 0.5), drag_quadratic=rng.uniform(0.0, 3.0))
    return Scene(**kw)


def test_no_drag_integrates_no_work_slot():
    # A conservative scene advances exactly the slots it did before the work slot existed
    # (so its steps are the same arithmetic), and reports no work.
    for contact, size in (("rolling", 5), ("slipping", 4), ("point", 4)):
        sc = Scene(contact=contact)
        assert K.integrated_size(sc.model_code, sc.params()) == size
        assert K.integrated_size(sc.model_code, sc.with_(drag_linear=0.1).params()) == size + 1
        assert K.integrated_size(sc.model_code, sc.with_(drag_quadratic=0.1).params()) == size + 1
        tr = simulate(sc, initial_state(sc, 0.01, 0.005), 1.0, omega=25.0)
        assert tr.work.shape == tr.t.shape and not np.any(tr.work)
    # drilling friction dissipates only on a rolling ball
    assert K.integrated_size(K.ROLLING, Scene(drilling_friction=1.0).params()) == 6
    slip = Scene(contact="slipping", drilling_friction=1.0)
    assert K.integrated_size(slip.model_code, slip.params()) == 4


@pytest.mark.parametrize("contact", ["rolling", "slipping", "point"])
def test_jacobi_change_equals_the_work_of_drag(contact):
    # h(t) - h(0) = W(t) at constant Ω, W integrated alongside the state: to 1e-9 of |h|
    # (the scale of the Jacobi drift the integrator itself leaves, ~1e-12..3e-10 here) over
    # 10 s on random scenes that stay trapped, some with drilling friction; W itself is
    # then resolved to 1e-7 or better (residuals 5e-12..9e-9 of max|W| measured).
    rng = np.random.default_rng({"rolling": 1, "slipping": 2, "point": 3}[contact])
    runs = 0
    while runs < 4:
        sc = _random_scene(rng, contact).with_(
            drilling_friction=rng.uniform(0.5, 3.0) if runs % 2 else 0.0)
        omega = rng.uniform(18.0, 30.0)
        if not is_stable(sc, omega):
            continue
        s0 = initial_state(sc, rng.uniform(-0.01, 0.01), rng.uniform(-0.01, 0.01),
                           rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), spin_normal=5.0)
        tr = simulate(sc, s0, 10.0, omega=omega, rtol=1e-12)
        if tr.event is not None:
            continue
        runs += 1
        residual = np.max(np.abs(tr.h - tr.h[0] - tr.work))
        assert np.max(np.abs(tr.work)) > 1e-4  # the drag did real work
        assert residual < 1e-9 * np.max(np.abs(tr.h))
        assert residual < 1e-7 * np.max(np.abs(tr.work))


def test_batch_reports_the_same_work():
    scenes = [Scene(drag_linear=0.2), Scene(contact="slipping", drag_quadratic=1.0),
              Scene(contact="point", drag_linear=0.1)]
    batch, singles = batch_and_singles(scenes)
    for i, (sc, single) in enumerate(zip(scenes, singles)):
        n = len(single.t)
        assert np.array_equal(batch.state[i, :n, : sc.state_size], single.state)
        assert np.array_equal(batch.work[i, :n], single.work)


@pytest.mark.parametrize("contact, seed", [("rolling", 11), ("rolling", 12), ("slipping", 13),
                                           ("point", 14)])
def test_drag_matches_the_lab_frame_reference(contact, seed):
    # Random scenes, drag in the laboratory, Ω ramping with a ripple: the independent
    # lab-frame model (drag on the lab velocity, no frame forces) agrees.
    rng = np.random.default_rng(seed)
    while True:  # a run that stays trapped, so the comparison lasts its whole length
        sc = _random_scene(rng, contact)
        profile = OmegaProfile(rng.uniform(18, 24), rng.uniform(-2, 2), rng.uniform(0, 2),
                               rng.uniform(3, 8), rng.uniform(0, 6))
        q0 = tuple(rng.uniform(-0.004, 0.004, 2))
        v0 = tuple(rng.uniform(-0.01, 0.01, 2))
        spin = rng.uniform(-5, 5) if sc.rolling else 0.0
        s0 = initial_state(sc, *q0, *v0, spin_normal=spin)
        if all(is_stable(sc, w) for w in profile(np.linspace(0.0, 2.0, 41))):
            tr = simulate(sc, s0, 2.0, omega=profile, dt_out=0.05, rtol=1e-13, events=())
            if tr.event is None and np.max(np.hypot(tr.x, tr.y)) < 0.05:
                break
    ref = simulate_lab_frame(contact, sc.a, sc.b, sc.radius, sc.alpha, sc.g, profile,
                             profile.rate_at, q0, v0, tr.t, spin_normal=spin, rtol=1e-12,
                             atol=1e-14, drag_linear=sc.drag_linear,
                             drag_quadratic=sc.drag_quadratic)
    assert_matches_lab_frame(tr, ref, sc.rolling)
    # and the drag matters at this tolerance: the drag-free reference is far off
    free = simulate_lab_frame(contact, sc.a, sc.b, sc.radius, sc.alpha, sc.g, profile,
                              profile.rate_at, q0, v0, tr.t, spin_normal=spin)
    assert np.max(np.abs(free["x"] - ref["x"])) > 1e-6


@pytest.mark.parametrize("kw, omega, spin_z", [
    ({"contact": "rolling", "b": 0.2}, 25.0, 0.0),
    ({"contact": "rolling", "a": 0.2, "b": 0.13, "R": 0.006}, 19.0, 30.0),
    ({"contact": "slipping", "b": 0.12}, 30.0, 0.0),
    ({"contact": "point"}, 20.0, 0.0),
])
def test_linearisation_with_drag_equals_finite_differences(kw, omega, spin_z):
    sc = Scene(drag_linear=0.3, **kw)
    M = system_matrix(sc, omega, spin_z)
    assert np.allclose(M, fd_linearisation(sc, omega, spin_z), rtol=1e-7, atol=1e-7)
    assert not np.allclose(M, system_matrix(sc.with_(drag_linear=0.0), omega, spin_z))


def test_drag_damps_a_slipping_ball_at_half_its_rate():
    # A frictionless ball (or mass point) feels only the drag on its lab velocity: every
    # mode of the stable trap decays as e^{-k t / 2}, whatever the speed or the saddle.
    for kw in ({"contact": "slipping"}, {"contact": "point", "b": 0.2}):
        for omega in (15.0, 25.0, 60.0):
            sc = Scene(drag_linear=0.04, **kw)
            assert is_stable(sc, omega)
            eig = np.linalg.eigvals(system_matrix(sc, omega))
            assert np.allclose(eig.real, -0.02, rtol=0, atol=1e-9)


def _orbit_vs_linear(sc, omega, release, t_end):
    s0 = initial_state(sc, release, release, start="lab-rest", omega=omega)
    tr = simulate(sc, s0, t_end, omega=omega, dt_out=0.01, rtol=1e-12, events=())
    lin = linear_trajectory(sc, omega, centre_state(sc, s0), tr.t)
    c = tr.centre[:, :2]
    gap = np.max(np.hypot(*(c - lin[:, :2]).T)) / np.max(np.hypot(*c.T))
    r = np.hypot(*c.T)
    return gap, r


def test_drag_drives_a_rolling_ball_out_of_an_asymmetric_trap():
    # Dissipation-induced instability: on this asymmetric saddle the drag-free rolling ball
    # is (marginally) stable at Ω = 19.5 rad/s, yet with drag in still air one mode grows
    # (rate ≈ 1.6 k here). The nonlinear model, released near the centre, follows the
    # linear theory with drag and its orbit grows by the predicted factor.
    sc = Scene(a=0.229, b=0.143, R=0.006, drag_linear=0.1)
    omega = 19.5
    assert is_stable(sc.with_(drag_linear=0.0), omega)
    rate = growth_rate(sc, omega)
    assert rate > 0.1
    gap, r = _orbit_vs_linear(sc, omega, 5e-6, 10.0)
    assert gap < 2e-3
    early, late = np.max(r[:200]), np.max(r[-200:])  # the first and the last 2 s
    assert late / early > math.exp(0.6 * rate * 8.0)


def test_drag_damps_a_rolling_ball_on_the_symmetric_saddle():
    sc = Scene(drag_linear=0.1)
    rate = growth_rate(sc, 25.0)
    assert rate < -0.01
    gap, r = _orbit_vs_linear(sc, 25.0, 2e-5, 10.0)
    assert gap < 1e-3
    assert np.max(r[-200:]) < np.max(r[:200])


def test_env_takes_the_drag_keywords():
    env = gym.make("SaddleTrap-v0", drag_linear=0.1, drag_quadratic=0.5)
    assert env.unwrapped.scene.drag_linear == 0.1
    assert env.unwrapped.scene.drag_quadratic == 0.5
    env.reset(seed=0)
    for _ in range(5):
        env.step(env.action_space.sample())
    with pytest.raises(ValueError, match="^drag_linear must"):
        gym.make("SaddleTrap-v0", drag_linear=-1.0)


def test_damped_band_loses_the_top_of_an_asymmetric_band_to_drag():
    # Without drag damped_band is stable_band. With drag the symmetric saddle's band keeps
    # no upper edge (every mode decays), while on the asymmetric saddle above ~12.57 rad/s
    # a mode grows (the dissipation-induced instability) and the band becomes finite; the
    # rate is ≤ 0 inside each band and > 0 just outside.
    for kw in ({"R": 0.0265}, {"a": 0.229, "b": 0.143, "R": 0.006}):
        sc = Scene(**kw)
        assert damped_band(sc, omega_max=100.0) == stable_band(sc, omega_max=100.0)
    sym = damped_band(Scene(R=0.0265, drag_linear=0.1), omega_max=100.0)
    assert len(sym) == 1 and sym[0][1] == math.inf
    sc = Scene(a=0.229, b=0.143, R=0.006, drag_linear=0.1)
    (lo, hi), = damped_band(sc, omega_max=100.0)
    free_lo = stable_band(sc, omega_max=100.0)[0][0]
    assert abs(lo - free_lo) < 1e-3 and 12.0 < hi < 13.0
    for inside in (lo * (1 + 1e-6), 0.5 * (lo + hi), hi * (1 - 1e-6)):
        assert growth_rate(sc, inside) <= 0.0
    for outside in (lo * (1 - 1e-6), hi * (1 + 1e-6), 50.0):
        assert growth_rate(sc, outside) > 0.0
