"""Figures from the nonlinear model.

* ``trajectories``: the paper's Fig. traj — rolling and slipping orbits, the precession of
  the mass point's orbit and its convergence to the small-amplitude formula, nonlinear vs
  linearised r(t);
* ``support``: its Fig. support — normal force vs time at Ω = 20 and 30 s⁻¹, with the paper's
  own approximate equation (`paper_eom`) alongside;
* ``feasible``: its Fig. feasible — starting points that never detach, Ω = 35 and 45 s⁻¹;
* ``trapping``: its Fig. result(a–c) — simulated trapping time vs Ω for its three balls.

Which initial-velocity convention each claim needs is part of every CSV header and of
``summary.json``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import kernels as K
from ..linear import critical_omega, eigenfrequencies, linear_trajectory
from ..runner import Start
from ..scene import P_A, P_B, P_R, Scene
from ..simulate import Trajectory, initial_state, simulate
from . import paper_eom
from .context import Context
from .precession import linear_precession_rate, orientation_series, precession_angle
from .theory_figs import A_PAPER, PAPER_BALLS

G = 9.8
CONVENTIONS: tuple[Start, ...] = ("rotating-rest", "lab-rest")
CONVENTION_TEXT = {"rotating-rest": "at rest on the saddle (rotating-rest)",
                   "lab-rest": "placed at rest in the laboratory (lab-rest)"}


def _centre_state(scene: Scene, state: np.ndarray) -> np.ndarray:
    """(c_x, c_y, ċ_x, ċ_y) of a state, from the shared kernels (for the linear solution)."""
    y = np.zeros(K.STATE_WIDTH)
    y[: len(state)] = state
    p = scene.params()
    geo = K.geometry(p[P_A], p[P_B], p[P_R], y[0], y[1])
    vx, vy = K.contact_velocity(scene.model_code, p, y)
    return np.array([geo.cx, geo.cy, geo.J1x * vx + geo.J2x * vy, geo.J1y * vx + geo.J2y * vy])


def _linear_contact_r(scene: Scene, omega: float, tr: Trajectory) -> np.ndarray:
    """r_o(t) of the linearised solution started from the same state (centre → contact by
    the linear map x_o = x_c/(1 − 2R/a), y_o = y_c/(1 + 2R/b))."""
    lin = linear_trajectory(scene, omega, _centre_state(scene, tr.state[0]), tr.t)
    R = scene.radius
    assert scene.b is not None  # Scene.__post_init__ sets b (None means b = a)
    return np.hypot(lin[:, 0] / (1 - 2 * R / scene.a), lin[:, 1] / (1 + 2 * R / scene.b))


# ------------------------------------------------------------------------------------------
# Trajectories and precession
# ------------------------------------------------------------------------------------------

def _r_against_linear(ax, tr, r_lin, t_show, labels, title):
    """One panel: r(t) of the exact model against the linearised model, first t_show s."""
    show = tr.t <= t_show
    ax.plot(tr.t[show], 1e3 * tr.r[show], lw=0.8, label=labels[0])
    ax.plot(tr.t[show], 1e3 * r_lin[show], lw=0.8, ls="--", label=labels[1])
    ax.set(xlabel="t [s]", ylabel="r_o [mm]", xlim=(0, t_show), title=title)
    ax.legend(fontsize=7, loc="upper right")


W_TRAJ = 30.0   # [1/s] the paper's Fig. traj speed
D0 = 0.001      # [m] contact point released at x = y = D0
T_PREC = 33.5   # [s] the paper's precession run
T_ROLL = 10.0   # [s] the rolling runs
T_SHOW = 3.0    # [s] r(t) panels show the first seconds (the gap is measured over T_ROLL)


@dataclass(frozen=True)
class _RollingRuns:
    """The rolling ball (R = 2 cm) from both starts, each with its linearised r(t)."""

    lab_rest: Trajectory
    rotating_rest: Trajectory
    r_lin: np.ndarray
    r_lin_rr: np.ndarray
    gap: float       # max |r - r_lin| / max r, lab-rest
    gap_rr: float    # the same, rotating-rest


@dataclass(frozen=True)
class _Precession:
    """The mass point's precession from several releases, against the linear limit."""

    releases: tuple[float, ...]
    runs: dict[float, Trajectory]
    angles: np.ndarray        # [deg] in T_PREC, per release
    limit: float              # [deg] the linear small-amplitude limit
    rate_formula: float       # [rad/s] g²/(2a²Ω³)
    formula: float            # [deg] rate_formula · T_PREC
    excess: np.ndarray        # [deg] angles − limit
    power: float              # excess ∝ release^power
    rotating_rest: Trajectory  # the same mass point at rest on the saddle

    @property
    def rel(self) -> np.ndarray:
        return np.array(self.releases)

    @property
    def ok(self) -> np.ndarray:
        """Releases with a positive excess (plotted and fitted on a log scale)."""
        return self.excess > 0

    @property
    def at_d0(self) -> Trajectory:
        return self.runs[D0]


def _rolling_runs(roll: Scene) -> _RollingRuns:
    tr_roll = simulate(roll, initial_state(roll, D0, D0, start="lab-rest", omega=W_TRAJ), T_ROLL,
                       omega=W_TRAJ, dt_out=0.002, rtol=1e-12)
    tr_roll_rr = simulate(roll, initial_state(roll, D0, D0, start="rotating-rest"), T_ROLL,
                          omega=W_TRAJ, dt_out=0.002, rtol=1e-12)
    r_lin = _linear_contact_r(roll, W_TRAJ, tr_roll)
    r_lin_rr = _linear_contact_r(roll, W_TRAJ, tr_roll_rr)
    gap = float(np.max(np.abs(tr_roll.r - r_lin)) / tr_roll.r.max())
    gap_rr = float(np.max(np.abs(tr_roll_rr.r - r_lin_rr)) / tr_roll_rr.r.max())
    return _RollingRuns(tr_roll, tr_roll_rr, r_lin, r_lin_rr, gap, gap_rr)


