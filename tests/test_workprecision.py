"""saddle-bench, its scipy peer, and automatic accuracy (simulate(tol=...))."""

import json
import math
import warnings

import numpy as np
import pytest

from saddle_env import OmegaProfile, Scene, initial_state, simulate, simulate_batch
from saddle_env import kernels as K
from saddle_env.accuracy import AccuracyWarning, assess, check_tol, choose, jacobi_drift
from saddle_env.workprecision import main as bench_main
from saddle_env.workprecision.core import Case
from saddle_env.workprecision.peer import PeerModel
from saddle_env.workprecision.report import (
    cheapest_meeting,
    interpolated_cost,
    read_rows,
    summarize,
)


# ----------------------------------------------------------------------------------------
# The peer: an independent plain-numpy right-hand side (third cross-check of the kernels)
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("contact", ["rolling", "slipping", "point"])
def test_peer_rhs_agrees_with_the_kernels(contact):
    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(100):
        sc = Scene(a=rng.uniform(0.1, 0.3), b=rng.uniform(0.08, 0.3), R=0.02,
                   alpha=rng.uniform(0.3, 0.7), contact=contact,
                   drilling_friction=rng.uniform(0, 2))
        # the last two: a voltage-driven motor's relaxation (decay, 1/τ), zero in half the draws
        om = (rng.uniform(-30, 30), rng.uniform(-5, 5), rng.uniform(0, 3), rng.uniform(0, 10),
              rng.uniform(0, 6), rng.uniform(-10, 10) * rng.integers(0, 2), rng.uniform(1, 20))
        force, theta0, t = tuple(rng.uniform(-1, 1, 2)), rng.uniform(0, 6), rng.uniform(0, 3)
        drive = np.zeros(K.DRIVE_WIDTH)  # the full row: a short one is read past its end
        drive[[K.DRIVE_W0, K.DRIVE_RATE, K.DRIVE_AMP, K.DRIVE_FREQ, K.DRIVE_PHASE, K.DRIVE_DECAY,
               K.DRIVE_DECAY_RATE]] = om
        drive[K.DRIVE_THETA0], drive[[K.DRIVE_FX, K.DRIVE_FY]] = theta0, force
        n = sc.state_size
        y = np.zeros(K.STATE_WIDTH)
        y[:2] = rng.uniform(-0.04, 0.04, 2)
        y[2:n] = rng.uniform(-3, 3, n - 2) if sc.rolling else rng.uniform(-0.3, 0.3, 2)
        dy = np.zeros(K.STATE_WIDTH)
        N = K.rhs(sc.model_code, sc.params(), drive, t, y, dy, True)
        peer_dy, peer_N = PeerModel.from_scene(sc, om, force, theta0).derivatives(t, y[:n])
        scale = np.abs(dy[:n]) + 1e-3
        worst = max(worst, float(np.max(np.abs(peer_dy - dy[:n]) / scale)),
                    abs(peer_N - N) / (abs(N) + 1e-3))
    assert worst < 1e-12, worst


def test_peer_trajectory_matches_the_simulator():
    from scipy.integrate import solve_ivp

    sc = Scene()
    s0 = initial_state(sc, 0.005, 0.0025, start="lab-rest", omega=20.0)
    t = np.linspace(0, 1, 11)
    tr = simulate(sc, s0, 1.0, omega=20.0, dt_out=0.1, rtol=1e-12)
    sol = solve_ivp(PeerModel.from_scene(sc, (20.0,)).fun(), (0, 1), s0, method="DOP853",
                    rtol=1e-12, atol=1e-14, t_eval=t)
    assert np.max(np.abs(sol.y[:2].T - tr.state[:, :2])) < 1e-11


# ----------------------------------------------------------------------------------------
# The benchmark
# ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    # The compiled peers have their own tests (tests/test_peers.py): only scipy's here.
    assert bench_main(["--quick", "--quiet", "--out", str(out), "--jacobi-periods", "200",
                       "--peers", "plain"]) == 0
    return out


@pytest.mark.slow  # an end-to-end run: CI runs it with -m slow
def test_quick_bench_writes_csv_figures_and_summary(quick_run):
    rows = read_rows(quick_run / "bench.csv")
    tiers = {r["tier"] for r in rows}
    assert tiers == {"rolling", "slipping", "point", "coulomb", "linear"}
    assert {r["solver"] for r in rows} == {"saddle_env", "scipy"}
    for r in rows:
        assert r["us_per_sim_s"] > 0 and math.isfinite(r["us_per_sim_s"])
        assert r["status"] in ("ok", "reference")
        assert r["model_error_m"] >= 0
    for name in ("bench_single.png", "bench_batch.png"):
        assert (quick_run / name).stat().st_size > 10_000
    summary = json.loads((quick_run / "summary.json").read_text())
    t1 = summary["target_speedup"]
    assert t1["ours"]["error_m"] <= 1e-9 and t1["scipy_dop853"]["error_m"] <= 1e-9
    assert t1["speedup_cheapest_rows"] > 10  # the full run's figure is in docs/accuracy.md
    assert summary["target_jacobi"]["jacobi_drift_relative"] < 1e-9


