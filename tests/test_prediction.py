"""saddle_env.prediction.predict_batch: the MPC's window on the integrator.

A one-segment prediction is `simulate` on the same drive, sample for sample and bit for
bit (the same compiled loop, the same output times); segments chain the state and the saddle
angle; events stop a run where `simulate` stops.
"""

import numpy as np
import pytest

from saddle_env import OmegaProfile, Scene, initial_state, prediction, simulate
from saddle_env import kernels as K
from saddle_env.compilation import threads as threads_mod
from saddle_env.compilation.specialise import FULL_KERNELS_ENV, entry, specialise
from saddle_env.compilation.threads import in_threads
from saddle_env.integrators import STATUS_DETACH, STATUS_DONE, STATUS_ESCAPE
from saddle_env.prediction import predict_batch
from saddle_env.simulate import drive_row

RTOL, MAX_STEP = 1e-9, 0.02


def _drives(rows):
    """(n, S, 8) from per-run lists of (profile, force) pairs."""
    return np.array([[drive_row(prof, force) for prof, force in run] for run in rows])


def _padded(scene, state):
    y = np.zeros(K.STATE_WIDTH)
    y[:scene.state_size] = state
    return y


# (scene, contact point placed at rest in the laboratory, drive, duration, samples): a ramp
# with ripple and an air current on a rolling ball, a slipping ball at constant speed, and
# the point model ramping down.
CASES = [
    (Scene(), (0.01, 0.004), OmegaProfile(18.0, 3.0, 0.8, 20.0, 0.4), (0.3, -0.2), 0.4, 7),
    (Scene(contact="slipping", R=0.03), (-0.006, 0.01), OmegaProfile(20.0), (0.0, 0.0), 0.25, 5),
    (Scene(contact="point"), (0.012, 0.0), OmegaProfile(21.0, -4.0), (0.1, 0.1), 0.3, 3),
]


def _start(case):
    scene, xy, prof = case[:3]
    return initial_state(scene, *xy, start="lab-rest", omega=prof)


def test_one_segment_is_simulate_bit_for_bit():
    scenes = [c[0] for c in CASES]
    Y0 = np.array([_padded(s, _start(c)) for s, c in zip(scenes, CASES)])
    drives = _drives([[(c[2], c[3])] for c in CASES])
    # one duration per run; runs sample on their own grids (T / m each), padded with NaN
    durations = np.array([[c[4]] for c in CASES])
    for r, (scene, _, prof, force, T, m) in enumerate(CASES):
        pred = predict_batch(scene.model_code, scene.params()[None], Y0[r:r + 1],
                             drives[r:r + 1], durations[r:r + 1], T / m, rtol=RTOL,
                             max_step=MAX_STEP)
        traj = simulate(scene, _start(CASES[r]), T, omega=prof, dt_out=T / m,
                        rtol=RTOL, max_step=MAX_STEP, force=force)
        assert traj.event is None and pred.status[0] == STATUS_DONE
        assert len(traj.t) == m + 1  # t = 0 and the m samples
        np.testing.assert_array_equal(pred.t[0, 0, :m], traj.t[1:])
        np.testing.assert_array_equal(pred.state[0, 0, :m, :scene.state_size], traj.state[1:])
        np.testing.assert_array_equal(pred.final_state[0, :scene.state_size], traj.state[-1])
        dy = np.empty(K.STATE_WIDTH)
        row = drive_row(prof, force)
        expected = [K.rhs(scene.model_code, scene.params(), row, t, y, dy, True)
                    for t, y in zip(traj.t[1:], pred.state[0, 0, :m])]
        np.testing.assert_array_equal(pred.normal[0, 0, :m], expected)


def _cases_batch():
    """Every case of CASES as one run of a batch: models, P, Y0, drives, durations."""
    scenes = [c[0] for c in CASES]
    Y0 = np.array([_padded(s, _start(c)) for s, c in zip(scenes, CASES)])
    drives = _drives([[(c[2], c[3])] for c in CASES])
    durations = np.full((len(CASES), 1), 0.3)
    P = np.array([s.params() for s in scenes])
    models = np.array([s.model_code for s in scenes])
    return models, P, Y0, drives, durations


def test_the_kernel_is_called_with_the_same_types_however_the_models_are_given(monkeypatch):
    """One model for all runs (an int), one per run (an array, of any integer type): the
    compiled kernel gets the same argument types, so one compiled entry point (the install's
    build holds one per contact model) serves every form, and `kernels.entry`, which keeps
    the entry it checked first, never hands it others."""
    import numba

    models, P, Y0, drives, durations = _cases_batch()
    keep = [0, 0, 0]      # three runs of one model
    seen = []
    real = entry

    def spy(codes, resist, module, name, args):
        seen.append(tuple(numba.typeof(a) for a in args))
        return real(codes, resist, module, name, args)

    monkeypatch.setattr(prediction, "entry", spy)
    for given in (int(models[0]), models[keep], models[keep].astype(np.int32),
                  np.broadcast_to(models[:1], (3,))):
        predict_batch(given, P[keep], Y0[keep], drives[keep], durations[keep], 0.05,
                      rtol=RTOL, max_step=MAX_STEP)
    assert len(seen) == 4 and len(set(seen)) == 1, seen


