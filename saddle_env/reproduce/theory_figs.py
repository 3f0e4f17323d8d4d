"""Figures from linear theory, each checked against the nonlinear model.

* ``eigen``: the paper's Fig. ComplexFrequency — eigen-frequency loci vs Ω, Ω_crt marked;
* ``critical``: its Fig. result(d)(e) — Ω_crt vs R and a, and Ω_crt² vs 1/(a − 2R);
* ``asymmetric``: the stable band of Ω on a saddle with a ≠ b (the paper only cites it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..linear import critical_omega, eigenfrequencies, is_stable, mass_point_band, stable_band
from ..scene import ContactModel, Scene
from ..simulate import initial_state
from .context import Context

A_PAPER = 0.159                       # saddle length of the paper's experiment [m]
PAPER_BALLS = (0.0223, 0.0265, 0.0330)  # radii of its three polyfoam balls [m]
# Nonlinear stability criterion (used for every "nonlinear Ω_crt" and stability marker):
# released 1 mm off-centre on the x axis, placed at rest in the laboratory, the ball must
# stay within LOST_RADIUS of the axis for HORIZON seconds.
RELEASE = 0.001       # [m]
LOST_RADIUS = 0.01    # [m]
HORIZON = 30.0        # [s]
CRITERION = (f"released at x = {RELEASE * 1e3:g} mm, y = 0, placed at rest in the laboratory; "
             f"stable = stays within r < {LOST_RADIUS * 1e2:g} cm for {HORIZON:g} s")


def _release_states(scenes: Sequence[Scene], omegas: np.ndarray,
                    release: float = RELEASE) -> np.ndarray:
    """Padded (n, 5) lab-rest states at (release, 0) for each scene and speed."""
    out = np.zeros((len(scenes), 5))
    for i, (sc, w) in enumerate(zip(scenes, omegas)):
        s = initial_state(sc, release, 0.0, start="lab-rest", omega=float(w))
        out[i, : len(s)] = s
    return out


def lost(ctx: Context, scenes: Sequence[Scene], omegas: np.ndarray, desc: str,
         horizon: float = HORIZON, release: float = RELEASE) -> np.ndarray:
    """Whether each ball leaves r < LOST_RADIUS within ``horizon`` (the CRITERION; the
    release distance may be changed).

    The scenes' rim is set to LOST_RADIUS so that leaving it is an escape event and the
    run stops there (no output is stored).
    """
    rimmed = [sc.with_(rim_radius=LOST_RADIUS) for sc in scenes]
    status, _ = ctx.run_batch(rimmed, _release_states(rimmed, omegas, release), horizon,
                              omegas, desc=desc)
    return status != 0


def nonlinear_threshold(ctx: Context, scenes: Sequence[Scene], iterations: int,
                        desc: str) -> np.ndarray:
    """Lowest stabilising Ω of the nonlinear model per scene, by bisection on the CRITERION.

    The bracket starts at ±10 % around linear theory's Ω_crt and is checked; all scenes are
    bisected together, one batch per iteration.
    """
    theory = np.array([critical_omega(sc) for sc in scenes])
    lo, hi = 0.9 * theory, 1.1 * theory
    if not lost(ctx, scenes, lo, f"{desc} bracket").all() or \
            lost(ctx, scenes, hi, f"{desc} bracket").any():
        raise RuntimeError("the nonlinear threshold is not within ±10 % of linear theory")
    for k in range(iterations):
        mid = 0.5 * (lo + hi)
        gone = lost(ctx, scenes, mid, f"{desc} bisection {k + 1}/{iterations}")
        lo = np.where(gone, mid, lo)
        hi = np.where(gone, hi, mid)
    return 0.5 * (lo + hi)


# ------------------------------------------------------------------------------------------
# Eigen-frequency loci
# ------------------------------------------------------------------------------------------
def fig_eigen(ctx: Context) -> None:
    """Eigen-frequency loci in the complex plane vs Ω (rolling, R = 0.03 m, a = 0.159 m)."""
    import matplotlib.pyplot as plt

    sc = Scene(a=A_PAPER, R=0.03, contact="rolling")
    omegas = np.linspace(2.0, 40.0, 60 if ctx.quick else 761)
    roots = np.array([eigenfrequencies(sc, w) for w in omegas])     # (n, 4) sorted by Re
    wc = critical_omega(sc)
    # Ω_crt as read off the loci: the lowest Ω above which no root has Im ϖ < 0 (x ∝ e^{iϖt}).
    unstable = roots.imag.min(axis=1) < -1e-9 * np.abs(roots).max(axis=1)
    above = omegas[~unstable & (omegas > omegas[np.argmax(unstable)])]
    from_loci = float(above.min()) if above.size else math.nan
    cols = {"omega": omegas}
    for j in range(4):
        cols[f"re{j + 1}"] = roots[:, j].real
        cols[f"im{j + 1}"] = roots[:, j].imag
    ctx.write_csv("eigen", cols, [
        ("Eigen-frequencies varpi [rad/s] of the linearised rolling ball (x ~ exp(i varpi t)), "
        "R = 0.03 m, a = b = 0.159 m, alpha = 0.4, spin omega_z = 0; roots sorted by real part"),
        f"Omega_crt = sqrt(2g/(a-2R)) = {wc:.6f} rad/s; Im < 0 means growth"])

    fig, ax = plt.subplots(1, 3, figsize=(13, 4.2))
    sca = None
    for j in range(4):
        sca = ax[0].scatter(roots[:, j].real, roots[:, j].imag, c=omegas, s=4, cmap="viridis")
    # Label a few speeds: on the right-hand real branch, and on the imaginary pair below Ω_crt.
    for w_lab in (5, 14, 20, 30, 40):
        i = int(np.argmin(abs(omegas - w_lab)))
        ax[0].annotate(f"{w_lab}", (roots[i, 3].real, 0), fontsize=7, xytext=(-3, 4),
                       textcoords="offset points")
    for w_lab in (2, 10, 13):
        i = int(np.argmin(abs(omegas - w_lab)))
        ax[0].annotate(f"{w_lab}", (0, abs(roots[i, 1].imag)), fontsize=7, xytext=(4, -3),
                       textcoords="offset points")
    ax[0].axhline(0, color="k", lw=0.5)
    ax[0].set(xlabel="Re ϖ [rad/s]", ylabel="Im ϖ [rad/s]",
              title="(a) loci of the four roots (labels: Ω)")
    assert sca is not None  # the loop above ran
    fig.colorbar(sca, ax=ax[0], label="Ω [s⁻¹]")
    for j in range(4):
        ax[1].plot(omegas, roots[:, j].imag, lw=1.2, label=f"root {j + 1}")
        ax[2].plot(omegas, roots[:, j].real, lw=1.2, label=f"root {j + 1}")
    for a_ in ax[1:]:
        a_.axvline(wc, color="k", ls="--", lw=0.8)
        a_.set_xlabel("Ω [s⁻¹]")
    ax[1].text(wc, ax[1].get_ylim()[0] * 0.9, f" Ω_crt = {wc:.2f}", fontsize=8)
    ax[1].set(ylabel="Im ϖ [rad/s]", title="(b) imaginary parts (< 0: unstable)")
    ax[2].set(ylabel="Re ϖ [rad/s]", title="(c) real parts")
    ax[2].legend(fontsize=7)
    fig.suptitle("Eigen-frequencies of a rolling ball, R = 3 cm, a = 0.159 m "
                 "(paper Fig. ComplexFrequency)", fontsize=10)
    fig.tight_layout()
    ctx.save_png(fig, "eigen")
    ctx.update_summary({"omega_crt_R3cm": {
        "theory": wc, "from_loci_grid": from_loci, "paper": 14.07, "unit": "1/s",
        "convention": "none (linear theory)",
        "note": "R = 0.03 m, a = 0.159 m rolling; from_loci_grid is the first grid speed "
                "with no growing root (grid spacing "
                f"{omegas[1] - omegas[0]:.3g} 1/s)"}})


# ------------------------------------------------------------------------------------------
# Ω_crt vs R and a
# ------------------------------------------------------------------------------------------
G = 9.8
CRITICAL_A_LIST = (0.12, 0.159, 0.20, 0.25)   # saddle lengths of the theory curves [m]


@dataclass(frozen=True)
class _Critical:
    """Ω_crt of the nonlinear model against theory, per radius (a = A_PAPER)."""

    iters: int
    radii: np.ndarray
    theory: np.ndarray          # sqrt(2g/(a − 2R))
    rolling: np.ndarray         # the nonlinear model's threshold, rolling
    slipping: np.ndarray        # and slipping
    point: float                # the mass point's
    point_theory: float         # sqrt(2g/a)

    @property
    def balls(self) -> np.ndarray:
        """Which radii are the paper's three balls."""
        return np.isin(self.radii, PAPER_BALLS)

    @property
    def inv_gap(self) -> np.ndarray:
        """1/(a − 2R) [1/m]."""
        return 1 / (A_PAPER - 2 * self.radii)


