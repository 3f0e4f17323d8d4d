"""``analogy``: the paper's ion-trap analogy, run (its section "Electromagnetic Analogy").

Four panels (saddle a = 0.159 m, g = 9.8 m/s², Ω = 30 s⁻¹ as in the paper's Fig. traj):

(a) a rolling ball (R = 2 cm, exact nonlinear model) against the RRF ion `ball_to_ion`
    maps it to and against the paper's own analogy ion, centre paths in the rotating frame;
(b) the relative gap |Δr(t)| / max r of each pairing over 10 s, log scale — the linearised
    mass point and its ion agree to integration accuracy;
(c) the growth rate of the linearised motion against Ω: mass point, rolling ball (R = 3 cm),
    the RRF ion mapped from the mass point, and the Paul trap with the same field strength
    (Floquet multipliers from simulation), thresholds marked;
(d) the flapping Paul trap against the rotating saddle (= RRF ion) at the same Ω: x(t) in the
    laboratory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..iontrap import (
    Q_MAX,
    BallIonMap,
    IonTrajectory,
    PaulTrap,
    RRFTrap,
    ball_to_ion,
    eigenfrequency_mismatch,
    floquet_multipliers,
    lab_rest_state,
    max_rel_diff,
    paper_analogy_ion,
    simulate_ion,
)
from ..linear import critical_omega, eigenfrequencies, linear_trajectory
from ..scene import Scene
from ..simulate import Trajectory, initial_state, simulate
from .context import Context

A_PAPER = 0.159
OMEGA = 30.0           # [1/s] the paper's Fig. traj speed
RELEASE = 0.001        # [m] contact point at x = y = 1 mm, placed at rest in the laboratory
T_END = 10.0           # [s]
DT_OUT = 0.002         # [s] output spacing (Ω = 30: ~100 samples per turn)
SPIN = 5.0             # [rad/s] a relative spin about the vertical, for the p != q case
CONVENTION = ("lab-rest (placed at rest in the laboratory, contact point at x = y = 1 mm, "
              "as in the paper's Fig. traj)")


def _start(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """The ball's lab-rest state and its centre's (x_c, y_c, ẋ_c, ẏ_c) in the rotating frame.

    The centre velocity is, by the definition of the lab-rest start (`initial_state`), the
    part of −Ω k × c tangent to the surface (normal n): exact, no linearisation."""
    state = initial_state(scene, RELEASE, RELEASE, start="lab-rest", omega=OMEGA)
    x = y = RELEASE
    assert scene.b is not None  # Scene.__post_init__ sets b (None means b = a)
    n = np.array([-2 * x / scene.a, 2 * y / scene.b, 1.0])
    n /= np.linalg.norm(n)
    c = np.array([x, y, 0.0]) + scene.radius * n
    v = np.array([OMEGA * c[1], -OMEGA * c[0], 0.0])
    v -= n * (n @ v)
    return state, np.array([c[0], c[1], v[0], v[1]])


def _growth(roots: np.ndarray) -> float:
    """Growth rate [1/s] of the linear motion: the largest −Im ϖ (x ∝ e^{iϖt}), or 0."""
    return max(0.0, float(-roots.imag.min()))


@dataclass(frozen=True)
class _MassPoint:
    """The linearised and the exact mass point against its RRF ion (no field)."""

    ion: IonTrajectory
    linear: np.ndarray          # (n, 4) linear solution at ion.t
    exact: Trajectory
    d_linear: float             # max relative gap, linear vs ion
    d_exact: float              # max relative gap, exact vs ion


@dataclass(frozen=True)
class _Rolling:
    """The rolling ball (R = 2 cm) against its best-matching ion and the paper's ion."""

    best: BallIonMap
    ion_best: IonTrajectory
    ion_paper: IonTrajectory
    linear: np.ndarray          # (n, 4) linear solution at ion_best.t
    centre: np.ndarray          # (n, 2) the exact ball's centre path
    d_linear: float
    d_best: float
    d_paper: float
    mismatch_paper: float
    mismatch_best: float


@dataclass(frozen=True)
class _Spun:
    """The rolling ball with a relative spin SPIN about the vertical (p != q)."""

    map: BallIonMap
    mismatch_best: float
    mismatch_paper: float
    d_unstretched: float
    d_stretched: float


