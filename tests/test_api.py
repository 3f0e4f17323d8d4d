import math

import numpy as np
import pytest
from helpers import batch_and_singles

import saddle_env as se
from saddle_env import OmegaProfile, Scene, initial_state, simulate, simulate_batch


def test_initial_state_rolling_spin_rolls_without_slipping():
    sc = Scene()
    s = initial_state(sc, 0.01, -0.004, 0.02, 0.03, spin_normal=1.5)
    tr = simulate(sc, s, 0.01, omega=20.0, dt_out=0.01)
    assert tr.vx[0] == pytest.approx(0.02, rel=1e-12)
    assert tr.vy[0] == pytest.approx(0.03, rel=1e-12)
    # the spin about the normal is what was asked for
    x, y = 0.01, -0.004
    n = np.array([-2 * x / sc.a, 2 * y / sc.b, 1.0])
    n /= np.linalg.norm(n)
    assert s[2:] @ n == pytest.approx(1.5, rel=1e-12)


@pytest.mark.parametrize("contact", ["rolling", "slipping", "point"])
def test_lab_rest_centre_has_no_horizontal_lab_velocity_on_axes(contact):
    # On the x axis the tangent plane contains the direction of -Ω k×c, so a ball placed at
    # rest in the lab really is at rest there.
    sc = Scene(contact=contact, R=0.03)
    s = initial_state(sc, 0.01, 0.0, start="lab-rest", omega=25.0)
    tr = simulate(sc, s, 0.01, omega=25.0, dt_out=0.01)
    c = tr.centre[0]
    vx_c, vy_c = tr.vx[0], tr.vy[0]  # contact point; check the centre velocity instead
    from helpers import centre_state
    cs = centre_state(sc, s)
    lab_v = cs[2:] + 25.0 * np.array([-c[1], c[0]])
    assert np.allclose(lab_v, 0.0, atol=1e-14)
    assert vx_c == pytest.approx(0.0, abs=1e-14) and abs(vy_c) > 0.1


@pytest.mark.parametrize("contact", ["rolling", "slipping", "point"])
@pytest.mark.parametrize("method, kw", [("dop853", {}), ("dopri5", {"rtol": 1e-8}),
                                        ("rk4", {"dt": 1e-3})])
def test_batch_is_bit_identical_to_single(contact, method, kw):
    sc = Scene(contact=contact, R=0.025)
    omegas = [18.0, OmegaProfile(22.0, 1.5, 0.5, 3.0), 30.0]
    starts = [(0.004, 0.002), (-0.01, 0.003), (0.002, -0.006)]
    states = np.array([initial_state(sc, x, y) for x, y in starts])
    batch = simulate_batch(sc, states, 2.0, omega=omegas, method=method, **kw)
    for i in range(3):
        single = simulate(sc, states[i], 2.0, omega=omegas[i], method=method, **kw)
        n = len(single.t)
        assert batch.n_out[i] == n
        assert np.array_equal(batch.state[i, :n, : sc.state_size], single.state)
        assert batch.event(i) == (single.event.kind if single.event else None)
        if single.event:
            assert batch.t_final[i] == single.event.t


def test_batch_mixes_contact_models():
    scenes = [Scene(contact="rolling"), Scene(contact="slipping"), Scene(contact="point")]
    batch, singles = batch_and_singles(scenes)
    for i, (sc, single) in enumerate(zip(scenes, singles)):
        assert np.array_equal(batch.state[i, : len(single.t), : sc.state_size], single.state)


def test_a_narrower_balls_padding_in_a_mixed_batch_is_nan_not_the_kernels_scratch():
    # A dissipating rolling ball beside a Coulomb ball: the batch is 7 wide, the rolling
    # ball's state 5; its slots 5 and 6 (where the kernel keeps the work and scratch) read
    # NaN, in the outputs and in the final state of a ball stopped by an event.
    rolling, coulomb = Scene(contact="rolling", drag_linear=0.5), Scene(contact="coulomb", mu=0.05)
    states = np.zeros((2, 7))
    states[0, :5] = initial_state(rolling, 0.05, 0.0)
    states[1] = initial_state(coulomb, 0.01, 0.0)
    batch = simulate_batch([rolling, coulomb], states, 3.0, omega=5.0, dt_out=0.1)
    assert batch.event(0) is not None and np.any(batch.work[0, 1:batch.n_out[0]] != 0.0)
    assert np.all(np.isnan(batch.state[0, :, 5:])) and np.all(np.isnan(batch.final_state[0, 5:]))
    assert np.all(np.isfinite(batch.final_state[0, :5]))
    assert np.all(np.isfinite(batch.final_state[1])) and np.all(np.isfinite(batch.state[1, 0]))


