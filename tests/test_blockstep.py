"""simulate_batch(..., shared_steps=True): blocks of balls share their steps (saddle_env.blockstep).

What must hold: a block of one ball takes exactly the steps `simulate` takes (same
operations in the same order, so the same bits); a fixed step is the same arithmetic for
every ball, so the whole batch is bit for bit the per-ball batch; with adaptive steps a
ball's trajectory stays within the tolerance of its own; a ball that meets an event leaves
the block and ends exactly as `simulate` ends it; balls no block steps run alone."""

import numpy as np
import pytest

from saddle_env import OmegaProfile, Scene, initial_state, simulate, simulate_batch


def _releases(scene, n, omega=20.0, spread=0.2, seed=3):
    rng = np.random.default_rng(seed)
    f = 1.0 + spread * (2.0 * rng.random((n, 2)) - 1.0)
    return np.array([initial_state(scene, 0.005 * fx, 0.0025 * fy, start="lab-rest",
                                   omega=omega) for fx, fy in f])


@pytest.mark.parametrize("contact", ["rolling", "slipping", "point"])
@pytest.mark.parametrize("omega", [20.0, OmegaProfile(22.0, 1.5, 0.5, 3.0)])
def test_a_block_of_one_ball_is_simulate_bit_for_bit(contact, omega):
    sc = Scene(contact=contact, R=0.02)
    s0 = _releases(sc, 1, 22.0)
    shared = simulate_batch(sc, s0, 3.0, omega=omega, dt_out=0.1, rtol=1e-9, shared_steps=True)
    single = simulate(sc, s0[0], 3.0, omega=omega, dt_out=0.1, rtol=1e-9)
    n = len(single.t)
    assert shared.n_out[0] == n
    assert np.array_equal(shared.state[0, :n, :sc.state_size], single.state)
    assert shared.event(0) == (single.event.kind if single.event else None)
    assert shared.t_final[0] == (single.event.t if single.event else 3.0)
    assert shared.stats[0, 0] == single.stats.steps
    assert shared.stats[0, 1] == single.stats.rejected


@pytest.mark.parametrize("contact", ["rolling", "slipping"])
def test_a_fixed_step_is_the_per_ball_batch_bit_for_bit(contact):
    sc = Scene(contact=contact, R=0.02)
    states = _releases(sc, 70)  # two blocks: 64 balls and 6
    kw = dict(omega=20.0, dt_out=0.05, method="dop853", dt=0.01)
    alone = simulate_batch(sc, states, 1.0, **kw)
    shared = simulate_batch(sc, states, 1.0, shared_steps=True, **kw)
    assert np.array_equal(alone.state, shared.state, equal_nan=True)
    assert np.array_equal(alone.final_state, shared.final_state, equal_nan=True)


@pytest.mark.parametrize("contact", ["rolling", "slipping"])
@pytest.mark.parametrize("rtol", [1e-6, 1e-9])
def test_shared_steps_stay_within_the_tolerance_of_each_balls_own(contact, rtol):
    sc = Scene(contact=contact, R=0.02)
    states = _releases(sc, 150)
    kw = dict(omega=20.0, dt_out=0.1, rtol=rtol)
    alone = simulate_batch(sc, states, 3.0, **kw)
    shared = simulate_batch(sc, states, 3.0, shared_steps=True, **kw)
    tight = simulate_batch(sc, states[::15], 3.0, omega=20.0, dt_out=0.1, rtol=1e-12)
    assert np.all(shared.status == 0) and np.all(alone.status == 0)
    gap = np.max(np.abs(shared.state[..., :2] - alone.state[..., :2]))
    # both are within a few tolerances of the balls' true paths: the position error of this
    # case is about 2 x rtol [m] (docs/accuracy.md), so they differ by about that, not more
    assert 0.0 < gap < 20 * rtol
    err_shared = np.max(np.abs(shared.state[::15, :, :2] - tight.state[..., :2]))
    err_alone = np.max(np.abs(alone.state[::15, :, :2] - tight.state[..., :2]))
    assert err_shared < 2 * err_alone + 1e-13
    # a block's step is the smallest its balls need: never more steps than any ball alone
    # would take by much, and never fewer than the fewest
    assert shared.stats[:, 0].min() >= alone.stats[:, 0].min()


