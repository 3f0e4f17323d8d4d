"""``damping``: how linear air drag moves the trap's stable band (not in the paper).

Two panels, each the growth rate of the orbit (largest real part of the eigenvalues of
`saddle_env.linear.system_matrix`, 1/s; < 0: the orbit decays) against Ω for a few drag
levels k₁, theory as lines and the nonlinear model as markers:

(a) the paper's symmetric saddle, a = b = 0.159 m, rolling ball R = 2.65 cm: drag damps the
    orbit everywhere in the band, at a rate that falls with Ω;
(b) an asymmetric saddle, a = 0.229 m, b = 0.143 m, rolling ball R = 6 mm: drag damps the
    orbit just above the lower edge but drives it out above ~12.6 1/s, where the drag-free
    ball is kept for ever (dissipation-induced instability), so the band becomes finite.

The stable band (`damped_band`: growth ≤ 0) of each level is drawn as a bar under the curves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..linear import damped_band, growth_rate, system_matrix
from ..scene import Scene
from ..simulate import initial_state, simulate
from .context import Context

DRAG_LEVELS = (0.0, 0.05, 0.1, 0.2)   # linear drag k₁ [1/s]
OMEGA_MAX = 100.0     # [1/s] the bands are searched up to here (inf: no upper edge below it)
RELEASE = 1e-5        # [m] the orbit stays < 0.2 mm (from 0.1 mm it reaches 1.5 mm and the
                      # fastest rate comes out 1.3 % high: the saddle's nonlinearity)
SIM_WINDOW = 10.0     # [s] simulated time per rate (quick: QUICK_WINDOW)
QUICK_WINDOW = 6.0
DT_OUT = 0.002        # [s] output spacing: the per-period maximum is sampled to ~1e-4
# Agreement asked of the nonlinear rates: |simulated − theory| ≤ ABS_TOL + REL_TOL·|theory|.
ABS_TOL = 2e-4        # [1/s]
REL_TOL = 0.005
CONVENTION = ("none for the theory; the simulation releases the ball on the linear mode "
              f"that grows fastest (or decays slowest), {RELEASE * 1e3:g} mm off centre, "
              "spin omega_z = 0")


@dataclass(frozen=True)
class Panel:
    """One panel of the figure: its scene, speed range and the speeds simulated."""

    key: str                    # CSV and summary name
    title: str
    scene: Scene                # drag-free; each level sets drag_linear
    omegas: tuple[float, float]   # plotted range (lo, hi)
    simulated: tuple[float, ...]  # speeds checked with the nonlinear model
    ylim: tuple[float, float]   # with room at the bottom for the band bars


PANELS = (
    Panel("symmetric", "(a) symmetric saddle a = b = 0.159 m, rolling R = 2.65 cm",
          Scene(a=0.159, R=0.0265, contact="rolling"), (8.0, 40.0),
          (15.0, 20.0, 27.0, 35.0), (-0.1, 0.02)),
    Panel("asymmetric", "(b) asymmetric saddle a = 0.229 m, b = 0.143 m, rolling R = 6 mm",
          Scene(a=0.229, b=0.143, R=0.006, contact="rolling"), (6.0, 40.0),
          (10.5, 14.0, 19.5, 27.0, 35.0), (-0.17, 0.4)),
)


def dominant_mode(scene: Scene, omega: float) -> tuple[complex, np.ndarray]:
    """The eigenvalue of largest real part and a real centre state (x_c, y_c, ẋ_c, ẏ_c) in its
    mode, scaled so that the centre starts RELEASE from the axis."""
    values, vectors = np.linalg.eig(system_matrix(scene, omega))
    i = int(np.argmax(values.real))
    v = vectors[:, i]
    v = v / v[np.argmax(np.abs(v))]          # phase with a real largest component
    z = v.real
    return complex(values[i]), RELEASE * z / np.hypot(z[0], z[1])


def model_state(scene: Scene, centre: np.ndarray) -> np.ndarray:
    """The model's state for a small centre state: the contact point and its velocity are
    the centre's scaled by the linear map of `saddle_env.linear.centre_from_contact`."""
    assert scene.b is not None  # Scene.__post_init__ sets b (None means b = a)
    sx, sy = 1 - 2 * scene.radius / scene.a, 1 + 2 * scene.radius / scene.b
    xc, yc, vxc, vyc = centre
    return initial_state(scene, xc / sx, yc / sy, vxc / sx, vyc / sy)