def test_repeated_runs_are_bit_identical():
    sc = Scene()
    s = initial_state(sc, 0.01, 0.002)
    a = simulate(sc, s, 3.0, omega=OmegaProfile(20, 2, 1, 5))
    b = simulate(sc, s, 3.0, omega=OmegaProfile(20, 2, 1, 5))
    assert np.array_equal(a.state, b.state) and np.array_equal(a.N_over_mg, b.N_over_mg)


def test_output_grid_and_lazy_normal_force():
    sc = Scene()
    tr = simulate(sc, initial_state(sc, 0.005, 0.0), 1.0, omega=20.0, dt_out=0.1,
                  events=("escape",))
    assert np.array_equal(tr.t, np.arange(11) * 0.1)
    assert tr._obs is None  # nothing derived yet
    _ = tr.h
    assert not tr._obs_has_normal  # the Jacobi integral does not compute the normal force
    assert np.all(tr.N_over_mg > 0)


def test_lab_frame_rotation():
    sc = Scene(contact="point")
    tr = simulate(sc, initial_state(sc, 0.001, 0.0), 0.2, omega=10.0, dt_out=0.05,
                  events=())
    theta = 10.0 * tr.t
    xy = tr.lab_xy()
    assert np.allclose(np.hypot(*xy.T), tr.r, rtol=1e-14)
    assert np.allclose(np.arctan2(xy[:, 1], xy[:, 0]),
                       np.arctan2(tr.y, tr.x) + theta, atol=1e-12)


BAD_CALLS = [
    (dict(t_end=0.0), "t_end must be > 0"),
    (dict(t_end=math.nan), "t_end must be finite"),
    (dict(t_end="1"), "t_end must be a real number"),
    (dict(dt_out=-1.0), "dt_out must be > 0"),
    (dict(dt_out=1e-9, t_end=100.0), "at most"),
    (dict(omega=math.nan), "omega must be finite"),
    # a ramp is an OmegaProfile, never a tuple: a sequence is one entry per ball
    (dict(omega=(20.0, 1.0)), r"omega for one ball .* exactly 1 .* shape \(2,\)"),
    (dict(omega=(1, 2, 3, 4, 5, 6)), r"omega for one ball .* OmegaProfile\(w0, rate"),
    (dict(omega=[]), r"omega for one ball .* shape \(0,\)"),
    (dict(omega=np.array([20.0, 21.0])), r"omega for one ball .* shape \(2,\)"),
    (dict(omega=[math.inf]), "omega must be finite"),
    (dict(method="euler"), "method must be one of"),
    (dict(method="rk4", rtol=1e-6), "no error estimate"),
    (dict(rtol=0.0), "rtol must satisfy"),
    (dict(rtol=2.0), "rtol must satisfy"),
    (dict(atol=-1.0), "atol must satisfy"),
    (dict(dt=0.0), "dt must be > 0"),
    (dict(dt=1e-3, rtol=1e-6), "either dt"),
    (dict(events=("detach", "explode")), "events must be a subset"),
    (dict(max_step=0.0), "max_step must be > 0"),
    (dict(max_steps=0), "max_steps must be a positive integer"),
]


@pytest.mark.parametrize("kwargs, message", BAD_CALLS)
def test_bad_simulate_arguments(kwargs, message):
    sc = Scene()
    call = dict(t_end=1.0)
    call.update(kwargs)
    with pytest.raises(ValueError, match=message):
        simulate(sc, initial_state(sc, 0.01, 0.0), **call)


