"""saddle-reproduce: the --quick run's files and numbers, the cache, interruption, flags, and
the paper's approximate equation (saddle_env.reproduce.paper_eom) against the exact kernels."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from saddle_env import Scene, initial_state, simulate
from saddle_env import kernels as K
from saddle_env.reproduce import FIGURE_NAMES, main, paper_eom
from saddle_env.reproduce import cli as reproduce_cli
from saddle_env.reproduce.precession import orientation_series, precession_angle

PNGS = {name: name for name in FIGURE_NAMES}
CSV_COLUMNS = {
    "eigen": ["omega", "re1", "im1", "re2", "im2", "re3", "im3", "re4", "im4"],
    "critical_nonlinear": ["R", "a", "inv_a_minus_2R", "omega_crt_theory", "omega_crt_rolling",
                           "omega_crt_slipping", "paper_ball"],
    "critical_curves": ["R", "a", "omega_crt_rigid", "omega_crt_point"],
    "trajectories_rolling": ["t", "x_lab", "y_lab", "x", "y", "r_nonlinear", "r_linear",
                             "r_nonlinear_rotating_rest", "r_linear_rotating_rest"],
    "trajectories_point": ["t", "x_lab", "y_lab"],
    "precession_series": ["t", "angle_deg", "formula_deg", "linear_deg"],
    "precession_convergence": ["release_m", "angle_deg", "excess_over_linear_deg",
                               "linear_limit_deg", "formula_deg"],
    "support": ["t", "N_exact_rotating_rest_20", "N_paper_eom_rotating_rest_20",
                "N_exact_lab_rest_20", "N_paper_eom_lab_rest_20", "N_exact_rotating_rest_30",
                "N_paper_eom_rotating_rest_30", "N_exact_lab_rest_30",
                "N_paper_eom_lab_rest_30"],
    "feasible": ["x", "y", "omega", "convention", "event", "t_event"],
    "feasible_paper": ["x", "y", "omega", "feasible_exact", "feasible_paper_eom"],
    "trapping": ["R", "convention", "omega", "median_t", "q25_t", "q75_t", "fraction_kept",
                 "fraction_detached"],
    "asymmetric": ["model", "R", "b_over_a", "omega_low", "omega_high"],
    "asymmetric_nonlinear": ["case", "omega", "stable_nonlinear"],
    "analogy": ["omega", "growth_mass_point", "growth_rolling_R3cm", "growth_rrf_ion",
                "growth_paul", "paul_floquet_abs_mu"],
    "analogy_orbits": ["t", "ball_xc", "ball_yc", "best_ion_x", "best_ion_y", "paper_ion_x",
                       "paper_ion_y", "mass_point_linear_x", "mass_point_linear_y",
                       "mass_point_ion_x", "mass_point_ion_y"],
    "damping": ["panel", "k1", "omega", "growth_theory", "growth_simulated"],
    "damping_bands": ["panel", "k1", "omega_low", "omega_high"],
    "lifetimes": ["series", "rps", "lab_mean_s", "lab_std_s", "calibrated_s", "rigid_s"],
}


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper_figures")
    assert main(["--quick", "--out", str(out), "--no-progress"]) == 0
    return out


def _read_csv(path):
    with open(path, newline="") as fh:
        rows = [r for r in csv.reader(line for line in fh if not line.startswith("#"))]
    return rows[0], rows[1:]


def test_every_figure_has_a_non_blank_png(quick_run):
    from PIL import Image

    for name in PNGS:
        path = quick_run / f"{name}.png"
        assert path.exists(), name
        img = np.asarray(Image.open(path).convert("L"), dtype=float)
        assert img.shape[0] > 300 and img.shape[1] > 800
        # not blank: a real plot has dark ink on a light background over many pixels
        assert img.std() > 10 and np.mean(img < 128) > 0.005, name
        assert path.stat().st_size < 150_000, name


def test_csv_columns_and_values(quick_run):
    for name, cols in CSV_COLUMNS.items():
        header, rows = _read_csv(quick_run / f"{name}.csv")
        assert header == cols, name
        assert len(rows) > 2, name
        assert all(len(r) == len(cols) for r in rows), name
    header, rows = _read_csv(quick_run / "feasible.csv")
    events = {r[header.index("event")] for r in rows}
    assert events <= {"none", "detach", "escape"} and {"none", "detach"} <= events


def test_summary_numbers(quick_run):
    s = json.loads((quick_run / "summary.json").read_text())
    for key in ("omega_crt", "precession_deg_1mm", "precession_deg_formula",
                "t_first_N_negative_omega30", "feasible_fraction_35", "feasible_fraction_45"):
        assert key in s, key
    # every number carries its initial-velocity convention
    for key, entry in s.items():
        if not key.startswith("_"):
            assert "convention" in entry or all("convention" in v for v in entry.values()), key
    crt = s["omega_crt"]
    assert crt["R=3.00cm"]["theory"] == pytest.approx(14.0705, abs=1e-3)
    for ball in ("R=2.23cm", "R=2.65cm", "R=3.30cm"):
        e = crt[ball]
        assert e["convention"] == "lab-rest"
        assert e["theory"] == pytest.approx(math.sqrt(2 * 9.8 / (0.159 - 2 * e["R_m"])))
        for k in ("nonlinear_rolling", "nonlinear_slipping"):
            assert 0.995 * e["theory"] < e[k] <= e["theory"] * 1.001
    assert crt["mass_point"]["theory"] == pytest.approx(11.1027, abs=1e-3)
    assert s["precession_deg_formula"]["value"] == pytest.approx(135.03, abs=0.01)
    assert s["precession_deg_1mm"]["convention"] == "lab-rest"
    assert 140 < s["precession_deg_1mm"]["value"] < 160
    assert s["precession_deg_1mm"]["value"] > s["precession_deg_linear_limit"]["value"] \
        > s["precession_deg_formula"]["value"]
    t_det = s["t_first_N_negative_omega30"]
    assert t_det["convention"] == "rotating-rest"
    assert t_det["value"] == pytest.approx(0.241025, abs=1e-5)
    assert t_det["lab_rest_value"] is None
    assert s["min_N_over_mg_omega20"]["value"] > 0.5
    f35, f45 = s["feasible_fraction_35"], s["feasible_fraction_45"]
    assert f35["convention"] == f45["convention"] == "rotating-rest"
    assert 0 < f45["value"] < f35["value"] < 0.1
    assert 0 < s["feasible_fraction_45_lab_rest"]["value"] < s["feasible_fraction_35_lab_rest"]["value"]
    an = s["analogy"]
    assert an["masspoint_rrf_max_rel_diff"] < 1e-8
    assert an["rolling_eigenfrequency_mismatch"] > 0.05
    assert an["paul_threshold"] == pytest.approx(1.4841 * an["omega_crt_mass_point"], rel=1e-4)


def test_reruns_read_the_cache_and_rewrite_the_figure(quick_run):
    caches = sorted((quick_run / "cache").glob("feasible-*.npz"))
    assert caches
    stamps = [p.stat().st_mtime_ns for p in caches]
    png = quick_run / "feasible.png"
    png_stamp = png.stat().st_mtime_ns
    assert main(["--quick", "--out", str(quick_run), "--only", "feasible", "--no-progress"]) == 0
    assert [p.stat().st_mtime_ns for p in caches] == stamps
    assert png.stat().st_mtime_ns > png_stamp
    # --only keeps the other figures' numbers in summary.json
    s = json.loads((quick_run / "summary.json").read_text())
    assert "precession_deg_1mm" in s and "feasible_fraction_35" in s


def test_interruption_keeps_finished_figures(tmp_path, monkeypatch):
    def finished(ctx):
        ctx.write_csv("first", {"a": [1, 2, 3]})

    def interrupted(ctx):
        raise KeyboardInterrupt

    monkeypatch.setattr(reproduce_cli, "_figures",
                        lambda: {"trajectories": (finished, ""), "eigen": (interrupted, "")})
    assert main(["--out", str(tmp_path), "--only", "trajectories,eigen", "--no-progress"]) == 130
    assert (tmp_path / "first.csv").exists()
    assert not list(tmp_path.glob(".*tmp"))


@pytest.mark.parametrize("argv", [["--only", "nonsense"], ["--only", ""], ["--frobnicate"],
                                  ["--out", __file__]])
def test_bad_flags_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert "error" in capsys.readouterr().err


def test_importing_the_package_does_not_import_matplotlib():
    code = ("import sys, saddle_env, saddle_env.reproduce; "
            "assert 'matplotlib' not in sys.modules and 'tqdm' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)


# ------------------------------------------------------------------------------------------
# The paper's approximate equation
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("b", [None, 0.12])
def test_paper_eom_with_the_dropped_term_restored_is_the_exact_model(b):
    # The torque balance about the contact point plus r_o' x r_c' is derived independently of
    # the kernels' Newton-Euler form; the two must agree to rounding.
    rng = np.random.default_rng(3)
    sc = Scene(R=0.03, b=b)
    prof = np.zeros(K.DRIVE_WIDTH)
    prof[0] = 25.0
    for _ in range(5):
        y = np.r_[rng.uniform(-0.05, 0.05, 2), rng.normal(size=3) * 5]
        dy = np.zeros(K.STATE_WIDTH)
        N = K.rhs(sc.model_code, sc.params(), prof, 0.0, y, dy, True)
        dy = dy[: sc.state_size]  # the dynamics, without the work slot
        np.testing.assert_allclose(paper_eom.rhs(sc, 25.0, y, keep_transport=True), dy,
                                   rtol=1e-11, atol=1e-11)
        assert paper_eom.normal_force(sc, 25.0, y, True) == pytest.approx(N / 9.8, rel=1e-11)
        # the paper's form adds exactly (n'·w) n / alpha to the spin rate
        kin = paper_eom._kinematics(sc, y)
        extra = np.array(kin["n"]) * paper_eom._dot(kin["ndot"], kin["w"]) / sc.alpha
        np.testing.assert_allclose(paper_eom.rhs(sc, 25.0, y)[2:], dy[2:] + extra,
                                   rtol=1e-10, atol=1e-10)


def test_paper_eom_runs_and_feasibility_match_the_exact_model_when_restored():
    sc = Scene(R=0.033)
    s0 = initial_state(sc, 0.005, 0.005)
    exact = simulate(sc, s0, 0.5, omega=30.0, dt_out=None).event
    restored = paper_eom.simulate_paper(sc, s0, 0.5, 30.0, keep_transport=True)
    assert restored.t_detach == pytest.approx(exact.t, abs=1e-8)
    assert np.ptp(restored.h) < 1e-7           # the exact model conserves the Jacobi integral
    paper = paper_eom.simulate_paper(sc, s0, 0.5, 30.0)
    assert 1e-5 < abs(paper.t_detach - exact.t) < 1e-2
    assert np.ptp(paper.h) > 1e-4              # the paper's equation does not
    xs = np.array([-0.004, 0.0, 0.004, 0.008])
    S = np.array([initial_state(sc, x, 0.001) for x in xs])
    ok, _ = paper_eom.feasible_paper(sc, S, 35.0, 0.5, keep_transport=True)
    from saddle_env import simulate_batch
    assert np.array_equal(ok, simulate_batch(sc, S, 0.5, omega=35.0, dt_out=None).status == 0)


def test_paper_eom_rejects_slipping_balls():
    with pytest.raises(ValueError, match="rolling"):
        paper_eom.rhs(Scene(contact="slipping"), 20.0, np.zeros(5))


def test_orientation_series_is_the_precession_measurement():
    sc = Scene(contact="point")
    tr = simulate(sc, initial_state(sc, 5e-4, 5e-4, start="lab-rest", omega=30.0), 12.0,
                  omega=30.0, dt_out=0.002)
    t, ang = orientation_series(tr)
    slope = np.polyfit(t, ang, 1)[0]
    assert slope * 12.0 == pytest.approx(precession_angle(tr), rel=1e-12)