def test_runs_of_a_batch_do_not_interact():
    """A batch of mixed contact models gives each run what it gives alone."""
    models, P, Y0, drives, durations = _cases_batch()
    together = predict_batch(models, P, Y0, drives, durations, 0.05, rtol=RTOL, max_step=MAX_STEP)
    for r in range(len(CASES)):
        alone = predict_batch(models[r], P[r:r + 1], Y0[r:r + 1], drives[r:r + 1],
                              durations[r:r + 1], 0.05, rtol=RTOL, max_step=MAX_STEP)
        np.testing.assert_array_equal(together.state[r], alone.state[0])
        np.testing.assert_array_equal(together.normal[r], alone.normal[0])


@pytest.mark.parametrize("start, omega, status", [((0.03, 0.0, 0.0, 0.2), 25.0, STATUS_DETACH),
                                                  ((0.04, 0.0, 0.0, 0.4), 20.0, STATUS_ESCAPE)])
def test_a_run_stops_at_the_event_simulate_finds(start, omega, status):
    scene = Scene()
    y0 = initial_state(scene, *start)
    traj = simulate(scene, y0, 1.0, omega=omega, dt_out=0.01, rtol=RTOL, max_step=MAX_STEP)
    assert traj.event is not None and traj.event.t > 0.05
    # the event lands in the second of three segments of 0.05, 0.95 and 1 s
    drives = _drives([[(OmegaProfile(omega), (0.0, 0.0))] * 3])
    pred = predict_batch(scene.model_code, scene.params()[None], _padded(scene, y0)[None],
                         drives, np.array([[0.05, 0.95, 1.0]]), 0.01, rtol=RTOL,
                         max_step=MAX_STEP)
    assert pred.status[0] == status
    # the first segment is simulate's first five outputs; the second counts time from its
    # own start (output times round differently), so from there only the physics agrees
    np.testing.assert_array_equal(pred.state[0, 0, :5], traj.state[1:6])
    np.testing.assert_allclose(pred.final_state[0], traj.event.state, rtol=1e-6,
                               atol=1e-9)
    assert np.isnan(pred.state[0, 2]).all()  # the third segment was never reached
    reached = np.isfinite(pred.state[0, 1, :, 0])
    assert 0 < reached.sum() < 95
    assert (pred.normal[0, 1, reached] > 0).all()


def test_segments_chain_the_state_and_the_saddle_angle():
    """Two segments under one constant drive end where one segment of their total length
    does: the angle carries over, so the lab-fixed air current keeps its direction (started
    afresh at θ0 = 0 it would point 5 rad away after the first 0.3 s)."""
    scene = Scene()
    y0 = _padded(scene, initial_state(scene, 0.01, 0.0, 0.0, 0.03))
    row = (OmegaProfile(18.0), (0.4, -0.3))
    split = predict_batch(scene.model_code, scene.params()[None], y0[None],
                          _drives([[row, row]]), np.array([[0.3, 0.2]]), 0.1, rtol=1e-11,
                          max_step=MAX_STEP)
    whole = predict_batch(scene.model_code, scene.params()[None], y0[None], _drives([[row]]),
                          np.array([[0.5]]), 0.1, rtol=1e-11, max_step=MAX_STEP)
    assert split.status[0] == whole.status[0] == STATUS_DONE
    np.testing.assert_allclose(split.final_state, whole.final_state, rtol=1e-8, atol=1e-11)
    np.testing.assert_allclose(split.t[0, 1, :2], [0.4, 0.5], rtol=1e-14)


def test_a_segment_of_no_duration_is_skipped():
    scene = Scene()
    y0 = _padded(scene, initial_state(scene, 0.01, 0.0, 0.0, 0.03))
    a, b = (OmegaProfile(18.0, 5.0), (0.2, 0.0)), (OmegaProfile(19.5), (0.2, 0.0))
    two = predict_batch(scene.model_code, scene.params()[None], y0[None], _drives([[a, b]]),
                        np.array([[0.3, 0.2]]), 0.05, rtol=RTOL, max_step=MAX_STEP)
    three = predict_batch(scene.model_code, scene.params()[None], y0[None],
                          _drives([[a, a, b]]), np.array([[0.3, 0.0, 0.2]]), 0.05, rtol=RTOL,
                          max_step=MAX_STEP)
    np.testing.assert_array_equal(three.final_state, two.final_state)
    np.testing.assert_array_equal(three.state[0, [0, 2]], two.state[0])
    assert np.isnan(three.state[0, 1]).all()