@dataclass(frozen=True)
class _Thresholds:
    """Growth rates of the linear motion against Ω and the thresholds."""

    omegas: np.ndarray
    mass_point: np.ndarray
    rolling_R3: np.ndarray
    rrf_ion: np.ndarray
    paul: np.ndarray
    wc_mass_point: float
    wc_rolling_R3: float
    wc_paul: float
    paul_first_stable: float


def _ion_run(trap: RRFTrap | PaulTrap, state: np.ndarray, t_end: float) -> IonTrajectory:
    return simulate_ion(trap, state, t_end, dt_out=DT_OUT, escape=False)


def _mass_point(point: Scene, t_end: float) -> _MassPoint:
    """Mass point vs RRF ion without field: the same linear equations."""
    s_mp, z_mp = _start(point)
    mp_map = ball_to_ion(point, OMEGA)
    ion = _ion_run(mp_map.trap, mp_map.ion_state(z_mp), t_end)
    linear = linear_trajectory(point, OMEGA, z_mp, ion.t)
    exact = simulate(point, s_mp, t_end, omega=OMEGA, dt_out=DT_OUT)
    return _MassPoint(ion, linear, exact, max_rel_diff(linear[:, :2], ion.state[:, :2]),
                      max_rel_diff(exact.centre[:, :2], ion.state[:, :2]))


def _rolling(rolling: Scene, t_end: float) -> _Rolling:
    """Rolling ball vs the best-matching ion and the paper's analogy ion."""
    s_r, z_r = _start(rolling)
    best = ball_to_ion(rolling, OMEGA)
    paper = paper_analogy_ion(rolling, OMEGA)
    ion_best = _ion_run(best.trap, best.ion_state(z_r), t_end)
    ion_paper = _ion_run(paper, z_r, t_end)
    ball = simulate(rolling, s_r, t_end, omega=OMEGA, dt_out=DT_OUT)
    linear = linear_trajectory(rolling, OMEGA, z_r, ion_best.t)
    centre = ball.centre[:, :2]
    return _Rolling(best, ion_best, ion_paper, linear, centre,
                    d_linear=max_rel_diff(linear[:, :2], ion_best.state[:, :2]),
                    d_best=max_rel_diff(centre, ion_best.state[:, :2]),
                    d_paper=max_rel_diff(centre, ion_paper.state[:, :2]),
                    mismatch_paper=eigenfrequency_mismatch(rolling, OMEGA, paper),
                    mismatch_best=eigenfrequency_mismatch(rolling, OMEGA, best.trap))


def _spun(rolling: Scene, t_end: float) -> _Spun:
    """With a relative spin about the vertical: p != q, and the map stretches the plane."""
    _, z_r = _start(rolling)
    spun = ball_to_ion(rolling, OMEGA, SPIN)
    mis_best = eigenfrequency_mismatch(rolling, OMEGA, spun.trap, SPIN)
    mis_paper = eigenfrequency_mismatch(rolling, OMEGA, paper_analogy_ion(rolling, OMEGA, SPIN),
                                        SPIN)
    ion = _ion_run(spun.trap, spun.ion_state(z_r), t_end)
    linear = linear_trajectory(rolling, OMEGA, z_r, ion.t, SPIN)
    return _Spun(spun, mis_best, mis_paper,
                 d_unstretched=max_rel_diff(linear[:, :2], ion.state[:, :2]),
                 d_stretched=max_rel_diff(linear[:, :2], spun.ball_centre(ion.state[:, :2])))


