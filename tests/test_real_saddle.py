"""What a real saddle adds to the scene: a tilted axis, a square outline, surface drag and
the saddle given by its curvatures (Scene.tilt, rim_shape, surface_drag, from_curvatures).

Layers: validation names the parameter; a level scene is packed exactly as before; a tilted
axis moves a trapped mass point onto the orbit linear theory gives (its mean position in
the laboratory included); a square saddle lets the ball go at its edge, not at a circle;
the work of the surface drag closes the Jacobi integral's balance, and it undoes the trap
at the rate linear theory gives; the environment takes the three options.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from helpers import assert_matches_lab_frame
from reference_lab_frame import simulate_lab_frame

import saddle_env  # noqa: F401  (registers the environments)
from saddle_env import OmegaProfile, Scene, initial_state, simulate
from saddle_env.scene import P_G, P_RIM_SQUARE, P_SURFACE_DRAG, P_TILT_FORCE

G = 9.81


@pytest.mark.parametrize("kw, match", [
    ({"tilt": -1e-3}, "tilt"), ({"tilt": 0.3}, "tilt"), ({"tilt": math.nan}, "tilt"),
    ({"rim_shape": "hexagon"}, "rim_shape"), ({"surface_drag": -0.1}, "surface_drag"),
    ({"surface_drag": "x"}, "surface_drag"),
])
def test_bad_options_are_named(kw, match):
    with pytest.raises(ValueError, match=match):
        Scene(**kw)


def test_curvatures_give_the_lengths_and_are_checked():
    sc = Scene.from_curvatures(2.67, 4.66, R=0.0095)
    assert sc.a == 1 / 2.67 and sc.b == 1 / 4.66
    assert sc.c_plus == pytest.approx(2.67) and sc.c_minus == pytest.approx(4.66)
    for bad in ({"c_plus": 0.0, "c_minus": 1.0}, {"c_plus": 1.0, "c_minus": -2.0}):
        with pytest.raises(ValueError, match="c_plus|c_minus"):
            Scene.from_curvatures(**bad)
    with pytest.raises(ValueError, match="not both"):
        Scene.from_curvatures(2.0, 2.0, a=0.5)


def test_a_level_round_scene_packs_as_before():
    p = Scene(g=9.8).params()
    assert p[P_G] == 9.8 and p[P_TILT_FORCE] == 0.0 and p[P_RIM_SQUARE] == 0.0
    assert p[P_SURFACE_DRAG] == 0.0
    q = Scene(g=9.8, tilt=0.01, rim_shape="square", surface_drag=0.2).params()
    assert q[P_G] == pytest.approx(9.8 * math.cos(0.01), rel=1e-15)
    assert q[P_TILT_FORCE] == pytest.approx(9.8 * math.sin(0.01), rel=1e-15)
    assert q[P_RIM_SQUARE] == 1.0 and q[P_SURFACE_DRAG] == 0.2


def _forced_orbit(c_plus, c_minus, omega, force):
    """Linear theory: the mass point's orbit driven by a force per unit mass ``force`` fixed
    along the laboratory's x axis, x = X cos Ωt, y = -Y sin Ωt in the saddle's axes (which
    start along the laboratory's). From ẍ - 2Ωẏ + (2g c₊ - Ω²) x = F cos Ωt and
    ÿ + 2Ωẋ - (2g c₋ + Ω²) y = -F sin Ωt."""
    p, m, w = 2 * G * c_plus, 2 * G * c_minus, omega * omega
    det = 2 * w * (p - m) + p * m
    return force * (4 * w + m) / det, force * (4 * w - p) / det


@pytest.mark.parametrize("c_plus, c_minus, rps", [(2.67, 2.51, 1.6), (2.67, 0.997, 2.0),
                                                   (6.0, 6.0, 2.5)])
def test_a_tilt_moves_a_trapped_point_where_linear_theory_says(c_plus, c_minus, rps):
    # Started on linear theory's forced orbit, the nonlinear mass point stays on it: its
    # laboratory position averages (X + Y)/2 along the tilt, (X - Y)/2 cos 2Ωt about it.
    tilt = 2e-3
    sc = Scene.from_curvatures(c_plus, c_minus, contact="point", R=0.0, g=G, tilt=tilt,
                               rim_radius=1.0)
    omega = 2 * math.pi * rps
    X, Y = _forced_orbit(c_plus, c_minus, omega, G * math.sin(tilt) / math.cos(tilt))
    # (gravity along the tilted axis is g cos(tilt): the force per unit of it, times g)
    X, Y = X * math.cos(tilt), Y * math.cos(tilt)
    state = initial_state(sc, X, 0.0, 0.0, -Y * omega)
    periods = 20
    tr = simulate(sc, state, periods * 2 * math.pi / omega, omega=omega, dt_out=0.002,
                  rtol=1e-11)
    lab = tr.lab_xy()
    mean = lab[: -1].mean(axis=0)  # whole turns of the saddle, so the 2Ω ripple averages out
    assert mean[0] == pytest.approx((X + Y) / 2, rel=0.02)
    assert abs(mean[1]) < 0.02 * abs(X + Y) / 2
    # the whole orbit, not only its mean, to 2 % of its size
    expect = np.column_stack([X * np.cos(omega * tr.t), -Y * np.sin(omega * tr.t)])
    assert np.max(np.abs(np.column_stack([tr.x, tr.y]) - expect)) < 0.02 * max(X, Y)
    # and a level saddle does not move it: the same start then wanders off the orbit
    level = simulate(sc.with_(tilt=0.0), state, tr.t[-1], omega=omega, dt_out=0.002,
                     rtol=1e-11)
    assert np.max(np.abs(np.column_stack([level.x, level.y]) - expect)) > 0.2 * max(X, Y)


@pytest.mark.slow
@pytest.mark.parametrize("contact", ["point", "slipping", "rolling"])
def test_a_tilted_saddle_matches_the_lab_frame_reference(contact):
    # The independent laboratory-frame model knows nothing of tilts: it gets gravity
    # g cos(tilt) along the axis and a constant horizontal force g sin(tilt) along the
    # laboratory's x axis, which is what a tilted axis is. The rotating-frame kernels agree.
    tilt, omega = 0.005, 20.0
    sc = Scene(a=0.16, b=0.2, R=0.01, contact=contact, g=9.8, tilt=tilt, rim_radius=1.0)
    profile = OmegaProfile.coerce(omega)
    q0, v0 = (0.003, -0.002), (0.01, 0.004)
    s0 = initial_state(sc, *q0, *v0)
    tr = simulate(sc, s0, 0.6, omega=profile, dt_out=0.05, rtol=1e-13, events=())
    ref = simulate_lab_frame(contact, sc.a, sc.b, sc.radius, sc.alpha, 9.8 * math.cos(tilt),
                             profile, profile.rate_at, q0, v0, tr.t,
                             force=(9.8 * math.sin(tilt), 0.0))
    # the reference's N/mg is in units of its g, g cos(tilt); the model's of the whole weight
    ref = {**ref, "N_over_mg": ref["N_over_mg"] * math.cos(tilt)}
    assert_matches_lab_frame(tr, ref, sc.rolling)
    # and the tilt matters at this tolerance: the level reference is far off
    level = simulate_lab_frame(contact, sc.a, sc.b, sc.radius, sc.alpha, 9.8, profile,
                               profile.rate_at, q0, v0, tr.t)
    assert np.max(np.abs(level["x"] - ref["x"])) > 1e-5


def test_a_square_saddle_loses_the_ball_at_its_edge_not_a_circle():
    # At rest on a still saddle the ball runs away along y while x swings: a round saddle
    # loses it at sqrt(x² + y²) = rim, a square one at |y| = rim, later.
    state_args = (0.05, 0.002)
    ends = {}
    for shape in ("circle", "square"):
        sc = Scene(a=0.3, b=0.3, R=0.01, rim_radius=0.08, rim_shape=shape)
        tr = simulate(sc, initial_state(sc, *state_args), 20.0, omega=0.0, dt_out=None)
        assert tr.event is not None and tr.event.kind == "escape"
        x, y = tr.event.state[:2]
        ends[shape] = tr.event.t
        if shape == "circle":
            assert math.hypot(x, y) == pytest.approx(0.08, abs=1e-9)
        else:
            assert max(abs(x), abs(y)) == pytest.approx(0.08, abs=1e-9)
            assert math.hypot(x, y) > 0.08 + 1e-4
    assert ends["square"] > ends["circle"]


@pytest.mark.parametrize("contact", ["rolling", "point", "coulomb"])
def test_jacobi_change_equals_the_work_of_surface_drag(contact):
    kw = {"mu": 0.5} if contact == "coulomb" else {}
    sc = Scene(a=0.159, b=0.2, R=0.02, contact=contact, surface_drag=0.1, rim_radius=1.0, **kw)
    s0 = initial_state(sc, 0.004, -0.003, 0.02, 0.01)
    tr = simulate(sc, s0, 1.0, omega=14.0, rtol=1e-12, events=())
    assert np.max(np.hypot(tr.x, tr.y)) < 0.05  # still near the centre: a fair check
    residual = np.max(np.abs(tr.h - tr.h[0] - tr.work))
    assert np.max(np.abs(tr.work)) > 1e-5  # the drag did real work
    assert residual < 1e-7 * np.max(np.abs(tr.work))


def _linear_growth(c_plus, c_minus, omega, gamma):
    """The fastest growth rate [1/s] of a mass point with drag ``gamma`` against its
    velocity relative to the saddle, in the rotating frame (linear theory)."""
    k1, k2 = 2 * G * c_plus - omega ** 2, -2 * G * c_minus - omega ** 2
    A = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [-k1, 0, -gamma, 2 * omega],
                  [0, -k2, -2 * omega, -gamma]])
    return float(np.max(np.linalg.eigvals(A).real))


def test_surface_drag_undoes_the_trap_at_linear_theorys_rate():
    # Drag against the turning surface undoes the gyroscopic trap (air drag, against the
    # still laboratory, does not): the orbit's size grows as exp(σ t), σ from linear theory.
    c_plus, c_minus, omega, gamma = 2.67, 2.51, 2 * math.pi * 2.0, 0.3
    sigma = _linear_growth(c_plus, c_minus, omega, gamma)
    assert sigma > 0.3
    sc = Scene.from_curvatures(c_plus, c_minus, contact="point", R=0.0, g=G, surface_drag=gamma,
                               rim_radius=1.0)
    tr = simulate(sc, initial_state(sc, 1e-5, 0.0), 6.0, omega=omega, dt_out=0.005,
                  rtol=1e-11)
    r = np.hypot(tr.x, tr.y)
    # the envelope: the largest size within each 1 s window, over the last 4 s
    windows = [r[(tr.t >= t0) & (tr.t < t0 + 1.0)].max() for t0 in (2.0, 5.0)]
    measured = math.log(windows[1] / windows[0]) / 3.0
    assert measured == pytest.approx(sigma, rel=0.05)
    air = sc.with_(surface_drag=0.0, drag_linear=gamma)
    tr_air = simulate(air, initial_state(air, 1e-5, 0.0), 6.0, omega=omega, dt_out=0.005,
                      rtol=1e-11)
    r_air = np.hypot(tr_air.x, tr_air.y)
    first, last = (r_air[(tr_air.t >= t0) & (tr_air.t < t0 + 1.0)].max() for t0 in (0.0, 5.0))
    assert last < 0.6 * first  # the envelope shrinks


def test_the_environment_takes_the_real_saddle_options():
    env = gym.make("SaddleTrap-v0", tilt=0.004, rim_shape="square", surface_drag=0.05)
    env.reset(seed=0)
    _, _, terminated, _, info = env.step([0.0])
    assert not terminated and info["time"] > 0
    with pytest.raises(ValueError, match="rim_shape"):
        gym.make("SaddleTrap-v0", rim_shape="oval")