def test_bad_shapes_are_refused():
    scene = Scene()
    with pytest.raises(ValueError, match="shapes disagree"):
        predict_batch(scene.model_code, scene.params()[None], np.zeros((2, 5)),
                      np.zeros((1, 1, K.DRIVE_WIDTH)), np.ones((1, 1)), 0.1)
    with pytest.raises(ValueError, match="sample"):
        predict_batch(scene.model_code, scene.params()[None], np.zeros((1, 5)),
                      np.zeros((1, 1, K.DRIVE_WIDTH)), np.ones((1, 1)), 0.0)


@pytest.mark.parametrize("models, message", [
    (np.array([0, 0]), r"models must be one contact model code .* or 3 of them, .* shape \(2,\)"),
    (np.array([0]), r"or 3 of them, one per run, got ndarray of shape \(1,\)"),  # not broadcast
    ([0, 0, 0, 0], r"or 3 of them, .* shape \(4,\)"),
    (np.zeros((3, 1), dtype=int), r"shape \(3, 1\)"),
    (0.0, r"models must be one contact model code .* dtype float64"),
])
def test_models_of_the_wrong_length_are_refused(models, message):
    # one entry per run or one for all: a sequence's length never broadcasts
    _, P, Y0, drives, durations = _cases_batch()
    with pytest.raises(ValueError, match=message):
        predict_batch(models, P, Y0, drives, durations, 0.05)


def test_scales_of_the_wrong_shape_are_refused():
    _, P, Y0, drives, durations = _cases_batch()
    models = np.array([Scene().model_code] * 3)
    with pytest.raises(ValueError, match=rf"scales must have shape \(3, {K.STATE_WIDTH}\)"):
        predict_batch(models, P, Y0, drives, durations, 0.05, scales=np.ones(K.STATE_WIDTH))


def test_a_batch_compiled_for_its_own_contact_models_predicts_identically(monkeypatch):
    """`predict_batch` compiles its kernel for the batch's contact models alone
    (`compilation.specialise`, as the environment does): a rolling batch's prediction is the
    full kernels' bit for bit, and mixing in a slipping run takes a copy for both."""
    import sys

    scenes = [CASES[0][0], CASES[1][0]]
    Y0 = np.array([_padded(s, _start(c)) for s, c in zip(scenes, CASES)])
    drives = _drives([[(c[2], c[3]), (OmegaProfile(24.0), (0.0, 0.0))] for c in CASES[:2]])
    durations = np.array([[0.2, 0.15], [0.25, 0.1]])
    P = np.array([s.params() for s in scenes])
    models = np.array([s.model_code for s in scenes])

    def predict(k):
        return predict_batch(models[:k], P[:k], Y0[:k], drives[:k], durations[:k], 0.05,
                             rtol=RTOL, max_step=MAX_STEP)

    monkeypatch.delenv(FULL_KERNELS_ENV)           # the copies (the suite's default)
    own = [predict(1), predict(2)]
    module = sys.modules["saddle_env.prediction"]
    assert specialise(models[:1], False, module) is not module
    monkeypatch.setenv(FULL_KERNELS_ENV, "1")
    for k, pred in zip((1, 2), own):
        full = predict(k)
        for name in ("t", "state", "normal", "status", "final_state"):
            np.testing.assert_array_equal(getattr(pred, name), getattr(full, name))


@pytest.mark.parametrize("threads", [2, 3, 7])
def test_a_batch_over_threads_is_the_batch_on_one_thread_bit_for_bit(monkeypatch, threads):
    """`predict_batch` splits its runs among threads (`compilation.threads.in_threads`) when there is
    enough to simulate: any split gives the one-thread results to the last bit (more
    threads than runs included)."""
    models, P, Y0, drives, durations = _cases_batch()

    def predict():
        return predict_batch(models, P, Y0, drives, durations, 0.05, rtol=RTOL,
                             max_step=MAX_STEP)

    monkeypatch.setattr(threads_mod, "thread_count", lambda: 1)
    alone = predict()
    monkeypatch.setattr(threads_mod, "thread_count", lambda: threads)
    monkeypatch.setattr(threads_mod, "THREADS_FROM_SIMULATED_S", 0.0)   # split even this small batch
    split = predict()
    for name in ("t", "state", "normal", "status", "final_state"):
        np.testing.assert_array_equal(getattr(split, name), getattr(alone, name))


def test_threads_cover_every_row_once_and_pass_on_an_error():
    """`in_threads` hands out contiguous ranges that cover 0..n-1 once, and an error in any
    range (this thread's or another's) reaches the caller after every range has ended."""
    seen = []

    def record(lo, hi, out):
        seen.append((lo, hi))
        out[lo:hi] += 1

    out = np.zeros(10, dtype=np.int64)
    in_threads(record, 10, out, threads=3)
    assert sorted(seen) == [(0, 3), (3, 6), (6, 10)] and np.all(out == 1)

    def fail_late(lo, hi, out):
        if lo > 0:
            raise ValueError(f"range {lo}-{hi}")
        out[lo:hi] += 1

    with pytest.raises(ValueError, match="range 5-10"):
        in_threads(fail_late, 10, out, threads=2)
    assert np.all(out[:5] == 2)