def _thresholds(ctx: Context, point: Scene, kappa: float) -> _Thresholds:
    """Growth rates against Ω (mass point, R = 3 cm ball, RRF ion, Paul trap), written to
    ``analogy.csv``."""
    ball3 = Scene(a=A_PAPER, R=0.03, contact="rolling")
    omegas = np.linspace(2.0, 25.0, 47 if ctx.quick else 231)
    grow_mp = np.array([_growth(eigenfrequencies(point, w)) for w in omegas])
    grow_r3 = np.array([_growth(eigenfrequencies(ball3, w)) for w in omegas])
    grow_ion = np.array([_growth(RRFTrap(omega=w, kappa=kappa).eigenfrequencies())
                         for w in omegas])
    mu = np.array([floquet_multipliers(PaulTrap(omega=w, kappa=kappa)).max() for w in omegas])
    grow_paul = np.log(np.maximum(mu, 1.0)) * omegas / (2 * math.pi)
    # |μ| is 1 to integration accuracy where stable
    grow_paul[np.abs(mu - 1.0) < 1e-6] = 0.0
    wc_mp, wc_r3 = critical_omega(point), critical_omega(ball3)
    wc_paul = PaulTrap(omega=1.0, kappa=kappa).critical_omega()
    paul_sim = omegas[(grow_paul == 0) & (omegas > omegas[np.argmax(grow_paul > 0)])]
    paul_first_stable = float(paul_sim.min()) if paul_sim.size else math.nan
    ctx.write_csv("analogy", {"omega": omegas, "growth_mass_point": grow_mp,
                              "growth_rolling_R3cm": grow_r3, "growth_rrf_ion": grow_ion,
                              "growth_paul": grow_paul, "paul_floquet_abs_mu": mu}, [
        "Growth rate [1/s] of the linear motion against Omega [1/s], a = 0.159 m, g = 9.8: "
        "mass point and rolling ball R = 3 cm (Table I), the RRF ion with kappa = 2g/a and "
        "no field (Eq. comp2), the Paul trap with kappa = 2g/a driven at Omega (Floquet "
        "multipliers |mu| over one period, from simulate_ion: growth = ln|mu| Omega/2pi)",
        f"thresholds: mass point = RRF ion {wc_mp:.6f}, rolling R=3cm {wc_r3:.6f}, Paul "
        f"sqrt(2 kappa/q_max) {wc_paul:.6f} (q_max = {Q_MAX:.10f})"])
    return _Thresholds(omegas, grow_mp, grow_r3, grow_ion, grow_paul, wc_mp, wc_r3, wc_paul,
                       paul_first_stable)


def _side_by_side(kappa: float) -> dict[str, IonTrajectory]:
    """Paul trap vs rotating saddle (= RRF ion) at the same field strength, released at rest
    in the laboratory at x = RELEASE."""
    traps = (("rrf", RRFTrap(omega=OMEGA, kappa=kappa)),
             ("paul", PaulTrap(omega=OMEGA, kappa=kappa)),
             ("paul_2omega", PaulTrap(omega=2 * OMEGA, kappa=kappa)))
    return {name: simulate_ion(trap, lab_rest_state(trap, RELEASE, 0.0), 3.0, dt_out=0.002,
                               escape=False)
            for name, trap in traps}


def _write_orbits(ctx: Context, mp: _MassPoint, roll: _Rolling) -> None:
    ctx.write_csv("analogy_orbits", {
        "t": roll.ion_best.t, "ball_xc": roll.centre[:, 0], "ball_yc": roll.centre[:, 1],
        "best_ion_x": roll.ion_best.x, "best_ion_y": roll.ion_best.y,
        "paper_ion_x": roll.ion_paper.x, "paper_ion_y": roll.ion_paper.y,
        "mass_point_linear_x": mp.linear[:, 0], "mass_point_linear_y": mp.linear[:, 1],
        "mass_point_ion_x": mp.ion.x, "mass_point_ion_y": mp.ion.y}, [
        f"Rotating-frame centre paths [m], Omega = {OMEGA:g}, a = 0.159, start {CONVENTION}: "
        "rolling ball R = 2 cm (exact model), its best-matching RRF ion (ball_to_ion), the "
        "paper's analogy ion (paper_analogy_ion); linearised mass point and its RRF ion"])


MM = 1e3   # plotted lengths in mm


def _plot_orbits(ax: Any, roll: _Rolling) -> None:
    """(a) the first 2 s of the rolling ball and its two ions, rotating frame."""
    ion_best, ion_paper, c_ball = roll.ion_best, roll.ion_paper, roll.centre
    n2 = int(np.searchsorted(ion_best.t, 2.0)) + 1
    ax.plot(c_ball[:n2, 0] * MM, c_ball[:n2, 1] * MM, lw=2.2, color="0.7",
            label="rolling ball (exact model)")
    ax.plot(ion_best.x[:n2] * MM, ion_best.y[:n2] * MM, lw=0.9, color="C0",
            label=f"best ion: ω_B = αΩ/(1+α) = {roll.best.trap.omega_B:.3g} s⁻¹")
    ax.plot(ion_paper.x[:n2] * MM, ion_paper.y[:n2] * MM, lw=0.9, color="C3", ls="--",
            label="paper's analogy ion (ω_B = 0, Coriolis 2Ω)")
    ax.set(xlabel="x_c [mm]", ylabel="y_c [mm]", aspect="equal",
           title=f"(a) rolling ball R = 2 cm, Ω = {OMEGA:g} s⁻¹, first 2 s (rotating frame)")
    ax.legend(fontsize=7, loc="upper right")