def _slope(x: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of a line through the origin."""
    return float(np.sum(x * y) / np.sum(x * x))


def _critical_nonlinear(ctx: Context) -> _Critical:
    """The nonlinear thresholds by bisection (cached), rolling and slipping per radius and
    the mass point."""
    iters = 10 if ctx.quick else 24
    R_sweep = np.array([0.005, 0.015, 0.03, 0.045]) if ctx.quick else \
        np.round(np.arange(0.005, 0.0651, 0.005), 4)
    radii = np.unique(np.concatenate([R_sweep, PAPER_BALLS]))

    def compute() -> dict[str, np.ndarray]:
        scenes = [Scene(a=A_PAPER, R=float(R), contact=c) for c in ("rolling", "slipping")
                  for R in radii] + [Scene(a=A_PAPER, contact="point")]
        return {"omega": nonlinear_threshold(ctx, scenes, iters, "Ω_crt")}

    res = ctx.cached("critical", {"radii": radii, "iters": iters, "criterion": CRITERION,
                                  "a": A_PAPER}, compute)
    nl = res["omega"]
    n = len(radii)
    return _Critical(iters, radii, np.sqrt(2 * G / (A_PAPER - 2 * radii)), nl[:n], nl[n:2 * n],
                     float(nl[-1]), math.sqrt(2 * G / A_PAPER))


def _write_critical_csvs(ctx: Context, cr: _Critical) -> dict[str, np.ndarray]:
    """The nonlinear thresholds and the theory curves (returned: the plotted curves)."""
    radii, n = cr.radii, len(cr.radii)
    ctx.write_csv("critical_nonlinear", {
        "R": radii, "a": np.full(n, A_PAPER), "inv_a_minus_2R": cr.inv_gap,
        "omega_crt_theory": cr.theory, "omega_crt_rolling": cr.rolling,
        "omega_crt_slipping": cr.slipping, "paper_ball": cr.balls.astype(int)},
        [("Critical speed [1/s]: theory sqrt(2g/(a-2R)) and the nonlinear model's threshold "
         f"by bisection ({cr.iters} halvings of a +-10% bracket)"),
         f"nonlinear criterion: {CRITERION}",
         f"mass point: theory {cr.point_theory:.6f}, nonlinear {cr.point:.6f}"])
    R_grid = np.linspace(0.0, 0.065, 131)
    curve = {"R": np.tile(R_grid, len(CRITICAL_A_LIST)),
             "a": np.repeat(CRITICAL_A_LIST, len(R_grid))}
    gap = curve["a"] - 2 * curve["R"]
    curve["omega_crt_rigid"] = np.where(gap > 0, np.sqrt(2 * G / np.where(gap > 0, gap, 1.0)),
                                        np.nan)
    curve["omega_crt_point"] = np.sqrt(2 * G / curve["a"])
    ctx.write_csv("critical_curves", curve,
                  [("Linear theory: Omega_crt = sqrt(2g/(a-2R)) (rigid ball, rolling or slipping) "
                   "and sqrt(2g/a) (mass point), g = 9.8")])
    return curve


def _plot_critical_vs_R(ax: Any, cr: _Critical, curve: dict[str, np.ndarray]) -> None:
    """(a) Ω_crt against R for several a, the nonlinear thresholds marked."""
    for a_, col in zip(CRITICAL_A_LIST, ("C0", "C1", "C2", "C3")):
        m = curve["a"] == a_
        ax.plot(100 * curve["R"][m], curve["omega_crt_rigid"][m], color=col,
                label=f"rigid ball, a = {a_:g} m")
        ax.axhline(math.sqrt(2 * G / a_), color=col, ls="-.", lw=0.8)
    ax.plot(100 * cr.radii, cr.rolling, "k+", ms=7, label="nonlinear, rolling (a = 0.159)")
    ax.plot(100 * cr.radii, cr.slipping, "kx", ms=5, label="nonlinear, slipping (a = 0.159)")
    ax.plot(0, cr.point, "ko", mfc="none", label="nonlinear, mass point")
    for R in PAPER_BALLS:
        ax.axvline(100 * R, color="0.7", lw=0.6, zorder=0)
    ax.set(xlabel="R [cm]", ylabel="Ω_crt [s⁻¹]", ylim=(8, 30),
           title="(a) Ω_crt vs R (dot-dashed: mass point)")
    ax.legend(fontsize=6.5, loc="upper left")


def _critical_slopes(cr: _Critical) -> dict[str, float]:
    """Slopes of Ω_crt² against 1/(a − 2R): over the paper's three balls and over all R."""
    x_all, balls = cr.inv_gap, cr.balls
    return {"rolling_all": _slope(x_all, cr.rolling**2),
            "slipping_all": _slope(x_all, cr.slipping**2),
            "rolling_balls": _slope(x_all[balls], cr.rolling[balls]**2),
            "slipping_balls": _slope(x_all[balls], cr.slipping[balls]**2)}


def _plot_critical_squared(ax: Any, cr: _Critical, slopes: dict[str, float]) -> None:
    """(b) Ω_crt² against 1/(a − 2R): slope 2g in theory."""
    x_all, balls, theory = cr.inv_gap, cr.balls, cr.theory
    # Zoom on the paper's range (its Fig. result(e)); the fits use every R of the sweep.
    xs = np.linspace(0, 13, 50)
    ax.plot(xs, 2 * G * xs, "k--", lw=1, label="theory: slope 2g = 19.6 m/s²")
    ax.axhline(2 * G / A_PAPER, color="C3", ls="-.", lw=1,
               label="mass point 2g/a (independent of R)")
    ax.plot(x_all, cr.rolling**2, "C0+", ms=8,
            label=f"nonlinear rolling (slope {slopes['rolling_balls']:.2f}; "
                  f"all R: {slopes['rolling_all']:.2f})")
    ax.plot(x_all, cr.slipping**2, "C1x", ms=6,
            label=f"nonlinear slipping (slope {slopes['slipping_balls']:.2f}; "
                  f"all R: {slopes['slipping_all']:.2f})")
    ax.plot(x_all[balls], theory[balls]**2, "ks", mfc="none", ms=10,
            label="paper's balls R = 2.23, 2.65, 3.30 cm")
    for R, xv, yv in zip(cr.radii[balls], x_all[balls], theory[balls]**2):
        ax.annotate(f"{100 * R:.2f} cm", (xv, yv), xytext=(8, -12), textcoords="offset points",
                    fontsize=7)
    ax.set(xlabel="1/(a − 2R) [m⁻¹]", ylabel="Ω_crt² [s⁻²]", xlim=(6, 12), ylim=(100, 240),
           title="(b) Ω_crt² vs 1/(a − 2R), a = 0.159 m")
    ax.legend(fontsize=6.5, loc="upper left")


def _plot_critical_map(fig: Any, ax: Any) -> None:
    """(c) Ω_crt over the (a, R) plane."""
    AA, RR = np.meshgrid(np.linspace(0.08, 0.30, 120), np.linspace(0.0, 0.038, 120))
    WW = np.where(RR < AA / 2 - 1e-3, np.sqrt(2 * G / np.maximum(AA - 2 * RR, 1e-9)), np.nan)
    cs = ax.contourf(AA, 100 * RR, WW, levels=np.arange(6, 31, 2), cmap="viridis",
                     extend="max")
    fig.colorbar(cs, ax=ax, label="Ω_crt [s⁻¹]")
    ax.plot(np.full(3, A_PAPER), 100 * np.array(PAPER_BALLS), "w^", ms=6)
    ax.set(xlabel="a [m]", ylabel="R [cm]", title="(c) Ω_crt(a, R) = sqrt(2g/(a − 2R))")


def _critical_summary(cr: _Critical, slopes: dict[str, float]) -> dict[str, Any]:
    radii = cr.radii
    per_ball = {}
    for R in (*PAPER_BALLS, 0.03):
        i = int(np.flatnonzero(np.isclose(radii, R))[0])
        per_ball[f"R={100 * R:.2f}cm"] = {
            "R_m": R, "a_m": A_PAPER, "theory": float(cr.theory[i]),
            "nonlinear_rolling": float(cr.rolling[i]), "nonlinear_slipping": float(cr.slipping[i]),
            "unit": "1/s", "convention": "lab-rest", "criterion": CRITERION,
            "note": "the paper's three balls (and its R = 3 cm example); the nonlinear "
                    "threshold is a finite-time criterion, so it lies slightly below theory "
                    "(just below Omega_crt the growth is too slow to leave 1 cm in 30 s)"}
    per_ball["mass_point"] = {"R_m": 0.0, "a_m": A_PAPER, "theory": cr.point_theory,
                              "nonlinear": cr.point, "unit": "1/s", "convention": "lab-rest",
                              "criterion": CRITERION, "note": "Brouwer's sqrt(2g/a)"}
    return {
        "omega_crt": per_ball,
        "omega_crt_squared_slope": {
            "theory": 2 * G, "nonlinear_rolling_three_balls": slopes["rolling_balls"],
            "nonlinear_slipping_three_balls": slopes["slipping_balls"],
            "nonlinear_rolling_all_R": slopes["rolling_all"],
            "nonlinear_slipping_all_R": slopes["slipping_all"], "unit": "m/s^2",
            "convention": "lab-rest",
            "note": "least-squares slope through the origin of Omega_crt^2 vs 1/(a-2R), over the "
                    f"paper's three balls and over R = {radii.min() * 100:g}..{radii.max() * 100:g}"
                    " cm; the finite-time criterion puts the nonlinear threshold below theory by "
                    "a relative amount growing with R, which lowers the all-R slope"}}


def fig_critical(ctx: Context) -> None:
    """Ω_crt vs R and a (rigid ball vs mass point) and Ω_crt² vs 1/(a − 2R), slope 2g."""
    import matplotlib.pyplot as plt

    cr = _critical_nonlinear(ctx)
    curve = _write_critical_csvs(ctx, cr)
    slopes = _critical_slopes(cr)
    fig, ax = plt.subplots(1, 3, figsize=(14, 4.3))
    _plot_critical_vs_R(ax[0], cr, curve)
    _plot_critical_squared(ax[1], cr, slopes)
    _plot_critical_map(fig, ax[2])
    fig.suptitle("Critical speed: rigid ball vs mass point (paper Fig. result (d), (e)); "
                 "markers: the nonlinear model's threshold", fontsize=10)
    fig.tight_layout()
    ctx.save_png(fig, "critical")
    ctx.update_summary(_critical_summary(cr, slopes))


# ------------------------------------------------------------------------------------------
# Asymmetric saddle
# ------------------------------------------------------------------------------------------
# Cases checked point by point with the nonlinear model: (label, contact, R, b/a).
ASYM_RELEASE = 1e-4   # [m]
ASYM_CASES: tuple[tuple[str, ContactModel, float, float], ...] = (("mass point, b/a = 0.8", "point", 0.0, 0.8),
              ("slipping R = 1 cm, b/a = 0.35", "slipping", 0.01, 0.35),
              ("rolling R = 1 cm, b/a = 0.35", "rolling", 0.01, 0.35))


ASYM_OMEGA_MAX = 80.0   # [1/s] bands are searched up to this speed
# The linear models of the band figure: (contact, R).
ASYM_MODELS: tuple[tuple[ContactModel, float], ...] = (("point", 0.0), ("slipping", 0.01),
                                                       ("rolling", 0.01))


def _write_asymmetric_bands(ctx: Context) -> None:
    """The stable bands of linear theory against b/a, one CSV row per band."""
    ratios = np.linspace(0.2, 1.2, 26 if ctx.quick else 201)
    rows: dict[str, list] = {"model": [], "R": [], "b_over_a": [], "omega_low": [],
                             "omega_high": []}
    for contact, R in ASYM_MODELS:
        for r in ratios:
            b = A_PAPER * r
            if contact != "point" and R >= b / 2:
                continue
            sc = Scene(a=A_PAPER, b=b, R=R, contact=contact)
            for lo_, hi_ in stable_band(sc, omega_max=ASYM_OMEGA_MAX,
                                        n_grid=1000 if ctx.quick else 4000):
                rows["model"].append(contact)
                rows["R"].append(R)
                rows["b_over_a"].append(r)
                rows["omega_low"].append(lo_)
                rows["omega_high"].append(hi_)
    ctx.write_csv("asymmetric", rows, [
        ("Stable bands (omega_low, omega_high) [1/s] of the linearised motion on z = x^2/a - y^2/b, "
        f"a = {A_PAPER} m, spin omega_z = 0, searched up to {ASYM_OMEGA_MAX} 1/s (inf: no upper "
        "edge below it)"), "one row per band; b/a values with no row have no stable speed"])


def _asymmetric_nonlinear(ctx: Context) -> tuple[np.ndarray, np.ndarray, str]:
    """The nonlinear check of ASYM_CASES on a grid of Ω (cached, written to a CSV): the
    grid, which runs were lost (cases × grid) and the criterion used."""
    grid = np.linspace(6.0, 60.0, 28 if ctx.quick else 109)
    horizon = 10.0 if ctx.quick else HORIZON
    release = ASYM_RELEASE

    def compute() -> dict[str, np.ndarray]:
        scenes, oms = [], []
        for _, contact, R, r in ASYM_CASES:
            sc = Scene(a=A_PAPER, b=A_PAPER * r, R=R, contact=contact)
            scenes += [sc] * len(grid)
            oms.append(grid)
        return {"lost": lost(ctx, scenes, np.concatenate(oms), "asymmetric", horizon, release)}

    res = ctx.cached("asymmetric", {"grid": grid, "cases": ASYM_CASES, "criterion": CRITERION,
                                    "horizon": horizon, "release": release}, compute)
    gone = res["lost"].reshape(len(ASYM_CASES), len(grid))
    criterion = (CRITERION.replace(f"x = {RELEASE * 1e3:g} mm", f"x = {release * 1e3:g} mm")
                 .replace(f"for {HORIZON:g} s", f"for {horizon:g} s"))
    ctx.write_csv("asymmetric_nonlinear", {
        "case": np.repeat([c[0] for c in ASYM_CASES], len(grid)),
        "omega": np.tile(grid, len(ASYM_CASES)), "stable_nonlinear": (~gone).ravel().astype(int)},
        [f"Nonlinear check: {criterion}",
         ("(a smaller release than for Omega_crt: near the edges of a band the bounded linear orbit "
         "from a 1 mm release can itself exceed 1 cm)")])
    return grid, gone, criterion


def _plot_asymmetric_panel(ax: Any, contact: ContactModel, R: float, quick: bool,
                           grid: np.ndarray, gone: np.ndarray) -> None:
    """One model's stability map on a (b/a, Ω) grid (the band edges in the CSV are exact),
    the mass point's closed-form edges and the nonlinear checks on top."""
    from matplotlib.colors import ListedColormap

    map_r = np.linspace(0.2, 1.2, 51 if quick else 201)
    map_w = np.linspace(0.2, ASYM_OMEGA_MAX, 120 if quick else 400)
    titles = {"point": "(a) mass point", "slipping": "(b) slipping ball, R = 1 cm",
              "rolling": "(c) rolling ball, R = 1 cm"}
    stab = np.full((len(map_w), len(map_r)), np.nan)
    for i, r in enumerate(map_r):
        if contact != "point" and R >= A_PAPER * r / 2:
            continue
        sc = Scene(a=A_PAPER, b=A_PAPER * r, R=R, contact=contact)
        stab[:, i] = [is_stable(sc, w) for w in map_w]
    ax.pcolormesh(map_r, map_w, stab, cmap=ListedColormap(["white", "#9ecae1"]),
                  vmin=0, vmax=1, shading="nearest", rasterized=True)
    ax.plot([], [], "s", color="#9ecae1", ms=8, label="linearly stable")
    if contact == "point":
        rb = np.linspace(1 / 3 + 1e-4, 1.2, 300)
        up = np.array([(mass_point_band(A_PAPER, A_PAPER * x) or (np.nan, np.nan))[1]
                       for x in rb])
        ax.plot(rb, np.sqrt(2 * 9.8 / A_PAPER) * np.ones_like(rb), "k--", lw=1,
                label="Ω² = 2g/a")
        ax.plot(rb, up, "k:", lw=1.2, label="Ω² = g(a+b)²/(4ab(a−b))")
        ax.axvline(1 / 3, color="0.5", lw=0.6)
        ax.text(0.335, 55, "a = 3b", fontsize=7, rotation=90)
    for case, (label, c_, _R, r_) in zip(gone, ASYM_CASES):
        if c_ != contact:
            continue
        ax.plot(np.full((~case).sum(), r_), grid[~case], "g.", ms=4,
                label=f"nonlinear: kept ({label})")
        ax.plot(np.full(case.sum(), r_), grid[case], "rx", ms=3, label="nonlinear: lost")
    ax.axvline(1.0, color="0.6", lw=0.6, ls="--")
    ax.set(xlabel="b / a", title=titles[contact], ylim=(0, ASYM_OMEGA_MAX), xlim=(0.2, 1.2))
    ax.legend(fontsize=6.5, loc="upper right")


def _asymmetric_summary(grid: np.ndarray, gone: np.ndarray, criterion: str) -> dict[str, Any]:
    summary = {}
    for (label, contact, R, r), case in zip(ASYM_CASES, gone):
        sc = Scene(a=A_PAPER, b=A_PAPER * r, R=R, contact=contact)
        bands = stable_band(sc, omega_max=ASYM_OMEGA_MAX)
        summary[label] = {"bands_theory": [[lo_, hi_] for lo_, hi_ in bands],
                          "nonlinear_stable_fraction_agreeing": float(np.mean(
                              [(not gw) == _in_bands(w, bands) for w, gw in zip(grid, case)])),
                          "convention": "lab-rest", "criterion": criterion}
    return summary


def fig_asymmetric(ctx: Context) -> None:
    """Stable band(s) of Ω on z = x²/a − y²/b (a = 0.159 m) vs b/a, with nonlinear checks."""
    import matplotlib.pyplot as plt

    _write_asymmetric_bands(ctx)
    grid, gone, criterion = _asymmetric_nonlinear(ctx)
    fig, ax = plt.subplots(1, 3, figsize=(14, 4.3), sharey=True)
    for k, (contact, R) in enumerate(ASYM_MODELS):
        _plot_asymmetric_panel(ax[k], contact, R, ctx.quick, grid, gone)
    ax[0].set_ylabel("Ω [s⁻¹]")
    fig.suptitle("Asymmetric saddle z = x²/a − y²/b, a = 0.159 m: stable bands of Ω "
                 "(upper edge cited by the paper from Kirillov)", fontsize=10)
    fig.tight_layout()
    ctx.save_png(fig, "asymmetric")
    ctx.update_summary({"asymmetric_band": _asymmetric_summary(grid, gone, criterion)})


def _in_bands(w: float, bands: Sequence[tuple[float, float]]) -> bool:
    return any(lo <= w <= hi for lo, hi in bands)