def _precession(ctx: Context, point: Scene) -> _Precession:
    releases = (1e-3, 5e-4, 2.5e-4) if ctx.quick else (1e-3, 7.07e-4, 5e-4, 3.54e-4, 2.5e-4,
                                                      1.25e-4, 6.25e-5)
    runs = {}
    for d in releases:
        tr = simulate(point, initial_state(point, d, d, start="lab-rest", omega=W_TRAJ), T_PREC,
                      omega=W_TRAJ, dt_out=0.002)
        if tr.event is not None:
            raise RuntimeError(f"the mass point released at {d} m was lost: {tr.event}")
        runs[d] = tr
    angles = np.array([math.degrees(precession_angle(runs[d])) for d in releases])
    limit = math.degrees(linear_precession_rate(runs[D0]) * T_PREC)
    rate_formula = G**2 / (2 * A_PAPER**2 * W_TRAJ**3)
    excess = angles - limit
    rel = np.array(releases)
    ok = excess > 0
    power = float(np.polyfit(np.log(rel[ok]), np.log(excess[ok]), 1)[0]) if ok.sum() >= 2 \
        else math.nan
    rotating_rest = simulate(point, initial_state(point, D0, D0, start="rotating-rest"), T_PREC,
                             omega=W_TRAJ, dt_out=0.01)
    return _Precession(releases, runs, angles, limit, rate_formula,
                       math.degrees(rate_formula * T_PREC), excess, power, rotating_rest)


def _write_trajectory_csvs(ctx: Context, rr: _RollingRuns, pr: _Precession) -> None:
    tr_roll, tr_pt = rr.lab_rest, pr.at_d0
    xy_roll = tr_roll.lab_xy()
    ctx.write_csv("trajectories_rolling", {
        "t": tr_roll.t, "x_lab": xy_roll[:, 0], "y_lab": xy_roll[:, 1], "x": tr_roll.x,
        "y": tr_roll.y, "r_nonlinear": tr_roll.r, "r_linear": rr.r_lin,
        "r_nonlinear_rotating_rest": rr.rotating_rest.r, "r_linear_rotating_rest": rr.r_lin_rr},
        [("Rolling ball R = 0.02 m, a = 0.159 m, Omega = 30 1/s, contact point released at "
         "x = y = 1 mm; columns without suffix: lab-rest; *_rotating_rest: at rest on the saddle"),
         ("x, y: rotating frame; x_lab, y_lab: laboratory; r_linear: the linearised equations "
         "(Table I) from the same initial state [m]")])
    xy_pt = tr_pt.lab_xy()
    tc, ang = orientation_series(tr_pt)
    ctx.write_csv("trajectories_point", {"t": tr_pt.t, "x_lab": xy_pt[:, 0],
                                         "y_lab": xy_pt[:, 1]},
                  [("Mass point (slipping, R -> 0), a = 0.159 m, Omega = 30 1/s, released at "
                   "x = y = 1 mm, placed at rest in the laboratory (lab-rest); lab frame [m]")])
    ctx.write_csv("precession_series", {
        "t": tc, "angle_deg": np.degrees(ang - ang[0]),
        "formula_deg": np.degrees(pr.rate_formula * (tc - tc[0])),
        "linear_deg": np.degrees(linear_precession_rate(tr_pt) * (tc - tc[0]))},
        [("Orientation of the mass point's secular ellipse (lab frame), relative to the first "
         "window; formula: g^2/(2 a^2 Omega^3) t; linear: Omega - (w+ + w-)/2 (linear theory)")])
    rel = pr.rel
    ctx.write_csv("precession_convergence", {
        "release_m": rel, "angle_deg": pr.angles, "excess_over_linear_deg": pr.excess,
        "linear_limit_deg": np.full(len(rel), pr.limit),
        "formula_deg": np.full(len(rel), pr.formula)},
        [(f"Precession angle in {T_PREC} s of the mass point at Omega = {W_TRAJ}, released at "
         "x = y = release_m, lab-rest; measured by saddle_env.reproduce.precession.precession_angle"),
         f"excess ~ release^{pr.power:.2f}"])


def _plot_orbits(ax: Any, point: Scene, rr: _RollingRuns, pr: _Precession) -> None:
    """(a) the rolling ball's and (b) the mass point's orbit in the laboratory."""
    xy_roll, tr_pt = rr.lab_rest.lab_xy(), pr.at_d0
    xy_pt = tr_pt.lab_xy()
    a_ = ax[0]
    a_.plot(1e3 * xy_roll[:, 0], 1e3 * xy_roll[:, 1], lw=0.4, color="C0")
    a_.plot(1e3 * xy_roll[0, 0], 1e3 * xy_roll[0, 1], "ko", ms=3)
    a_.set(aspect="equal", xlabel="x_lab [mm]", ylabel="y_lab [mm]",
           title=f"(a) rolling, R = 2 cm, {T_ROLL:g} s (lab frame)")
    a_ = ax[1]
    a_.plot(1e3 * xy_pt[:, 0], 1e3 * xy_pt[:, 1], lw=0.25, color="C1")
    pos = np.sort(eigenfrequencies(point, W_TRAJ).real)[2:]
    first = tr_pt.t <= 2 * math.pi / (0.5 * (pos[1] - pos[0]))
    a_.plot(1e3 * xy_pt[first, 0], 1e3 * xy_pt[first, 1], lw=1.2, color="k",
            label="first secular period")
    a_.set(aspect="equal", xlabel="x_lab [mm]", ylabel="y_lab [mm]",
           title=f"(b) slipping, R → 0 (mass point), {T_PREC:g} s")
    a_.legend(fontsize=7, loc="upper right")