# One argument, one meaning: a sequence of speeds is one entry per ball, whatever its length;
# `simulate_batch(scene, three_states, 1.0, omega=[20, 21])` was once a ramp (20 rad/s rising
# at 21 rad/s^2) for every ball.
BAD_BATCH_OMEGAS = [
    ([20.0, 21.0], r"omega as a sequence .* per ball, 3 entries, got 2"),
    ((20.0, 21.0), r"omega as a sequence .* 3 entries, got 2"),
    ([20.0, 21.0, 22.0, 23.0], r"omega as a sequence .* 3 entries, got 4"),
    ([20.0, 21.0, 22.0, 23.0, 24.0], r"3 entries, got 5; a ramp .* OmegaProfile"),
    ([20.0], r"3 entries, got 1"),
    (np.array([20.0, 21.0]), r"omega as an array must have shape \(3,\) .* or \(3, 5\)"),
    (np.full((3, 4), 20.0), r"omega as an array .* got \(3, 4\)"),
    ([[20.0, 1.0], 21.0, 22.0], r"omega\[0\] for one ball .* shape \(2,\)"),
    ([20.0, math.nan, 22.0], r"omega\[1\] must be finite"),
    ([20.0, "21", 22.0], r"omega\[1\] must be a real number"),
]


@pytest.mark.parametrize("omega, message", BAD_BATCH_OMEGAS)
def test_batch_omega_of_the_wrong_length_is_refused(omega, message):
    sc = Scene()
    states = np.array([initial_state(sc, 0.005 * (i + 1), 0.0) for i in range(3)])
    with pytest.raises(ValueError, match=message):
        simulate_batch(sc, states, 1.0, omega=omega)


def test_batch_omega_one_entry_per_ball_whatever_the_count():
    # two balls, two speeds: per-ball constant speeds (not a ramp), as two single runs; one
    # ball, one speed; a ramp for every ball is one OmegaProfile
    sc = Scene()
    states = np.array([initial_state(sc, 0.005, 0.0), initial_state(sc, 0.01, 0.0)])
    batch = simulate_batch(sc, states, 0.3, omega=[20.0, 21.0], dt_out=0.1)
    for i, w in enumerate((20.0, 21.0)):
        single = simulate(sc, states[i], 0.3, omega=w, dt_out=0.1)
        np.testing.assert_array_equal(batch.state[i], single.state)
    one = simulate_batch(sc, states[1:], 0.3, omega=[21.0], dt_out=0.1)
    np.testing.assert_array_equal(one.state[0], batch.state[1])
    ramp = OmegaProfile(20.0, 21.0)
    ramped = simulate_batch(sc, states, 0.3, omega=ramp, dt_out=0.1)
    np.testing.assert_array_equal(ramped.state[1],
                                  simulate(sc, states[1], 0.3, omega=ramp, dt_out=0.1).state)
    assert not np.array_equal(ramped.state[1], batch.state[1])


@pytest.mark.parametrize("state, message", [
    (np.zeros(4), "length 5"),
    (np.array([0.01, 0, 0, 0, math.nan]), "must be finite"),
    (["a", 0, 0, 0, 0], "real vector"),
])
def test_bad_states(state, message):
    with pytest.raises(ValueError, match=message):
        simulate(Scene(), state, 1.0)


def test_bad_initial_state_arguments():
    with pytest.raises(ValueError, match="^x must be finite"):
        initial_state(Scene(), math.nan, 0.0)
    with pytest.raises(ValueError, match="start must be"):
        initial_state(Scene(), 0.0, 0.0, start="rest")
    with pytest.raises(ValueError, match="scene must be"):
        simulate("scene", np.zeros(5), 1.0)  # type: ignore[arg-type]


def test_runaway_without_rim_is_a_clear_error():
    sc = Scene(contact="point", rim_radius=math.inf)
    s = initial_state(sc, 0.004, 0.004, start="lab-rest", omega=30.0)
    with pytest.raises(se.SimulationError, match="left the saddle"):
        simulate(sc, s, 5.0, omega=30.0, events=(), max_steps=200_000)


def test_start_outside_rim_escapes_at_once():
    sc = Scene(rim_radius=0.05)
    tr = simulate(sc, initial_state(sc, 0.06, 0.0), 1.0, omega=20.0)
    assert tr.event is not None and tr.event.kind == "escape" and tr.event.t == 0.0
    assert len(tr.t) == 0