@pytest.mark.slow  # reads the end-to-end run
def test_a_coulomb_row_counts_its_phases(quick_run):
    rows = read_rows(quick_run / "bench.csv")
    coulomb = [r for r in rows if r["tier"] == "coulomb" and r["solver"] == "saddle_env"]
    assert coulomb and all(r["phase_changes"] >= 0 and 0 <= r["slipping_share"] <= 1
                           for r in coulomb)
    others = [r for r in rows if r["tier"] == "rolling"]
    assert all(math.isnan(r["phase_changes"]) for r in others)


def test_slipping_share_is_the_time_between_located_changes():
    from saddle_env.runner import Transition
    from saddle_env.workprecision.core import slipping_share

    class Run:   # what slipping_share reads of a Trajectory
        t = np.array([0.0, 10.0])
        phase = np.array([K.STICK, K.STICK])
        transitions = [Transition(1.0, "slip"), Transition(3.0, "stick"), Transition(9.0, "slip")]

    assert slipping_share(Run()) == pytest.approx(0.3)


def test_pilot_cost_times_each_tolerance_and_gives_the_range():
    from saddle_env.workprecision import pilot

    out = pilot.pilot_cost(Case(t_end=1.0), tols=(1e-4, 1e-7), n_rounds=1)
    assert set(out["tols"]) == {"0.0001", "1e-07"}
    assert out["ratio"] == [min(r["ratio"] for r in out["tols"].values()),
                            max(r["ratio"] for r in out["tols"].values())]
    assert all(r["pilot_s"] > 0 and r["run_s"] > 0 for r in out["tols"].values())


@pytest.mark.slow  # an end-to-end run: CI runs it with -m slow
def test_summary_is_reproducible_from_the_csv(quick_run, tmp_path):
    before = json.loads((quick_run / "summary.json").read_text())
    assert bench_main(["--replot", str(quick_run / "bench.csv"), "--out", str(tmp_path),
                       "--no-figures"]) == 0
    after = json.loads((tmp_path / "summary.json").read_text())
    for key in ("target_speedup", "target_batch", "cheapest_setting_per_error",
                "model_error_vs_rolling"):
        assert after[key] == before[key]
    # Replotting in place keeps what only the run knew (machine, Jacobi drift, peers asked).
    assert bench_main(["--replot", str(quick_run / "bench.csv"), "--no-figures"]) == 0
    again = json.loads((quick_run / "summary.json").read_text())
    for key in ("machine", "target_jacobi", "peers_run", "run"):
        assert again[key] == before[key]


@pytest.mark.slow  # an end-to-end run: CI runs it with -m slow
def test_csv_rows_can_be_rerun(quick_run):
    # Every row carries its case and setting: re-running one gives the same error.
    row = next(r for r in read_rows(quick_run / "bench.csv")
               if r["tier"] == "rolling" and r["method"] == "rk4")
    case = Case(a=row["a"], R=row["R"], omega=row["omega"], x0=row["x0"], y0=row["y0"],
                t_end=row["t_end"], dt_out=row["dt_out"])
    from saddle_env.workprecision.core import centre_xy, max_distance, reference

    sc = case.scene("rolling")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AccuracyWarning)
        tr = simulate(sc, case.state("rolling"), case.t_end, omega=case.omega,
                      dt_out=case.dt_out, method="rk4", dt=row["dt"])
    err = max_distance(centre_xy(sc, tr.state), reference(case, "rolling"))
    assert err == pytest.approx(row["error_m"], rel=1e-12)


def test_bench_rejects_bad_arguments(capsys):
    for argv in (["--tiers", "nonsense"], ["--jacobi-periods", "-1"], ["--replot", "/no/such.csv"],
                 ["--frobnicate"], ["--peers", "fortran77"]):
        with pytest.raises(SystemExit) as exc:
            bench_main(argv)
        assert exc.value.code == 2


def _rows(*triples):
    return [{"status": "ok", "error_m": e, "us_per_sim_s": c, "label": lab, "method": "m",
             "kind": "adaptive", "rtol": 1.0, "dt": math.nan, "max_step": math.nan,
             "batch_us_per_ball_sim_s": math.nan} for e, c, lab in triples]


def test_cheapest_and_interpolated_cost():
    rows = _rows((1e-6, 10.0, "a"), (1e-8, 20.0, "b"), (1e-10, 40.0, "c"), (1e-12, 15.0, "d"))
    assert cheapest_meeting(rows, 1e-9)["label"] == "d"
    assert cheapest_meeting(rows, 1e-13) is None
    rows = _rows((1e-6, 10.0, "a"), (1e-10, 100.0, "b"))
    assert interpolated_cost(rows, 1e-8) == pytest.approx(math.sqrt(10.0 * 100.0))
    assert summarize([])["model_error_vs_rolling"] == {}


# ----------------------------------------------------------------------------------------
# Automatic accuracy
# ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def bench_case():
    sc = Scene()
    s0 = initial_state(sc, 0.005, 0.0025, start="lab-rest", omega=20.0)
    ref = simulate(sc, s0, 5.0, omega=20.0, dt_out=0.1, rtol=1e-13)
    return sc, s0, ref