def simulated_growth_rate(scene: Scene, omega: float, window: float) -> float:
    """Growth rate [1/s] of the nonlinear model's orbit, released in the dominant linear mode.

    Started in one mode the orbit is an ellipse scaled by e^{rate·t}, so the largest
    distance of the centre from the axis in each turn of the mode grows as e^{rate·t}; the
    rate is the slope of a straight-line fit of its log against time. Had the theory's mode
    been wrong the orbit would mix modes and the maxima would beat instead.
    """
    value, centre = dominant_mode(scene, omega)
    period = 2 * math.pi / abs(value.imag)   # every rate drawn as a marker is oscillatory
    tr = simulate(scene, model_state(scene, centre), window, omega=omega, dt_out=DT_OUT,
                  events=())
    r = np.hypot(tr.centre[:, 0], tr.centre[:, 1])
    turns = (tr.t // period).astype(int)
    whole = turns < turns[-1]                 # drop the last, incomplete turn
    t_max, log_max = [], []
    for k in range(turns[-1]):
        j = np.flatnonzero(whole & (turns == k))
        m = j[np.argmax(r[j])]
        t_max.append(tr.t[m])
        log_max.append(math.log(r[m]))
    return float(np.polyfit(t_max, log_max, 1)[0])


def fig_damping(ctx: Context) -> None:
    """Draw the damping figure (the module's docstring) into ``ctx``'s folder."""
    import matplotlib.pyplot as plt

    window = QUICK_WINDOW if ctx.quick else SIM_WINDOW
    n_theory = 120 if ctx.quick else 400
    colours = {k: f"C{j}" for j, k in enumerate(DRAG_LEVELS)}
    rows: dict[str, list | np.ndarray] = {"panel": [], "k1": [], "omega": [], "growth_theory": [],
                             "growth_simulated": []}
    band_rows: dict[str, list] = {"panel": [], "k1": [], "omega_low": [], "omega_high": []}
    summary: dict[str, Any] = {}   # a section of summary.json: a dict per panel, then notes
    worst_abs, worst_rel = 0.0, 0.0

    fig, axes = plt.subplots(1, 2, figsize=(13, 4.8))
    for ax, panel in zip(axes, PANELS):
        grid = np.linspace(*panel.omegas, n_theory)
        summary[panel.key] = {}
        for j, k1 in enumerate(DRAG_LEVELS):
            sc = panel.scene.with_(drag_linear=k1)
            theory = np.array([growth_rate(sc, w) for w in grid])
            sim_w = np.array(panel.simulated[::2] if ctx.quick else panel.simulated)
            sim_theory = np.array([growth_rate(sc, w) for w in sim_w])
            sim = np.array([simulated_growth_rate(sc, w, window) for w in sim_w])
            diff = np.abs(sim - sim_theory)
            worst_abs = max(worst_abs, float(diff.max()))
            worst_rel = max(worst_rel, float(np.max(diff / np.maximum(np.abs(sim_theory),
                                                                       ABS_TOL))))
            bands = damped_band(sc, omega_max=OMEGA_MAX)

            omegas = np.concatenate([grid, sim_w])
            order = np.argsort(omegas, kind="stable")
            rows["panel"] += [panel.key] * len(omegas)
            rows["k1"] += [k1] * len(omegas)
            rows["omega"] += list(omegas[order])
            rows["growth_theory"] += list(np.concatenate([theory, sim_theory])[order])
            rows["growth_simulated"] += list(np.concatenate(
                [np.full(len(grid), ""), sim.astype(object)])[order])
            for lo, hi in bands:
                band_rows["panel"].append(panel.key)
                band_rows["k1"].append(k1)
                band_rows["omega_low"].append(lo)
                band_rows["omega_high"].append(hi)
            summary[panel.key][f"k1={k1:g}"] = {
                "bands": [[lo, hi] for lo, hi in bands],
                "simulated_omega": sim_w, "growth_simulated": sim, "growth_theory": sim_theory}

            col = colours[k1]
            ax.plot(grid, theory, color=col, lw=1.3, label=f"k₁ = {k1:g} s⁻¹")
            ax.plot(sim_w, sim, "o", color=col, mfc="none", ms=7)
            # the band as a bar under the curves, one row per level
            y_bar = 0.03 + 0.035 * j
            for lo, hi in bands:
                hi_drawn = min(hi, panel.omegas[1])
                ax.plot([lo, hi_drawn], [y_bar, y_bar], color=col, lw=5, solid_capstyle="butt",
                        transform=ax.get_xaxis_transform())
                ax.plot([lo, lo], [0, 1], color=col, lw=0.6, ls=":",
                        transform=ax.get_xaxis_transform())
                if hi < panel.omegas[1]:
                    ax.plot([hi, hi], [0, 1], color=col, lw=0.6, ls=":",
                            transform=ax.get_xaxis_transform())
                    ax.annotate(f"{hi:.2f}", (hi, y_bar), xycoords=ax.get_xaxis_transform(),
                                xytext=(3, -2.5), textcoords="offset points", fontsize=6.5,
                                color=col)
        ax.axhline(0, color="k", lw=0.6)
        ax.plot([], [], "ko", mfc="none", label="nonlinear model")
        ax.plot([], [], "k-", lw=5, label="stable band (growth ≤ 0)")
        ax.set(xlabel="Ω [s⁻¹]", ylabel="growth rate [s⁻¹]", xlim=panel.omegas,
               ylim=panel.ylim, title=panel.title)
        ax.title.set_fontsize(9)
    axes[-1].legend(fontsize=7, loc="upper right")   # one legend: the levels share colours
    fig.suptitle("Linear air drag −k₁u on the orbit's growth rate (largest Re λ; off scale: "
                 "the drag-free instability below the band)", fontsize=10)
    fig.tight_layout()
    ctx.save_png(fig, "damping")

    tolerance = f"|simulated - theory| <= {ABS_TOL:g} + {REL_TOL:g} |theory| 1/s"
    # "" and floats in one column: an object array keeps the floats' CSV formatting
    rows["growth_simulated"] = np.array(rows["growth_simulated"], dtype=object)
    ctx.write_csv("damping", rows, [
        ("Growth rate [1/s] of the orbit about the saddle point: largest real part of the "
         "eigenvalues of the linearised motion with linear drag k1 [1/s] (theory), and the "
         "slope of log(per-turn max distance) vs time of the nonlinear model (simulated)"),
        (f"simulated: released on the dominant linear mode {RELEASE * 1e3:g} mm off centre, "
         f"{window:g} s; empty where not simulated; asked: {tolerance}"),
        (f"measured: max |simulated - theory| = {worst_abs:.2g} 1/s, max relative "
         f"{worst_rel:.2g} (of max(|theory|, {ABS_TOL:g}))"),
        "panels: symmetric a = b = 0.159 m, R = 0.0265 m; asymmetric a = 0.229, b = 0.143 m, "
        "R = 0.006 m; rolling, alpha = 0.4, g = 9.8"])
    ctx.write_csv("damping_bands", band_rows, [
        (f"Stable bands (growth <= 0) of Omega [1/s] per drag level, searched up to "
         f"{OMEGA_MAX:g} 1/s (inf: no upper edge below it); without drag the marginal band"),
        "one row per band"])
    summary.update({
        "convention": CONVENTION, "unit": "1/s",
        "max_abs_diff_simulated_theory": worst_abs, "max_rel_diff_simulated_theory": worst_rel,
        "tolerance": tolerance, "window_s": window,
        "note": "bands: intervals of Omega where the orbit does not grow (inf: no upper edge "
                f"below {OMEGA_MAX:g} 1/s); drag makes the asymmetric rolling band finite"})
    ctx.update_summary({"damping": summary})