def _gap(a_: np.ndarray, b_: np.ndarray) -> np.ndarray:
    """|Δr(t)| relative to the largest |r| of the first path."""
    return np.linalg.norm(a_ - b_, axis=1) / np.linalg.norm(a_, axis=1).max()


def _plot_gaps(ax: Any, mp: _MassPoint, roll: _Rolling) -> None:
    """(b) the relative gap of each pairing over time, log scale."""
    floor = 1e-16
    ion_mp, ion_best = mp.ion, roll.ion_best
    ax.semilogy(ion_mp.t, _gap(mp.linear[:, :2], ion_mp.state[:, :2]) + floor, lw=0.8,
                label=f"linearised mass point vs RRF ion (B = 0): max {mp.d_linear:.1e}")
    ax.semilogy(ion_mp.t, _gap(mp.exact.centre[:, :2], ion_mp.state[:, :2]) + floor, lw=0.8,
                label=f"exact mass point vs RRF ion: max {mp.d_exact:.1e}")
    ax.semilogy(ion_best.t, _gap(roll.linear[:, :2], ion_best.state[:, :2]) + floor, lw=0.8,
                label=f"linearised rolling ball vs best ion: max {roll.d_linear:.1e}")
    ax.semilogy(ion_best.t, _gap(roll.centre, ion_best.state[:, :2]) + floor, lw=0.8,
                label=f"exact rolling ball vs best ion: max {roll.d_best:.1e}")
    ax.semilogy(ion_best.t, _gap(roll.centre, roll.ion_paper.state[:, :2]) + floor, lw=0.8,
                label=f"exact rolling ball vs paper's ion: max {roll.d_paper:.2f}")
    ax.set(xlabel="t [s]", ylabel="|Δr(t)| / max r", ylim=(1e-16, 10),
           title="(b) how far apart, relative to the orbit size")
    ax.legend(fontsize=7, loc="lower right")


def _plot_thresholds(ax: Any, th: _Thresholds) -> None:
    """(c) growth rates against Ω, the thresholds marked."""
    omegas = th.omegas
    ax.plot(omegas, th.mass_point, lw=2.2, color="0.7", label="mass point (Table I)")
    ax.plot(omegas[::4], th.rrf_ion[::4], "o", ms=3, color="C0",
            label="RRF ion κ = 2g/a, B = 0 (comp2)")
    ax.plot(omegas, th.rolling_R3, lw=1.2, color="C2", label="rolling ball R = 3 cm")
    ax.plot(omegas, th.paul, lw=1.2, color="C3",
            label="Paul trap κ = 2g/a, drive Ω (Floquet, simulated)")
    top = ax.get_ylim()[1]
    marks = ((th.wc_mass_point, "0.4", "Ω_crt point"), (th.wc_rolling_R3, "C2", "Ω_crt R=3cm"),
             (th.wc_paul, "C3", "Paul q = q_max"))
    for k, (w, c, lab) in enumerate(marks):
        ax.axvline(w, color=c, ls=":", lw=1)
        ax.text(w, top * (0.93 - 0.09 * k), f" {lab} {w:.2f}", fontsize=7, color=c)
    ax.set(xlabel="Ω [s⁻¹]", ylabel="growth rate [s⁻¹]",
           title="(c) instability against Ω: thresholds side by side")
    ax.legend(fontsize=7, loc="center right")


def _plot_side_by_side(ax: Any, side: dict[str, IonTrajectory]) -> None:
    """(d) the flapping Paul trap against the rotating saddle: x(t) in the laboratory."""
    for name, c, lab in (("rrf", "0.5", f"rotating saddle = RRF ion, Ω = {OMEGA:g}"),
                         ("paul", "C3", f"Paul trap, drive Ω = {OMEGA:g}"),
                         ("paul_2omega", "C0", f"Paul trap, drive 2Ω = {2 * OMEGA:g}")):
        tr = side[name]
        ax.plot(tr.t, tr.lab_xy()[:, 0] * MM, lw=0.8, color=c, label=lab)
    ax.set(xlabel="t [s]", ylabel="x (laboratory) [mm]",
           title="(d) same field strength κ = 2g/a, released at rest at x = 1 mm")
    ax.legend(fontsize=7, loc="lower right")