def _plot_precession(ax: Any, pr: _Precession) -> None:
    """(d) the orbit's orientation over time and (e) its convergence to the linear limit."""
    from matplotlib.ticker import NullLocator

    tc, _ = orientation_series(pr.at_d0)
    a_ = ax[0]
    for d in pr.releases[:: max(1, len(pr.releases) // 4)]:
        t_d, a_d = orientation_series(pr.runs[d])
        a_.plot(t_d, np.degrees(a_d - a_d[0]), lw=1, label=f"measured, release {d * 1e3:.3g} mm")
    a_.plot(tc, np.degrees(pr.rate_formula * (tc - tc[0])), "k--", lw=1,
            label="g²/(2a²Ω³)·t (paper)")
    a_.set(xlabel="t [s]", ylabel="precession angle [deg]",
           title="(d) orientation of the mass point's orbit (lab)")
    a_.legend(fontsize=7)
    a_ = ax[1]
    rel, ok, excess, limit, formula = pr.rel, pr.ok, pr.excess, pr.limit, pr.formula
    a_.loglog(1e3 * rel[ok], excess[ok], "o-", label="measured − linear limit")
    a_.loglog(1e3 * rel, excess[0] * (rel / rel[0]) ** 2, "k:", lw=1, label="∝ release²")
    a_.axhline(limit - formula, color="C3", ls="--", lw=1,
               label=f"linear limit − formula = {limit - formula:.2f}°")
    a_.xaxis.set_minor_locator(NullLocator())
    a_.set_xticks(1e3 * rel[ok], [f"{1e3 * v:.3g}" for v in rel[ok]], fontsize=7)
    a_.set(xlabel="release x = y [mm]", ylabel="excess angle in 33.5 s [deg]",
           title=f"(e) {pr.angles[0]:.1f}° at 1 mm → {limit:.2f}° (formula {formula:.2f}°)")
    a_.legend(fontsize=7)


def _trajectory_summary(rr: _RollingRuns, pr: _Precession) -> dict[str, Any]:
    tr_pt_rr = pr.rotating_rest
    return {
        "precession_deg_1mm": {
            "value": float(pr.angles[0]), "unit": "deg", "convention": "lab-rest",
            "note": "mass point, a = 0.159 m, Omega = 30, released at x = y = 0.1 cm placed at "
                    "rest in the laboratory, precession of the lab-frame orbit in 33.5 s "
                    "(saddle_env.reproduce.precession.precession_angle)"},
        "precession_deg_formula": {
            "value": pr.formula, "unit": "deg", "convention": "none (small-amplitude formula)",
            "note": "g^2/(2 a^2 Omega^3) * 33.5 s, the paper's 135.03 deg"},
        "precession_deg_linear_limit": {
            "value": pr.limit, "unit": "deg", "convention": "none (linear theory)",
            "note": "(Omega - (w+ + w-)/2) * 33.5 s, the exact small-amplitude limit; the "
                    "formula is its leading term"},
        "precession_convergence": {
            "release_m": pr.rel, "angle_deg": pr.angles, "excess_power_law": pr.power,
            "convention": "lab-rest",
            "note": "the excess over the linear limit shrinks as release^power (2 = quadratic)"},
        "precession_rotating_rest_1mm": {
            "value": None if tr_pt_rr.event is None else tr_pt_rr.event.t, "unit": "s",
            "event": None if tr_pt_rr.event is None else tr_pt_rr.event.kind,
            "convention": "rotating-rest",
            "note": "the same mass point at rest on the saddle: time it leaves the 10 cm rim "
                    "(null: kept), so the paper's regular 33.5 s precession is lab-rest"},
        "nonlinear_vs_linear_gap": {
            "lab_rest": rr.gap, "rotating_rest": rr.gap_rr, "convention": "both, as named",
            "note": "rolling R = 2 cm at Omega = 30 from x = y = 1 mm over 10 s: max |r_nonlinear "
                    "- r_linear| / max r_nonlinear (paper Fig. traj(c))"}}


def fig_trajectories(ctx: Context) -> None:
    """Rolling (R = 2 cm) and slipping (R → 0) orbits at Ω = 30 from x = y = 0.1 cm; the
    precession angle vs g²/(2a²Ω³)·t and its convergence; nonlinear vs linearised r(t)."""
    import matplotlib.pyplot as plt

    roll = Scene(a=A_PAPER, R=0.02, contact="rolling")
    point = Scene(a=A_PAPER, contact="point")
    rr = _rolling_runs(roll)
    pr = _precession(ctx, point)
    _write_trajectory_csvs(ctx, rr, pr)

    fig, ax = plt.subplots(2, 3, figsize=(14, 8.4))
    _plot_orbits(ax[0, :2], point, rr, pr)
    _r_against_linear(ax[0, 2], rr.lab_rest, rr.r_lin, T_SHOW,
                      ("nonlinear (exact model)", "linearised (Table I)"),
                      f"(c) r(t), rolling, lab-rest; 10 s gap {100 * rr.gap:.0f} %")
    _plot_precession(ax[1, :2], pr)
    _r_against_linear(ax[1, 2], rr.rotating_rest, rr.r_lin_rr, T_SHOW, ("nonlinear", "linearised"),
                      f"(f) same, rotating-rest start; 10 s gap {100 * rr.gap_rr:.0f} %")
    fig.suptitle("Trajectories at Ω = 30 s⁻¹, a = 0.159 m, released at x = y = 0.1 cm "
                 "(paper Fig. traj); (a)–(e) placed at rest in the laboratory", fontsize=10)
    fig.tight_layout()
    ctx.save_png(fig, "trajectories")
    ctx.update_summary(_trajectory_summary(rr, pr))


# ------------------------------------------------------------------------------------------
# Support force
# ------------------------------------------------------------------------------------------
SUPPORT_OMEGAS = (20.0, 30.0)


def _support_runs(sc: Scene, T: float, dt: float) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
    """N/mg over time of the exact model and of the paper's equation, both starts, both
    speeds (the CSV's columns), and per run its first detachment and extremes."""
    cols: dict[str, np.ndarray] = {}
    t_grid = np.arange(int(np.rint(T / dt)) + 1) * dt
    cols["t"] = t_grid
    info: dict[str, dict] = {}
    for W in SUPPORT_OMEGAS:
        for conv in CONVENTIONS:
            s0 = initial_state(sc, 0.005, 0.005, start=conv, omega=W)
            # Run on through N < 0 (as the paper's figure does) until the rim; the detach
            # event of a second run gives the first N = 0 crossing to ~1e-12 s.
            tr = simulate(sc, s0, T, omega=W, dt_out=dt, events=("escape",))
            ev = simulate(sc, s0, T, omega=W, dt_out=None).event
            col = np.full(len(t_grid), np.nan)
            col[: len(tr.t)] = tr.N_over_mg
            cols[f"N_exact_{conv.replace('-', '_')}_{W:g}"] = col
            info[f"exact_{conv}_{W:g}"] = {
                "t_detach": ev.t if ev is not None and ev.kind == "detach" else None,
                "min_N": float(np.nanmin(col))}
            pr = paper_eom.simulate_paper(sc, s0, T, W, dt_out=dt)
            pcol = np.full(len(t_grid), np.nan)
            pcol[: len(pr.t)] = pr.N_over_mg
            cols[f"N_paper_eom_{conv.replace('-', '_')}_{W:g}"] = pcol
            both = np.isfinite(col) & np.isfinite(pcol)
            info[f"paper_{conv}_{W:g}"] = {"t_detach": pr.t_detach,
                                           "min_N": float(np.nanmin(pcol)),
                                           "jacobi_drift": float(np.ptp(pr.h)),
                                           "max_dN": float(np.max(np.abs(col - pcol)[both]))}
    return cols, info


def _plot_support(ax: Any, cols: dict[str, np.ndarray], info: dict[str, dict], T: float) -> None:
    """One panel per speed: N/mg of both models, the forbidden N < 0 shaded."""
    for k, W in enumerate(SUPPORT_OMEGAS):
        a_ = ax[k]
        t = cols["t"]
        a_.plot(t, cols[f"N_exact_rotating_rest_{W:g}"], color="C0" if W == 20 else "C3",
                lw=1.2, label="exact model, rotating-rest")
        a_.plot(t, cols[f"N_paper_eom_rotating_rest_{W:g}"], color="k", lw=0.8, ls="--",
                label="paper's Eq. (EOM), rotating-rest")
        a_.plot(t, cols[f"N_exact_lab_rest_{W:g}"], color="0.6", lw=0.8,
                label="exact model, lab-rest")
        a_.axhline(0, color="k", lw=0.6)
        neg = cols[f"N_exact_rotating_rest_{W:g}"] < 0
        a_.fill_between(t, 0, cols[f"N_exact_rotating_rest_{W:g}"], where=neg, color="C3",
                        alpha=0.25, label="N < 0: forbidden (detached)")
        td = info[f"exact_rotating-rest_{W:g}"]["t_detach"]
        if td is not None:
            a_.annotate(f"first N < 0: t = {td:.4f} s\n(paper's eq.: "
                        f"{info[f'paper_rotating-rest_{W:g}']['t_detach']:.4f} s)",
                        (td, 0), xytext=(td + 0.15, -1.2), fontsize=8,
                        arrowprops={"arrowstyle": "->"})
        a_.set(xlabel="t [s]", ylabel="N / mg", xlim=(0, T),
               title=f"({'ab'[k]}) Ω = {W:g} s⁻¹"
                     + (": N stays positive" if td is None else ": the ball detaches"))
        a_.legend(fontsize=7, loc="lower right" if W == 20 else "upper right")
    ax[1].set_ylim(max(-6, np.nanmin(cols["N_exact_rotating_rest_30"]) - 0.5), None)


def _support_summary(info: dict[str, dict], T: float) -> dict[str, Any]:
    e30, p30 = info["exact_rotating-rest_30"], info["paper_rotating-rest_30"]
    e20, p20 = info["exact_rotating-rest_20"], info["paper_rotating-rest_20"]
    return {
        "t_first_N_negative_omega30": {
            "value": e30["t_detach"], "unit": "s", "convention": "rotating-rest",
            "paper_eom_value": p30["t_detach"],
            "lab_rest_value": info["exact_lab-rest_30"]["t_detach"],
            "note": "rolling R = 3.3 cm from x = y = 0.5 cm at rest on the saddle; placed at rest "
                    "in the laboratory (lab_rest_value) it never detaches (min N/mg "
                    f"{info['exact_lab-rest_30']['min_N']:.3f}); paper_eom_value: the paper's "
                    "approximate equation"},
        "min_N_over_mg_omega20": {
            "value": e20["min_N"], "paper_eom_value": p20["min_N"],
            "lab_rest_value": info["exact_lab-rest_20"]["min_N"], "convention": "rotating-rest",
            "note": f"over {T:g} s: the support force stays positive at Omega = 20"},
        "paper_eom_support_force_difference": {
            "max_abs_dN_over_mg_omega20": p20["max_dN"],
            "detach_time_shift_omega30_s": (p30["t_detach"] - e30["t_detach"])
            if p30["t_detach"] is not None and e30["t_detach"] is not None else None,
            "jacobi_drift_paper_eom_omega20_J_per_kg": p20["jacobi_drift"],
            "convention": "rotating-rest",
            "note": f"paper's Eq. (EOM) minus exact model over {T:g} s (max |dN| at Omega = 30 "
                    "would compare the runs after detachment, so only the shift of the first "
                    "N = 0 crossing is given); the exact model conserves the Jacobi integral, "
                    "the paper's equation does not"},
        "paper_eom_support_force_difference_lab_rest": {
            "max_abs_dN_over_mg_omega20": info["paper_lab-rest_20"]["max_dN"],
            "max_abs_dN_over_mg_omega30": info["paper_lab-rest_30"]["max_dN"],
            "jacobi_drift_paper_eom_omega30_J_per_kg": info["paper_lab-rest_30"]["jacobi_drift"],
            "convention": "lab-rest",
            "note": f"as paper_eom_support_force_difference for the ball placed at rest in the "
                    f"laboratory (a smaller orbit; neither model detaches) over {T:g} s"}}


def fig_support(ctx: Context) -> None:
    """Normal force vs time, R = 3.3 cm, x = y = 0.5 cm, Ω = 20 and 30 s⁻¹."""
    import matplotlib.pyplot as plt

    sc = Scene(a=A_PAPER, R=0.033, contact="rolling")
    T = 1.0 if ctx.quick else 2.0
    dt = 0.001 if ctx.quick else 0.0005
    cols, info = _support_runs(sc, T, dt)
    ctx.write_csv("support", cols, [
        ("Normal force / weight, rolling ball R = 0.033 m, a = 0.159 m, contact point starting at "
        "x = y = 5 mm; columns N_<model>_<convention>_<Omega> (rotating_rest: at rest on the "
        "saddle; lab_rest: placed at rest in the laboratory)"),
        ("exact = this project's Newton-Euler model; paper_eom = the paper's Eq. (EOM) (drops "
        "r_o' x r_c'); runs continue through N < 0 as the paper's figure does; NaN after the "
        "ball leaves the 10 cm rim")])

    fig, ax = plt.subplots(1, 2, figsize=(13, 4.5))
    _plot_support(ax, cols, info, T)
    fig.suptitle("Support force, R = 3.3 cm, a = 0.159 m, starting at x = y = 0.5 cm "
                 "(paper Fig. support)", fontsize=10)
    fig.tight_layout()
    ctx.save_png(fig, "support")

    ctx.update_summary(_support_summary(info, T))


# ------------------------------------------------------------------------------------------
# Feasible regions
# ------------------------------------------------------------------------------------------
FEASIBLE_HALF = 0.03      # half-width of the square of starting points [m]


FEASIBLE_OMEGAS = (35.0, 45.0)
FEASIBLE_PAPER_HALF = 0.012   # half-width of the paper's equation's coarser square [m]


@dataclass(frozen=True)
class _FeasibleGrids:
    """The starting points: the exact model's fine square and the paper's equation's coarse
    one (rotating-rest, where the feasible region is small)."""

    n_side: int
    T: float          # [s] both maps' horizon
    X: np.ndarray
    Y: np.ndarray
    step_p: float     # [m] the coarse grid's spacing
    xp: np.ndarray
    XP: np.ndarray
    YP: np.ndarray


def _feasible_grids(quick: bool) -> _FeasibleGrids:
    n_side = 41 if quick else 121
    xs = np.linspace(-FEASIBLE_HALF, FEASIBLE_HALF, n_side)
    X, Y = np.meshgrid(xs, xs)
    step_p = 0.002 if quick else 0.001
    xp = np.arange(-FEASIBLE_PAPER_HALF, FEASIBLE_PAPER_HALF + 1e-12, step_p)
    XP, YP = np.meshgrid(xp, xp)
    return _FeasibleGrids(n_side, 3.0 if quick else 10.0, X, Y, step_p, xp, XP, YP)


def _feasible_exact(ctx: Context, sc: Scene, gr: _FeasibleGrids) -> dict[str, np.ndarray]:
    """Status and event time of every start of the fine square, both starts (cached)."""
    def compute() -> dict[str, np.ndarray]:
        out = {}
        for W in FEASIBLE_OMEGAS:
            for conv in CONVENTIONS:
                S = np.array([initial_state(sc, x, y, start=conv, omega=W)
                              for x, y in zip(gr.X.ravel(), gr.Y.ravel())])
                st, tf = ctx.run_batch(sc, S, gr.T, W, desc=f"feasible Ω={W:g} {conv}")
                out[f"status_{conv}_{W:g}"] = st
                out[f"t_{conv}_{W:g}"] = tf
        return out

    return ctx.cached("feasible", {"n": gr.n_side, "half": FEASIBLE_HALF, "T": gr.T, "R": sc.R,
                                   "omegas": FEASIBLE_OMEGAS}, compute)


def _feasible_paper(ctx: Context, sc: Scene, gr: _FeasibleGrids) -> dict[str, np.ndarray]:
    """The paper's approximate equation against the exact model on the coarse square
    (cached): plain numpy + scipy, so far slower than the compiled model."""
    def compute_paper() -> dict[str, np.ndarray]:
        out = {}
        for W in FEASIBLE_OMEGAS:
            S = np.array([initial_state(sc, x, y, start="rotating-rest")
                          for x, y in zip(gr.XP.ravel(), gr.YP.ravel())])
            # All balls advance together, so the bar shows the fraction of simulated time.
            with ctx.bar(100, f"paper's eq. Ω={W:g}", unit="%") as bar:
                done = [0]

                def tick(frac: float, bar=bar, done=done) -> None:
                    now = round(100 * frac)
                    bar.update(now - done[0])
                    done[0] = now

                ok_p, _ = paper_eom.feasible_paper(sc, S, W, gr.T, progress=tick)
            st, _ = ctx.run_batch(sc, S, gr.T, W, desc=f"exact Ω={W:g} (coarse grid)")
            out[f"paper_{W:g}"] = ok_p
            out[f"exact_{W:g}"] = st == 0
        return out

    return ctx.cached("feasible_paper", {"step": gr.step_p, "half": FEASIBLE_PAPER_HALF,
                                         "T": gr.T, "R": sc.R, "omegas": FEASIBLE_OMEGAS},
                      compute_paper)


def _feasible_areas(res: dict[str, np.ndarray]
                    ) -> tuple[dict[tuple[str, float], float], dict[tuple[str, float], float]]:
    """The feasible fraction of the fine square and its area [cm²], per (start, Ω)."""
    frac: dict[tuple[str, float], float] = {}
    area: dict[tuple[str, float], float] = {}
    for W in FEASIBLE_OMEGAS:
        for conv in CONVENTIONS:
            frac[(conv, W)] = float(np.mean(res[f"status_{conv}_{W:g}"] == 0))
            area[(conv, W)] = frac[(conv, W)] * (2 * FEASIBLE_HALF * 100) ** 2
    return frac, area


def _write_feasible_csvs(ctx: Context, gr: _FeasibleGrids, res: dict[str, np.ndarray],
                         rp: dict[str, np.ndarray]) -> None:
    long: dict[str, list] = {"x": [], "y": [], "omega": [], "convention": [], "event": [],
                             "t_event": []}
    kinds = {0: "none", 1: "detach", 2: "escape"}
    for W in FEASIBLE_OMEGAS:
        for conv in CONVENTIONS:
            st, tf = res[f"status_{conv}_{W:g}"], res[f"t_{conv}_{W:g}"]
            long["x"] += list(gr.X.ravel())
            long["y"] += list(gr.Y.ravel())
            long["omega"] += [W] * st.size
            long["convention"] += [conv] * st.size
            long["event"] += [kinds.get(int(s), f"failed{int(s)}") for s in st]
            long["t_event"] += list(np.where(st == 0, np.nan, tf))
    ctx.write_csv("feasible", long, [
        (f"Rolling ball R = 0.033 m, a = 0.159 m: contact point starting at (x, y) [m], run for "
        f"{gr.T:g} s; event: none (feasible), detach (N fell to 0) or escape (left the 10 cm rim)"),
        ("convention: rotating-rest = at rest on the saddle; lab-rest = placed at rest in the "
        "laboratory")])
    XP, omegas = gr.XP, FEASIBLE_OMEGAS
    ctx.write_csv("feasible_paper", {
        "x": np.tile(XP.ravel(), 2), "y": np.tile(gr.YP.ravel(), 2),
        "omega": np.repeat(omegas, XP.size),
        "feasible_exact": np.concatenate([rp[f"exact_{W:g}"] for W in omegas]).astype(int),
        "feasible_paper_eom": np.concatenate([rp[f"paper_{W:g}"] for W in omegas]).astype(int)},
        [(f"Rotating-rest starts on a {gr.step_p * 1e3:g} mm grid, run for {gr.T:g} s: the exact "
         "model vs the paper's approximate Eq. (EOM) (which drops r_o' x r_c')")])


def _plot_feasible_maps(ax: Any, gr: _FeasibleGrids, res: dict[str, np.ndarray],
                        area: dict[tuple[str, float], float]) -> None:
    """The exact model's map per start (rows) and speed (columns)."""
    from matplotlib.colors import ListedColormap

    ext = 100 * np.array([-FEASIBLE_HALF, FEASIBLE_HALF, -FEASIBLE_HALF, FEASIBLE_HALF])
    cmap = ListedColormap(["white", "0.15", "0.6"])  # feasible, detach, escape
    for i, conv in enumerate(CONVENTIONS):
        for j, W in enumerate(FEASIBLE_OMEGAS):
            st = res[f"status_{conv}_{W:g}"].reshape(gr.X.shape)
            a_ = ax[i, j]
            a_.imshow(np.clip(st, 0, 2), origin="lower", extent=ext, cmap=cmap, vmin=0, vmax=2,
                      interpolation="nearest")
            lim = 1.2 if conv == "rotating-rest" else 3.0
            a_.set(xlim=(-lim, lim), ylim=(-lim, lim), xlabel="x₀ [cm]", ylabel="y₀ [cm]",
                   title=f"Ω = {W:g} s⁻¹, {conv}:\nfeasible {area[(conv, W)]:.2f} cm²")
            a_.plot(0.5, 0.5, "r+", ms=8)


def _plot_feasible_vs_paper(ax: Any, gr: _FeasibleGrids, rp: dict[str, np.ndarray]) -> None:
    """The exact model against the paper's equation on the coarse square, per speed."""
    from matplotlib.colors import ListedColormap

    xp, step_p = gr.xp, gr.step_p
    for j, W in enumerate(FEASIBLE_OMEGAS):
        a_ = ax[j]
        ok_e = rp[f"exact_{W:g}"].reshape(gr.XP.shape)
        ok_p = rp[f"paper_{W:g}"].reshape(gr.XP.shape)
        code = np.where(ok_e & ok_p, 0, np.where(ok_p, 1, np.where(ok_e, 2, 3)))
        a_.imshow(code, origin="lower", cmap=ListedColormap(["white", "C1", "C0", "0.15"]),
                  vmin=0, vmax=3, extent=100 * np.array([xp[0] - step_p / 2, xp[-1] + step_p / 2,
                                                         xp[0] - step_p / 2, xp[-1] + step_p / 2]),
                  interpolation="nearest")
        cell = (step_p * 100) ** 2
        a_.set(xlabel="x₀ [cm]", ylabel="y₀ [cm]",
               title=f"Ω = {W:g} s⁻¹, rotating-rest: exact vs paper's eq.\n"
                     f"{ok_e.sum() * cell:.2f} cm² vs {ok_p.sum() * cell:.2f} cm²")
        a_.plot([], [], "s", color="w", mec="k", label=f"feasible by both ({step_p * 1e3:g} mm grid)")
        a_.plot([], [], "s", color="C1", label="feasible by the paper's eq. only")
        a_.plot([], [], "s", color="C0", label="feasible by the exact model only")
        a_.legend(fontsize=7, loc="lower left")


def _feasible_summary(gr: _FeasibleGrids, rp: dict[str, np.ndarray],
                      frac: dict[tuple[str, float], float],
                      area: dict[tuple[str, float], float]) -> dict[str, Any]:
    summary = {}
    n_side, T, step_p = gr.n_side, gr.T, gr.step_p
    for W in FEASIBLE_OMEGAS:
        summary[f"feasible_fraction_{W:g}"] = {
            "value": frac[("rotating-rest", W)], "area_cm2": area[("rotating-rest", W)],
            "convention": "rotating-rest",
            "note": f"fraction of the {2 * FEASIBLE_HALF * 100:g} cm x {2 * FEASIBLE_HALF * 100:g} "
                    f"cm square of starting points ({n_side}x{n_side} grid) from which a rolling "
                    f"R = 3.3 cm ball neither detaches nor leaves the rim in {T:g} s"}
        summary[f"feasible_fraction_{W:g}_lab_rest"] = {
            "value": frac[("lab-rest", W)], "area_cm2": area[("lab-rest", W)],
            "convention": "lab-rest", "note": "as feasible_fraction but placed at rest in the lab"}
        ok_e, ok_p = rp[f"exact_{W:g}"], rp[f"paper_{W:g}"]
        summary[f"feasible_area_paper_eom_{W:g}"] = {
            "exact_cm2": float(ok_e.sum() * (step_p * 100) ** 2),
            "paper_eom_cm2": float(ok_p.sum() * (step_p * 100) ** 2),
            "cells_differing": int(np.sum(ok_e != ok_p)), "convention": "rotating-rest",
            "note": f"{step_p * 1e3:g} mm grid over |x|, |y| <= {FEASIBLE_PAPER_HALF * 100:g} cm, "
                    f"{T:g} s: the paper's approximate equation vs the exact model"}
    return summary


def fig_feasible(ctx: Context) -> None:
    """Starting points that never detach (nor leave the rim), Ω = 35 and 45 s⁻¹, R = 3.3 cm."""
    import matplotlib.pyplot as plt

    sc = Scene(a=A_PAPER, R=0.033, contact="rolling")
    gr = _feasible_grids(ctx.quick)
    res = _feasible_exact(ctx, sc, gr)
    rp = _feasible_paper(ctx, sc, gr)
    frac, area = _feasible_areas(res)
    _write_feasible_csvs(ctx, gr, res, rp)

    fig, ax = plt.subplots(2, 3, figsize=(14, 8.6))
    _plot_feasible_maps(ax, gr, res, area)
    _plot_feasible_vs_paper(ax[:, 2], gr, rp)
    fig.suptitle("Feasible starting points (white: never detaches nor leaves the saddle), "
                 "R = 3.3 cm, a = 0.159 m (paper Fig. feasible); dark: detaches, grey: leaves "
                 "the rim; + : x = y = 0.5 cm", fontsize=10)
    fig.tight_layout()
    ctx.save_png(fig, "feasible")
    ctx.update_summary(_feasible_summary(gr, rp, frac, area))


# ------------------------------------------------------------------------------------------
# Trapping time
# ------------------------------------------------------------------------------------------
PLACEMENT_RADIUS = 0.005   # releases scattered over a disc of this radius [m]


def placements(n: int, radius: float = PLACEMENT_RADIUS) -> tuple[np.ndarray, np.ndarray]:
    """n points spread evenly over a disc (a sunflower spiral: deterministic, no RNG)."""
    k = np.arange(n) + 0.5
    r = radius * np.sqrt(k / n)
    th = k * math.pi * (3 - math.sqrt(5))
    return r * np.cos(th), r * np.sin(th)


def fig_trapping(ctx: Context) -> None:
    """Simulated trapping time vs Ω for the paper's three balls, both thresholds marked."""
    import matplotlib.pyplot as plt

    if ctx.quick:
        omegas = np.arange(8.0, 60.01, 2.0)
        n_rel, T_max = 6, 12.0
    else:
        omegas = np.unique(np.round(np.concatenate([np.arange(8.0, 18.0, 0.1),
                                                    np.arange(18.0, 60.01, 0.5)]), 6))
        n_rel, T_max = 24, 20.0
    px, py = placements(n_rel)

    def compute() -> dict[str, np.ndarray]:
        out = {}
        for R in PAPER_BALLS:
            sc = Scene(a=A_PAPER, R=R, contact="rolling")
            for conv in CONVENTIONS:
                S = np.array([initial_state(sc, x, y, start=conv, omega=W)
                              for W in omegas for x, y in zip(px, py)])
                oms = np.repeat(omegas, n_rel)
                st, tf = ctx.run_batch(sc, S, T_max, oms, desc=f"trapping R={R * 100:g}cm {conv}")
                out[f"status_{R:g}_{conv}"] = st.reshape(len(omegas), n_rel)
                out[f"t_{R:g}_{conv}"] = np.where(st == 0, T_max, tf).reshape(len(omegas), n_rel)
        return out

    res = ctx.cached("trapping", {"omegas": omegas, "n": n_rel, "T": T_max,
                                  "placement": PLACEMENT_RADIUS, "balls": PAPER_BALLS}, compute)

    long: dict[str, list] = {"R": [], "convention": [], "omega": [], "median_t": [], "q25_t": [],
                             "q75_t": [], "fraction_kept": [], "fraction_detached": []}
    thresholds: dict[str, dict] = {}
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.5), sharey=True)
    for k, R in enumerate(PAPER_BALLS):
        sc = Scene(a=A_PAPER, R=R)
        wc, wp = critical_omega(sc), math.sqrt(2 * G / A_PAPER)
        entry: dict[str, float | None] = {"theory_rigid": wc, "theory_mass_point": wp}
        for conv, col in zip(CONVENTIONS, ("C3", "C0")):
            tt, st = res[f"t_{R:g}_{conv}"], res[f"status_{R:g}_{conv}"]
            med = np.median(tt, axis=1)
            q25, q75 = np.quantile(tt, 0.25, axis=1), np.quantile(tt, 0.75, axis=1)
            long["R"] += [R] * len(omegas)
            long["convention"] += [conv] * len(omegas)
            long["omega"] += list(omegas)
            long["median_t"] += list(med)
            long["q25_t"] += list(q25)
            long["q75_t"] += list(q75)
            long["fraction_kept"] += list(np.mean(st == 0, axis=1))
            long["fraction_detached"] += list(np.mean(st == 1, axis=1))
            ax[k].plot(omegas, med, color=col, lw=1.2, label=f"median, {conv}")
            ax[k].fill_between(omegas, q25, q75, color=col, alpha=0.2, lw=0)
            entry[f"simulated_{conv}"] = _threshold(omegas, med)
            entry[f"upper_edge_{conv}"] = _upper_edge(omegas, med)
        ax[k].plot(omegas, 60 * math.pi / omegas, "k:", lw=1, label="60π/Ω (paper's criterion)")
        ax[k].axvline(wc, color="k", ls="--", lw=1, label=f"rigid-body Ω_crt = {wc:.2f}")
        ax[k].axvline(wp, color="k", ls="-.", lw=1, label=f"mass-point Ω_crt = {wp:.2f}")
        ax[k].set(yscale="log", xlabel="Ω [s⁻¹]", title=f"({'abc'[k]}) R = {100 * R:.2f} cm",
                  ylim=(0.05, T_max * 1.5))
        ax[k].legend(fontsize=6.5, loc="lower center")
        thresholds[f"R={100 * R:.2f}cm"] = {
            **entry, "unit": "1/s", "convention": "both, as named",
            "note": f"simulated: lowest Omega where the median trapping time of {n_rel} releases "
                    f"spread over a {PLACEMENT_RADIUS * 1e3:g} mm disc reaches 60 pi/Omega "
                    "(the paper's experimental criterion), interpolated on the grid; upper_edge: "
                    "lowest Omega above it where the median falls below 60 pi/Omega again "
                    f"(null: not below {omegas[-1]:g})"}
    ax[0].set_ylabel(f"trapping time [s] (capped at {T_max:g} s)")
    fig.suptitle("Simulated trapping time of rolling balls on a = 0.159 m (paper Fig. result "
                 f"(a)–(c)); {n_rel} releases within {PLACEMENT_RADIUS * 1e3:g} mm of the centre, "
                 "band: quartiles", fontsize=10)
    fig.tight_layout()
    ctx.save_png(fig, "trapping")
    ctx.write_csv("trapping", long, [
        (f"Trapping time [s] of rolling balls (a = 0.159 m) until detachment or leaving the 10 cm "
        f"rim, capped at {T_max:g} s; {n_rel} releases on a sunflower spiral over a disc of "
        f"radius {PLACEMENT_RADIUS * 1e3:g} mm; statistics over the releases")])
    ctx.update_summary({"trapping_threshold": thresholds})


def _threshold(omegas: np.ndarray, med: np.ndarray) -> float | None:
    """Lowest Ω where the median trapping time reaches 60π/Ω (log-linear interpolation)."""
    f = np.log(np.maximum(med, 1e-9)) - np.log(60 * math.pi / omegas)
    idx = np.flatnonzero((f[:-1] < 0) & (f[1:] >= 0))
    if f[0] >= 0:
        return float(omegas[0])
    if not idx.size:
        return None
    i = idx[0]
    return float(omegas[i] - f[i] * (omegas[i + 1] - omegas[i]) / (f[i + 1] - f[i]))


def _upper_edge(omegas: np.ndarray, med: np.ndarray) -> float | None:
    """Lowest Ω above the threshold where the median falls back below 60π/Ω."""
    f = np.log(np.maximum(med, 1e-9)) - np.log(60 * math.pi / omegas)
    idx = np.flatnonzero((f[:-1] >= 0) & (f[1:] < 0))
    if not idx.size:
        return None
    i = idx[0]
    return float(omegas[i] - f[i] * (omegas[i + 1] - omegas[i]) / (f[i + 1] - f[i]))