def test_balls_that_meet_an_event_leave_the_block_and_end_as_simulate_ends_them():
    # Below the threshold speed some releases roll off the saddle's rim, others are still on
    # it at the end: the block loses them one by one.
    sc = Scene(contact="rolling", R=0.02, rim_radius=0.05)
    rng = np.random.default_rng(7)
    size = 10.0 ** rng.uniform(-8.0, -1.7, 40)  # [m]: from kept for the run to gone at once
    angle = rng.uniform(0.0, 2.0 * np.pi, 40)
    states = np.array([initial_state(sc, r * np.cos(a), r * np.sin(a))
                       for r, a in zip(size, angle)])
    kw = dict(omega=11.0, dt_out=0.05, rtol=1e-10)
    shared = simulate_batch(sc, states, 2.0, shared_steps=True, **kw)
    events = [shared.event(i) for i in range(len(states))]
    assert "escape" in events and None in events
    for i in range(len(states)):
        single = simulate(sc, states[i], 2.0, **kw)
        assert shared.event(i) == (single.event.kind if single.event else None)
        if single.event:
            assert shared.t_final[i] == pytest.approx(single.event.t, abs=1e-6)
            n = shared.n_out[i]
            assert n == len(single.t)
            assert np.allclose(shared.state[i, :n, :5], single.state, atol=1e-7)


def test_a_start_where_an_event_holds_stops_at_once_as_alone():
    sc = Scene(contact="rolling", R=0.02, rim_radius=0.05)
    states = _releases(sc, 4)
    states[2, :2] = (0.06, 0.0)  # outside the rim
    kw = dict(omega=20.0, dt_out=0.1, rtol=1e-9)
    shared = simulate_batch(sc, states, 0.5, shared_steps=True, **kw)
    alone = simulate_batch(sc, states, 0.5, **kw)
    assert shared.event(2) == alone.event(2) == "escape"
    assert shared.t_final[2] == alone.t_final[2] == 0.0
    assert np.array_equal(shared.state[2], alone.state[2], equal_nan=True)
    assert all(shared.event(i) is None for i in (0, 1, 3))


def test_balls_no_block_steps_run_alone_beside_blocks():
    scenes = [Scene(contact="rolling"), Scene(contact="coulomb", mu=0.05),
              Scene(contact="rolling", rolling_resistance=1e-3), Scene(contact="slipping"),
              Scene(contact="rolling", drag_linear=0.3), Scene(contact="rolling")]
    states = np.zeros((len(scenes), 7))
    for i, sc in enumerate(scenes):
        states[i, :sc.state_size] = initial_state(sc, 0.004, 0.002)
    kw = dict(omega=20.0, dt_out=0.1, rtol=1e-9)
    shared = simulate_batch(scenes, states, 1.0, shared_steps=True, **kw)
    alone = simulate_batch(scenes, states, 1.0, **kw)
    for i in (1, 2):  # coulomb, rolling resistance: the scalar loop, the same bits
        assert np.array_equal(shared.state[i], alone.state[i], equal_nan=True)
    for i, sc in enumerate(scenes):
        assert shared.event(i) is None
        d = sc.state_size
        assert np.allclose(shared.state[i, :, :d], alone.state[i, :, :d], atol=1e-8)
    # the dragged ball integrates its work slot in its own block and books the same work
    assert shared.work[4, -1] == pytest.approx(alone.work[4, -1], rel=1e-6)
    assert shared.work[4, -1] < 0.0 or shared.work[4, -1] > 0.0


@pytest.mark.parametrize("bad", [1, "yes", None, np.bool_(True)])
def test_shared_steps_must_be_a_bool(bad):
    sc = Scene()
    with pytest.raises(ValueError, match="shared_steps"):
        simulate_batch(sc, _releases(sc, 2), 0.1, shared_steps=bad)