def _summary(t_end: float, rolling: Scene, mp: _MassPoint, roll: _Rolling, spun: _Spun,
             th: _Thresholds) -> dict[str, Any]:
    """The ``analogy`` entry of summary.json."""
    best = roll.best
    return {
        "convention": CONVENTION,
        "omega": OMEGA, "t_end_s": t_end,
        "masspoint_rrf_max_rel_diff": mp.d_linear,
        "masspoint_rrf_note": "linearised mass point (matrix exponential) vs the RRF ion with "
                              "kappa = 2g/a, omega_B = 0 simulated by simulate_ion (DOP853, "
                              "rtol 1e-10): the same linear equations",
        "masspoint_exact_vs_rrf_max_rel_diff": mp.d_exact,
        "rolling_R": rolling.R,
        "rolling_eigenfrequency_mismatch": roll.mismatch_paper,
        "rolling_eigenfrequency_mismatch_note": "max |varpi_ball - varpi_ion| / max |varpi_ball| "
                                                "against the paper's analogy ion (Coriolis 2 "
                                                "Omega instead of (2+alpha)/(1+alpha) Omega, "
                                                "omega_B = q omega_z)",
        "rolling_eigenfrequency_mismatch_best_ion": roll.mismatch_best,
        "rolling_best_ion": {"omega_B": best.trap.omega_B, "kappa": best.trap.kappa,
                             "kappa_t": best.trap.kappa_t,
                             "omega_B_over_omega": best.trap.omega_B / OMEGA},
        "rolling_linear_vs_best_ion_max_rel_diff": roll.d_linear,
        "rolling_exact_vs_best_ion_max_rel_diff": roll.d_best,
        "rolling_exact_vs_paper_ion_max_rel_diff": roll.d_paper,
        "spin_z": SPIN,
        "spin_stretch_lambda": spun.map.stretch,
        "spin_eigenfrequency_mismatch_best_ion": spun.mismatch_best,
        "spin_eigenfrequency_mismatch_paper_ion": spun.mismatch_paper,
        "spin_linear_vs_ion_max_rel_diff_unstretched": spun.d_unstretched,
        "spin_linear_vs_ion_max_rel_diff_stretched": spun.d_stretched,
        "paul_threshold": th.wc_paul,
        "paul_threshold_first_stable_on_grid": th.paul_first_stable,
        "omega_crt_mass_point": th.wc_mass_point,
        "omega_crt_rolling_R3cm": th.wc_rolling_R3,
        "paul_over_omega_crt": th.wc_paul / th.wc_mass_point,
        "paul_threshold_note": "Paul trap with the saddle's field strength kappa = 2g/a driven "
                               "at angular frequency Omega: stable for q = 2 kappa/Omega^2 < "
                               f"q_max = {Q_MAX:.6f}; the rotating saddle's quadrupole flaps "
                               "at 2 Omega, so as a rotation rate the Paul threshold is half "
                               "this",
        "paul_threshold_as_rotation_rate": th.wc_paul / 2,
        "unit": "1/s"}


def fig_analogy(ctx: Context) -> None:
    """Draw the ion-trap analogy figure (the module's docstring) into ``ctx``'s folder."""
    import matplotlib.pyplot as plt

    g = 9.8
    point = Scene(a=A_PAPER, contact="point")
    rolling = Scene(a=A_PAPER, R=0.02, contact="rolling")
    t_end = 3.0 if ctx.quick else T_END
    kappa = 2 * g / A_PAPER

    mp = _mass_point(point, t_end)
    roll = _rolling(rolling, t_end)
    spun = _spun(rolling, t_end)
    th = _thresholds(ctx, point, kappa)
    side = _side_by_side(kappa)
    _write_orbits(ctx, mp, roll)

    fig, ax = plt.subplots(2, 2, figsize=(12, 9.5))
    _plot_orbits(ax[0, 0], roll)
    _plot_gaps(ax[0, 1], mp, roll)
    _plot_thresholds(ax[1, 0], th)
    _plot_side_by_side(ax[1, 1], side)
    fig.suptitle("The ion-trap analogy: rotating saddle, RRF trap and Paul trap "
                 "(a = 0.159 m, saddle_env.iontrap)", fontsize=10)
    fig.tight_layout()
    ctx.save_png(fig, "analogy")
    ctx.update_summary({"analogy": _summary(t_end, rolling, mp, roll, spun, th)})