@pytest.mark.parametrize("tol", [1e-3, 1e-6, 1e-9])
@pytest.mark.parametrize("events", [("detach", "escape"), ()])
def test_tol_is_met_and_the_pick_is_named(bench_case, tol, events):
    sc, s0, ref = bench_case
    tr = simulate(sc, s0, 5.0, omega=20.0, dt_out=0.1, tol=tol, events=events)
    err = np.max(np.hypot(tr.x - ref.x, tr.y - ref.y))
    assert err <= tol, (err, tr.settings)
    assert tr.settings.startswith(f"auto (tol = {tol:g} m): picked ")


def test_looser_tol_is_cheaper(bench_case):
    sc, s0, _ = bench_case
    evals = [simulate(sc, s0, 5.0, omega=20.0, tol=tol).stats.rhs_evaluations
             for tol in (1e-3, 1e-6, 1e-10)]
    assert evals[0] < evals[1] < evals[2]


def test_tol_exclusive_and_range():
    sc = Scene()
    s0 = initial_state(sc, 0.005, 0.0)
    for kw in ({"method": "rk4"}, {"rtol": 1e-8}, {"dt": 1e-3}, {"max_step": 0.01},
               {"atol": 1e-8}):
        with pytest.raises(ValueError, match="tol"):
            simulate(sc, s0, 1.0, tol=1e-6, **kw)
    for bad in (0.0, -1.0, 1e-13, 10.0, math.nan, math.inf, "1e-6", None if False else [1e-6]):
        with pytest.raises(ValueError, match="tol"):
            check_tol(bad)


def test_batch_tol_and_choose_directly():
    sc = Scene()
    states = np.array([initial_state(sc, 0.004 + 0.001 * k, 0.002, start="lab-rest",
                                     omega=20.0) for k in range(6)])
    res = simulate_batch(sc, states, 2.0, omega=20.0, tol=1e-7)
    assert res.settings.startswith("auto (tol = 1e-07 m)")
    for i in range(len(states)):
        ref = simulate(sc, states[i], 2.0, omega=20.0, rtol=1e-13)
        assert np.max(np.abs(res.state[i, :, :2] - ref.state[:, :2])) <= 1e-7
    pick = choose(sc, [states[0]], 2.0, 1e-7, omegas=[OmegaProfile(20.0)])
    assert pick.kwargs()["method"] in ("rk4", "dopri5", "dop853")
    assert pick.predicted_error <= 1e-7


def test_a_choice_runs_as_is_on_the_output_grid_it_was_chosen_for():
    """choose() may prefer a fixed step longer than the output spacing (rk4 at a loose tol);
    the run lands on every output, so the choice reports the step it really takes and its
    kwargs() pass straight to simulate on that grid (a larger dt would be a ValueError)."""
    sc = Scene()
    s0 = initial_state(sc, 0.005, 0.0025, start="lab-rest", omega=20.0)
    for dt_out in (0.01, 0.003):
        pick = choose(sc, [s0], 2.0, 1e-3, omegas=[OmegaProfile(20.0)], dt_out=dt_out)
        if pick.dt is not None:
            assert pick.dt <= dt_out
        tr = simulate(sc, s0, 2.0, omega=20.0, dt_out=dt_out, **pick.kwargs())
        assert tr.t[-1] == pytest.approx(2.0)


def test_too_large_fixed_step_is_reported():
    sc = Scene()
    s0 = initial_state(sc, 0.005, 0.0025, start="lab-rest", omega=20.0)
    with pytest.warns(AccuracyWarning, match="Jacobi integral"):
        tr = simulate(sc, s0, 5.0, omega=20.0, method="rk4", dt=0.02, dt_out=0.1)
    with pytest.warns(AccuracyWarning, match="far too large"):
        simulate(sc, s0, 5.0, omega=20.0, method="dop853", dt=0.2, dt_out=None)
    # and a sensible fixed step is not flagged
    with warnings.catch_warnings():
        warnings.simplefilter("error", AccuracyWarning)
        fine = simulate(sc, s0, 5.0, omega=20.0, method="rk4", dt=0.001)
    assert jacobi_drift(fine) < 1e-8
    est = assess(tr, method="rk4", dt=0.02)
    assert est["error_estimate_m"] > 1e-5 and est["jacobi_drift"] > 1e-5


def test_blas_threads_are_one_within_the_block_and_the_callers_after():
    """The fit pins BLAS to one thread while it runs (a threaded OpenBLAS waking its workers
    on a busy machine made its SVDs 40x slower) and gives a program that called it its own
    thread count back."""
    from saddle_env.jobs.blas import _thread_controls, blas_threads

    def counts():
        return [int(get()) for _, _, get in _thread_controls() if get is not None]

    with blas_threads(2):
        before = counts()              # a caller's own setting, whatever the machine's
        if not before:
            pytest.skip("no OpenBLAS loaded: nothing to pin")
        with blas_threads(1) as changed:
            assert len(changed) == len(before) and counts() == [1] * len(before)
        assert counts() == before
