"""Compiled equations of motion: the one implementation every caller shares.

Everything here is in the frame rotating with the saddle (docs/physics.md, "The rotating
frame and its forces"), per unit mass, with the contact point ``q = (x, y)`` as generalised
coordinates. Vectors are handled as scalar triples so that numba keeps them in registers;
no arrays are allocated on the hot path.

State vectors always have ``STATE_WIDTH = 9`` slots so that single balls and batches of
mixed contact models share one memory layout:

* rolling:  ``(x, y, wx, wy, wz, W, ...)`` — contact point [m] and the ball's angular
  velocity relative to the saddle, in the saddle's axes [rad/s];
* slipping / point: ``(x, y, vx, vy, W, ...)`` — contact point and its velocity [m/s]. The
  spin is decoupled (docs/physics.md, "Frictionless slipping") and is not integrated;
* coulomb: ``(x, y, wx, wy, wz, vx, vy, W, phase)`` — both, and the phase (STICK, SLIP or
  ONSET) in PHASE_SLOT, switched by the integrator's loop and never integrated (the same
  slot of the rates carries what the loop checks a step with: see `rhs`).

Slots past a model's own are unused. W [J/kg], in the slot right after the dynamics
(`work_slot`), is the work per unit mass the dissipative forces (air drag, drilling friction,
rolling resistance, kinetic friction) have done since the start: the Jacobi integral's
change. It is integrated only when the scene dissipates (`integrated_size`), so a
conservative scene's step is the same arithmetic as without it.

Notation (derivations in docs/physics.md):
  m(q) = (-2x/a, 2y/b, 1) is the un-normalised normal — affine in q, so its second time
  derivative along a trajectory vanishes; s = |m|, n = m/s; c = o + R n the ball's centre;
  J = dc/dq; P = 1 - n nᵀ.  ṅ = P ṁ / s and, with q̈ = 0,
  c̈ = (0, 0, 2 vx²/a - 2 vy²/b) - (R/s) (2 (n·ṁ) ṅ + (ṅ·ṁ) n)   ("kappa" below).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from .compilation.jit import inline, jit
from .compilation.specialise import (  # the compile-time flags the kernels test (see there)
    COULOMB_ON,
    ION_ON,
    ROLLING_ON,
    SLIPPING_ON,
    specialisable,
)
from .scene import (
    COULOMB,
    ION_PAUL,
    ION_RRF,
    P_A,
    P_ALPHA,
    P_B,
    P_DRAG_LINEAR,
    P_DRAG_QUADRATIC,
    P_DRILL,
    P_G,
    P_MU,
    P_MU_STATIC,
    P_R,
    P_RESIST,
    P_SPIN_BAND,
    P_SURFACE_DRAG,
    P_TILT_FORCE,
    ROLLING,
    SLIPPING,
)

STATE_WIDTH = 9
# The longest state without its work slot (coulomb): the padded width of the public batch
# API's states (`saddle_env.simulate.simulate_batch`).
DYNAMICS_WIDTH = 7
# The slots a row holds in use: every model but coulomb ends at its work slot (slot 5 at
# most). The hot loops that copy the other models' rows stop there, with this constant as
# their length (the environment's step, `integrators.integrate_h`): the slots coulomb
# needs then cost those balls nothing (see `envs.control_step._step_range` for what they cost
# when they did).
ROW_WIDTH = 6
# A coulomb ball's phase, in the last slot: never integrated, switched by the integrator's
# loop at a stick-slip transition (saddle_env.integrators) and read by `rhs`.
PHASE_SLOT = 8
# ONSET is slip that has just begun from v_s = 0 and is still below the integration's noise
# level: the friction then acts against the slip the other forces start (its direction cannot
# be read off a slip velocity that small). Users see it as slip.
STICK, SLIP, ONSET = 0.0, 1.0, 2.0

# Layout of a drive row: the saddle speed
# Ω(t) = w0 + rate·t + decay·exp(-decay_rate·t) + amp·sin(freq·t + phase),
# the saddle angle θ0 at t = 0, and a horizontal force per unit mass (fx, fy) [m/s²] fixed
# in the laboratory (air currents), which the rotating frame sees turn at -Ω. The
# exponential term is a DC motor driven by a constant voltage (τ Ω̇ = K V − Ω: w0 = K V,
# decay = Ω(0) − K V, decay_rate = 1/τ), so the equations of motion see its exact Ω and Ω̇;
# decay = 0 (every other caller) skips it.
(DRIVE_W0, DRIVE_RATE, DRIVE_AMP, DRIVE_FREQ, DRIVE_PHASE, DRIVE_THETA0, DRIVE_FX, DRIVE_FY,
 DRIVE_DECAY, DRIVE_DECAY_RATE) = range(10)
DRIVE_WIDTH = 10

# Layout of the per-row observables written by `observables`.
OBS_VX, OBS_VY, OBS_N, OBS_H, OBS_CX, OBS_CY, OBS_CZ, OBS_OMEGA = range(8)
OBS_WIDTH = 8

@jit
def omega_at(prof, t):
    """Saddle speed Ω(t) [rad/s] and its rate Ω̇(t) [rad/s²] from a profile row."""
    w0, rate, amp = prof[DRIVE_W0], prof[DRIVE_RATE], prof[DRIVE_AMP]
    w, wd = w0 + rate * t, rate
    decay = prof[DRIVE_DECAY]
    if decay != 0.0:  # a voltage-driven motor relaxing to its steady speed w0
        e = decay * math.exp(-prof[DRIVE_DECAY_RATE] * t)
        w, wd = w + e, wd - prof[DRIVE_DECAY_RATE] * e
    if amp == 0.0:  # no ripple: skip the trigonometry (most calls)
        return w, wd
    freq = prof[DRIVE_FREQ]
    phase = freq * t + prof[DRIVE_PHASE]
    return w + amp * math.sin(phase), wd + amp * freq * math.cos(phase)


@jit
def angle_at(prof, t):
    """Saddle angle θ(t) = θ0 + ∫₀ᵗ Ω dt' [rad]."""
    amp, freq, phase = prof[DRIVE_AMP], prof[DRIVE_FREQ], prof[DRIVE_PHASE]
    theta = prof[DRIVE_THETA0] + prof[DRIVE_W0] * t + 0.5 * prof[DRIVE_RATE] * t * t
    decay = prof[DRIVE_DECAY]
    if decay != 0.0:  # ∫ decay·e^{-k t'} dt' = decay (1 − e^{-k t}) / k
        k = prof[DRIVE_DECAY_RATE]
        theta -= decay * math.expm1(-k * t) / k
    if freq != 0.0:
        return theta + amp / freq * (math.cos(phase) - math.cos(freq * t + phase))
    if amp == 0.0 and theta != 0.0 and math.isfinite(phase) and math.isfinite(t):
        return theta  # the term below is ±0, which leaves θ ≠ 0 as it is: spare the sin
    return theta + amp * math.sin(phase) * t


# What `geometry` returns, by name (a namedtuple of floats compiles to the same registers as
# a plain tuple): s = |m|, the unit normal n, the ball's centre c and the columns
# J1 = dc/dx, J2 = dc/dy of its Jacobian.
Geometry = namedtuple("Geometry", "s nx ny nz cx cy cz J1x J1y J1z J2x J2y J2z")


@jit
def geometry(a, b, R, x, y):
    """Normal, centre and the two columns of J = dc/dq at contact point (x, y).

    Returns a `Geometry` ``(s, nx, ny, nz, cx, cy, cz, J1x, J1y, J1z, J2x, J2y, J2z)``.
    """
    # Reciprocals once: divisions dominate the cost of the right-hand side.
    ia, ib = 1.0 / a, 1.0 / b
    fx = 2.0 * x * ia
    fy = -2.0 * y * ib
    s = math.sqrt(1.0 + fx * fx + fy * fy)
    nz = 1.0 / s
    nx, ny = -fx * nz, -fy * nz
    cx = x + R * nx
    cy = y + R * ny
    cz = (x * x * ia - y * y * ib) + R * nz
    # dn/dq_i = P (dm/dq_i) / s with dm/dx = (-2/a, 0, 0), dm/dy = (0, 2/b, 0).
    k1 = -2.0 * R * ia * nz
    k2 = 2.0 * R * ib * nz
    J1x = 1.0 + k1 * (1.0 - nx * nx)
    J1y = -k1 * ny * nx
    J1z = fx - k1 * nz * nx
    J2x = -k2 * nx * ny
    J2y = 1.0 + k2 * (1.0 - ny * ny)
    J2z = fy - k2 * nz * ny
    return Geometry(s, nx, ny, nz, cx, cy, cz, J1x, J1y, J1z, J2x, J2y, J2z)


@jit
def _solve_tangent(J1x, J1y, J1z, J2x, J2y, J2z, rx, ry, rz):
    """Least-squares coordinates u with J u = tangential part of r: (JᵀJ) u = Jᵀ r."""
    g11 = J1x * J1x + J1y * J1y + J1z * J1z
    g12 = J1x * J2x + J1y * J2y + J1z * J2z
    g22 = J2x * J2x + J2y * J2y + J2z * J2z
    b1 = J1x * rx + J1y * ry + J1z * rz
    b2 = J2x * rx + J2y * ry + J2z * rz
    inv_det = 1.0 / (g11 * g22 - g12 * g12)
    return (g22 * b1 - g12 * b2) * inv_det, (g11 * b2 - g12 * b1) * inv_det


@jit
def _normal_rate(a, b, s, nx, ny, nz, vx, vy):
    """ṁ (its z part is 0), n·ṁ and ṅ for contact-point velocity (vx, vy)."""
    mdx = -2.0 * vx * (1.0 / a)
    mdy = 2.0 * vy * (1.0 / b)
    nm = nx * mdx + ny * mdy
    inv_s = nz  # n_z = 1/s
    return mdx, mdy, nm, (mdx - nx * nm) * inv_s, (mdy - ny * nm) * inv_s, -nz * nm * inv_s


@jit
def frame_terms(prof, t, tilt_force):
    """Ω(t) [rad/s], Ω̇(t) [rad/s²] and the lab-fixed force per unit mass turned into the
    saddle's axes at t [m/s²]: everything the rates need from the drive row, with a tilted
    axis's share of gravity, ``tilt_force`` = g·sin(tilt) along the laboratory's x axis
    (the scene's `P_TILT_FORCE`), added to the drive's own force."""
    Om, Omd = omega_at(prof, t)
    fx, fy = prof[DRIVE_FX] + tilt_force, prof[DRIVE_FY]
    if fx == 0.0 and fy == 0.0:
        return Om, Omd, 0.0, 0.0
    th = angle_at(prof, t)
    ct, st = math.cos(th), math.sin(th)
    return Om, Omd, ct * fx + st * fy, -st * fx + ct * fy


@inline
def rim_margin(rim, square, x, y):
    """Positive while the contact point (x, y) [m, saddle axes] is inside the saddle's edge:
    rim² - (x² + y²) for a round saddle of radius ``rim``, rim - max(|x|, |y|) for a square
    one of half-width ``rim`` (``square`` = the scene's `P_RIM_SQUARE`, 1.0 or 0.0). Both
    are continuous and change sign on the edge, which is all event location needs."""
    if square != 0.0:
        return rim - max(abs(x), abs(y))
    return rim * rim - (x * x + y * y)


@jit
def _effective_gravity(g, Om, Omd, fx, fy, cx, cy, cdx, cdy):
    """g_eff = -g k - Ω̇ k×c - 2Ω k×ċ - Ω² k×(k×c) (gravity, Euler, Coriolis, centrifugal)
    plus the external horizontal force (fx, fy), already in the saddle's axes."""
    Om2 = Om * Om
    gx = Omd * cy + 2.0 * Om * cdy + Om2 * cx + fx
    gy = -Omd * cx - 2.0 * Om * cdx + Om2 * cy + fy
    return gx, gy, -g


@jit
def sized(model, drill, drag_linear, drag_quadratic, resist, surface_drag):
    """How many leading state slots the integrator advances: the dynamics (5 rolling, 4
    otherwise), plus the work slot W when the scene dissipates (air or surface drag;
    drilling friction or rolling resistance on a rolling ball). From the scene's dissipation
    coefficients (`integrated_size` takes the packed row)."""
    drag = drag_linear != 0.0 or drag_quadratic != 0.0 or surface_drag != 0.0
    if model == ROLLING:
        return 6 if (drag or drill != 0.0 or resist != 0.0) else 5
    if model == COULOMB:
        return 8  # kinetic friction dissipates whenever the ball slips
    return 5 if (model == SLIPPING and drag) else 4


@jit
def work_slot(model):
    """The state slot that holds the dissipated work W: right after the dynamics."""
    if model == ROLLING:
        return 5
    return 7 if model == COULOMB else 4


@jit
def integrated_size(model, p):
    """`sized` for the packed parameter row ``p``."""
    return sized(model, p[P_DRILL], p[P_DRAG_LINEAR], p[P_DRAG_QUADRATIC], p[P_RESIST],
                 p[P_SURFACE_DRAG])


@inline
def _air_drag(drag_linear, drag_quadratic, surface_drag, Om, cx, cy, cdx, cdy, cdz):
    """Air and surface drag per unit mass on the centre [m/s²], in the saddle's axes, and
    their power [W/kg] in the rotating frame, f·ċ. The air is still in the laboratory, so
    the centre moves through it at u = ċ + Ω k×c; the surface drag acts against ċ itself."""
    ux = cdx - Om * cy
    uy = cdy + Om * cx
    uz = cdz
    k = drag_linear
    if drag_quadratic != 0.0:
        k += drag_quadratic * math.sqrt(ux * ux + uy * uy + uz * uz)
    fx, fy, fz = -k * ux, -k * uy, -k * uz
    if surface_drag != 0.0:
        fx, fy, fz = fx - surface_drag * cdx, fy - surface_drag * cdy, fz - surface_drag * cdz
    return fx, fy, fz, fx * cdx + fy * cdy + fz * cdz


@inline
def _resistance(resist, band, R, normal, nx, ny, nz, nw, wx, wy, wz):
    """Rolling resistance c_rr: the factor k with τ/(m R²) = k·w_t (w_t = w - (n·w) n, the
    rolling part of the spin relative to the saddle; τ = -c_rr R N ŵ_t), its power
    τ·w/m = -c_rr R (N/m) |w_t| [W/kg], and whether the ball does not roll (`_resting`: k and
    the power are then 0, and the torque is the static one, `_static_resistance`)."""
    wt = _rolling_part(nx, ny, nz, nw, wx, wy, wz)[3]
    if _resting(R, band, wt, wx, wy, wz):
        return 0.0, 0.0, True
    return -resist * normal / (R * wt), -resist * R * normal * wt, False


@inline
def _rolling_part(nx, ny, nz, nw, wx, wy, wz):
    """The rolling part of the spin, w_t = w - (n·w) n (``nw`` = n·w), and its size |w_t|."""
    wtx, wty, wtz = wx - nw * nx, wy - nw * ny, wz - nw * nz
    return wtx, wty, wtz, math.sqrt(wtx * wtx + wty * wty + wtz * wtz)


# A ball whose rolling spin w_t is this small (against its spin, or against sqrt(1 m/s² / R)
# when it barely spins) does not roll: it rests on the saddle, or only spins about the normal.
# Rolling resistance then holds it so, as static friction would, while the torque that takes
# stays within c_rr R N (`_static_resistance`). A ball started at rest has w_t = 0 exactly; held,
# its w_t stays at the rounding level of the torque balance (1e-16 of the terms, which grows
# it by about 1e-14 rad/s per second), far below this.
REST_SPIN = 1e-12


@inline
def _resting(R, band, wt, wx, wy, wz):
    """Whether a ball with rolling spin |w_t| = ``wt`` [rad/s] does not roll: within ``band``
    (the integration's noise, `scene.P_SPIN_BAND`) or rounding (REST_SPIN)."""
    return wt <= band or wt <= REST_SPIN * (math.sqrt(wx * wx + wy * wy + wz * wz)
                                            + 1.0 / math.sqrt(R))


@inline
def _static_resistance(cap, hx, hy, hz):
    """The resistance on a ball that does not roll, as a term in the rolling equation: the
    term ``h`` that would keep it so, if it is within ``cap`` (c_rr N/m / R, the most the
    resistance gives), else ``cap`` along ``h`` (the ball starts to roll against it); and
    whether it holds."""
    need = math.sqrt(hx * hx + hy * hy + hz * hz)
    if need <= cap:
        return hx, hy, hz, True
    k = cap / need
    return k * hx, k * hy, k * hz, False


@inline
def rolling_rates(a, b, R, alpha, g, drill, drag_linear, drag_quadratic, surface_drag, resist,
                  band, Om, Omd, fx, fy, x, y, wx, wy, wz):
    """Time derivatives of a rolling ball's state (x, y, wx, wy, wz), the dissipated power
    Ẇ [W/kg] and N/m [m/s²].

    Scalars in, scalars out, always inlined: the same code serves `rhs` and the SIMD lanes
    of `saddle_env.lockstep` (a call would stop the compiler from vectorising the loop).
    (Om, Omd, fx, fy) come from `frame_terms`.
    """
    s, nx, ny, nz, cx, cy, cz, J1x, J1y, J1z, J2x, J2y, J2z = geometry(a, b, R, x, y)
    # Rolling constraint ċ = R w × n fixes the contact-point velocity.
    cdx = R * (wy * nz - wz * ny)
    cdy = R * (wz * nx - wx * nz)
    cdz = R * (wx * ny - wy * nx)
    vx, vy = _solve_tangent(J1x, J1y, J1z, J2x, J2y, J2z, cdx, cdy, cdz)
    mdx, mdy, nm, ndx, ndy, ndz = _normal_rate(a, b, s, nx, ny, nz, vx, vy)
    gx, gy, gz = _effective_gravity(g, Om, Omd, fx, fy, cx, cy, cdx, cdy)
    power = 0.0
    if drag_linear != 0.0 or drag_quadratic != 0.0 or surface_drag != 0.0:
        # Drag is a force on the centre, like gravity: it joins g_eff (and so the contact
        # force, which keeps the ball rolling, takes its share).
        dx, dy, dz, power = _air_drag(drag_linear, drag_quadratic, surface_drag, Om, cx, cy, cdx,
                                      cdy, cdz)
        gx, gy, gz = gx + dx, gy + dy, gz + dz
    # Euler's equation with the contact force eliminated:
    # [(1+α) 1 - n nᵀ] ẇ = -α(Ω̇ k + Ω k×w) - n×(w×ṅ) + n×g_eff/R, and n×(w×ṅ) = -(n·w) ṅ
    # because n·ṅ = 0. The matrix is inverted in closed form (Sherman–Morrison):
    # its inverse is (1 + n nᵀ/α)/(1+α).
    iR = 1.0 / R
    nw = nx * wx + ny * wy + nz * wz
    rx = alpha * Om * wy + nw * ndx + (ny * gz - nz * gy) * iR
    ry = -alpha * Om * wx + nw * ndy + (nz * gx - nx * gz) * iR
    rz = -alpha * Omd + nw * ndz + (nx * gy - ny * gx) * iR
    # n·r / α: only the frame terms survive (n·ṅ = 0, n·(n×·) = 0).
    nr_over_alpha = -(Omd * nz + Om * (ny * wx - nx * wy))
    inv = 1.0 / (1.0 + alpha)
    drl = drill * nw
    # N/m = n·(c̈ - g_eff) with n·c̈ = R n·(w×ṅ) (the ẇ×n part is tangential).
    wnx = wy * ndz - wz * ndy
    wny = wz * ndx - wx * ndz
    wnz = wx * ndy - wy * ndx
    normal = R * (nx * wnx + ny * wny + nz * wnz) - (nx * gx + ny * gy + nz * gz)
    if resist != 0.0:
        # Rolling resistance: the torque τ/m = -c_rr R (N/m) ŵ_t on the rolling part w_t of
        # the spin joins Euler's equation as τ/(m R²) (tangential, so n·r is unchanged).
        k, rpower, resting = _resistance(resist, band, R, normal, nx, ny, nz, nw, wx, wy, wz)
        if not resting:
            rx, ry, rz = (rx + k * (wx - nw * nx), ry + k * (wy - nw * ny),
                          rz + k * (wz - nw * nz))
        else:
            # Not rolling: the static torque keeps P ẇ = (n·w) ṅ (w_t stays 0) if it can. The
            # tangential ẇ is P r/(1+α), so the term it needs is (1+α)(n·w) ṅ - P r.
            nr = nx * rx + ny * ry + nz * rz
            spun = 1.0 + alpha
            hx, hy, hz, _ = _static_resistance(
                max(resist * normal * iR, 0.0), spun * nw * ndx - (rx - nr * nx),
                spun * nw * ndy - (ry - nr * ny), spun * nw * ndz - (rz - nr * nz))
            rx, ry, rz = rx + hx, ry + hy, rz + hz
            power += R * R * (hx * wx + hy * wy + hz * wz)  # τ·w/m, τ/m = R² h
        power += rpower
    # Drilling friction's power: α R² w·ẇ of its term -λ (n·w) n (the term is normal, so
    # the centre's acceleration does not see it).
    power -= alpha * R * R * drl * nw
    return (vx, vy, (rx + nr_over_alpha * nx) * inv - drl * nx,
            (ry + nr_over_alpha * ny) * inv - drl * ny,
            (rz + nr_over_alpha * nz) * inv - drl * nz, power, normal)


@inline
def _centre_motion(a, b, R, g, drag_linear, drag_quadratic, surface_drag, Om, Omd, fx, fy, s, nx,
                   ny, nz, cx, cy, J1x, J1y, J1z, J2x, J2y, J2z, vx, vy):
    """What moving the contact point at (vx, vy) means for the centre, shared by the slipping
    and coulomb rates: ċ = J q̇, ṅ, κ = J̇ q̇ (c̈ when q̈ = 0), the effective field g_eff with
    the air drag in it, and the drag's power [W/kg]."""
    cdx = J1x * vx + J2x * vy
    cdy = J1y * vx + J2y * vy
    cdz = J1z * vx + J2z * vy
    mdx, mdy, nm, ndx, ndy, ndz = _normal_rate(a, b, s, nx, ny, nz, vx, vy)
    ndm = ndx * mdx + ndy * mdy
    kR = R * nz  # R/s
    kapx = -kR * (2.0 * nm * ndx + ndm * nx)
    kapy = -kR * (2.0 * nm * ndy + ndm * ny)
    kapz = 2.0 * (vx * vx / a - vy * vy / b) - kR * (2.0 * nm * ndz + ndm * nz)
    gx, gy, gz = _effective_gravity(g, Om, Omd, fx, fy, cx, cy, cdx, cdy)
    power = 0.0
    if drag_linear != 0.0 or drag_quadratic != 0.0 or surface_drag != 0.0:
        dx, dy, dz, power = _air_drag(drag_linear, drag_quadratic, surface_drag, Om, cx, cy, cdx,
                                      cdy, cdz)
        gx, gy, gz = gx + dx, gy + dy, gz + dz
    return cdx, cdy, cdz, ndx, ndy, ndz, kapx, kapy, kapz, gx, gy, gz, power


@inline
def slipping_rates(a, b, R, g, drag_linear, drag_quadratic, surface_drag, Om, Omd, fx, fy, x, y,
                   vx, vy):
    """Time derivatives of a slipping ball's state (x, y, vx, vy), the dissipated power Ẇ
    [W/kg] and N/m [m/s²]; the point model is R = 0. Inlined like `rolling_rates`."""
    s, nx, ny, nz, cx, cy, cz, J1x, J1y, J1z, J2x, J2y, J2z = geometry(a, b, R, x, y)
    (cdx, cdy, cdz, ndx, ndy, ndz, kapx, kapy, kapz, gx, gy, gz,
     power) = _centre_motion(a, b, R, g, drag_linear, drag_quadratic, surface_drag, Om, Omd, fx,
                             fy, s, nx, ny, nz, cx, cy, J1x, J1y, J1z, J2x, J2y, J2z, vx, vy)
    # The centre is a particle on the offset surface: q̈ = (JᵀJ)⁻¹ Jᵀ (g_eff - J̇ q̇).
    rx, ry, rz = gx - kapx, gy - kapy, gz - kapz
    ax, ay = _solve_tangent(J1x, J1y, J1z, J2x, J2y, J2z, rx, ry, rz)
    # N/m = n·(c̈ - g_eff) and n·J q̈ = 0.
    return vx, vy, ax, ay, power, -(nx * rx + ny * ry + nz * rz)


@inline
def _push(R, gx, gy, gz, ex, ey, ez, wx, wy, wz, nx, ny, nz, ndx, ndy, ndz):
    """The push a0 = P g_eff + R e×n - R P(w×ṅ) the forces but friction give a coulomb ball's
    slip (e×n is tangential already)."""
    ux = gx + R * (ey * nz - ez * ny) - R * (wy * ndz - wz * ndy)
    uy = gy + R * (ez * nx - ex * nz) - R * (wz * ndx - wx * ndz)
    uz = gz + R * (ex * ny - ey * nx) - R * (wx * ndy - wy * ndx)
    un = nx * ux + ny * uy + nz * uz
    return ux - un * nx, uy - un * ny, uz - un * nz


@inline
def _friction(phase, mu, normal, gain, a0x, a0y, a0z, vsx, vsy, vsz, speed):
    """A coulomb ball's friction per unit mass and the growth of its slip speed [m/s²], given
    the push a0 and the slip v_s, with v̇_s = a0 + ``gain``·f: sticking, the friction that keeps
    v_s = 0; slipping, -μ N v̂_s; at onset, -μ N â0 (see `coulomb_rates`)."""
    if phase == STICK:
        return -a0x / gain, -a0y / gain, -a0z / gain, 0.0
    if phase != ONSET and speed > 0.0:
        k = -mu * normal / speed
        return (k * vsx, k * vsy, k * vsz,
                (vsx * a0x + vsy * a0y + vsz * a0z) / speed - gain * mu * normal)
    a0 = math.sqrt(a0x * a0x + a0y * a0y + a0z * a0z)
    k = -mu * normal / a0 if a0 > 0.0 else 0.0
    return k * a0x, k * a0y, k * a0z, a0 - gain * mu * normal


@inline
def coulomb_rates(a, b, R, alpha, g, drill, drag_linear, drag_quadratic, surface_drag, resist,
                  band, mu, phase, Om, Omd, fx, fy, x, y, wx, wy, wz, vx, vy):
    """Time derivatives of a coulomb ball's state (x, y, wx, wy, wz, vx, vy), Ẇ [W/kg], N/m
    [m/s²], the friction per unit mass |f| [m/s²], the slip speed |v_s| [m/s] and the rate at
    which the slip speed grows [m/s²] (docs/physics.md, "Coulomb friction").

    The ball's centre obeys c̈ = g_eff + f + (N/m) n and its spin
    ẇ = -(Ω̇ k + Ω k×w) - n×f/(αR) (- drilling friction), with the friction f tangential. The
    material point at the contact slips at v_s = ċ - R w×n, and
    v̇_s = a0 + (1 + 1/α) f with a0 what the other forces give it. Sticking (``phase``
    STICK): f = -P a0/(1 + 1/α), the friction that keeps v_s = 0, and the contact-point
    velocity is the rolling one, from w (the state's (vx, vy) are then only carried along),
    so the stick phase is exactly the rolling model. Slipping: f = -μ N v_s/|v_s|; as slip
    starts (``phase`` ONSET) the friction opposes the slip that a0 starts, -μ N a0/|a0|.
    """
    slipping = phase != STICK
    s, nx, ny, nz, cx, cy, cz, J1x, J1y, J1z, J2x, J2y, J2z = geometry(a, b, R, x, y)
    wnx = wy * nz - wz * ny
    wny = wz * nx - wx * nz
    wnz = wx * ny - wy * nx
    if not slipping:
        vx, vy = _solve_tangent(J1x, J1y, J1z, J2x, J2y, J2z, R * wnx, R * wny, R * wnz)
    (cdx, cdy, cdz, ndx, ndy, ndz, kapx, kapy, kapz, gx, gy, gz,
     power) = _centre_motion(a, b, R, g, drag_linear, drag_quadratic, surface_drag, Om, Omd, fx,
                             fy, s, nx, ny, nz, cx, cy, J1x, J1y, J1z, J2x, J2y, J2z, vx, vy)
    normal = nx * (kapx - gx) + ny * (kapy - gy) + nz * (kapz - gz)
    # e = Ω̇ k + Ω k×w; a0 = P g_eff + R e×n - R P(w×ṅ) (e×n is tangential already).
    ex, ey, ez = -Om * wy, Om * wx, Omd
    nw = nx * wx + ny * wy + nz * wz
    rpower = 0.0
    resting = False
    if resist != 0.0:
        # Rolling resistance: ẇ gains τ/(m α R²) = (k/α) w_t, which e carries like a frame
        # term (so the slip's a0 and the sticking friction see it too).
        k, rpower, resting = _resistance(resist, band, R, normal, nx, ny, nz, nw, wx, wy, wz)
        k = k / alpha
        ex, ey, ez = ex - k * (wx - nw * nx), ey - k * (wy - nw * ny), ez - k * (wz - nw * nz)
    a0x, a0y, a0z = _push(R, gx, gy, gz, ex, ey, ez, wx, wy, wz, nx, ny, nz, ndx, ndy, ndz)
    vsx, vsy, vsz = cdx - R * wnx, cdy - R * wny, cdz - R * wnz
    speed = math.sqrt(vsx * vsx + vsy * vsy + vsz * vsz)
    gain = 1.0 + 1.0 / alpha
    if resting:
        # A ball that does not roll (`_resting`): the static resistance term h in ẇ keeps
        # P ẇ = (n·w) ṅ if it can, so the spin stays locked and the contact moves like a
        # slider's, v̇_s = b + f with the push b = a0 - R ((n·w) ṅ + P e)×n (gain 1). The
        # term that takes is h = (n·w) ṅ + P e + n×f/(αR), within c_rr N/m/(αR).
        pe = nx * ex + ny * ey + nz * ez
        tx, ty, tz = nw * ndx + ex - pe * nx, nw * ndy + ey - pe * ny, nw * ndz + ez - pe * nz
        bx = a0x - R * (ty * nz - tz * ny)
        by = a0y - R * (tz * nx - tx * nz)
        bz = a0z - R * (tx * ny - ty * nx)
        ffx, ffy, ffz, growth = _friction(phase, mu, normal, 1.0, bx, by, bz, vsx, vsy, vsz,
                                          speed)
        iaR = 1.0 / (alpha * R)
        hx, hy, hz, held = _static_resistance(
            max(resist * normal * iaR, 0.0), tx + (ny * ffz - nz * ffy) * iaR,
            ty + (nz * ffx - nx * ffz) * iaR, tz + (nx * ffy - ny * ffx) * iaR)
        ex, ey, ez = ex - hx, ey - hy, ez - hz
        rpower = alpha * R * R * (hx * wx + hy * wy + hz * wz)  # τ·w/m, τ/m = α R² h
        a0x, a0y, a0z = bx, by, bz
        if not held:
            # held only up to its limit: the ball starts to roll, and friction acts as usual
            a0x, a0y, a0z = _push(R, gx, gy, gz, ex, ey, ez, wx, wy, wz, nx, ny, nz, ndx, ndy,
                                  ndz)
            ffx, ffy, ffz, growth = _friction(phase, mu, normal, gain, a0x, a0y, a0z, vsx,
                                              vsy, vsz, speed)
    else:
        ffx, ffy, ffz, growth = _friction(phase, mu, normal, gain, a0x, a0y, a0z, vsx, vsy,
                                          vsz, speed)
    # The centre: q̈ = (JᵀJ)⁻¹ Jᵀ (g_eff + f - J̇ q̇).
    ax, ay = _solve_tangent(J1x, J1y, J1z, J2x, J2y, J2z, gx + ffx - kapx, gy + ffy - kapy,
                            gz + ffz - kapz)
    # The spin: -n×f/(αR) is the friction's torque.
    iaR = 1.0 / (alpha * R)
    drl = drill * nw
    dwx = -ex - (ny * ffz - nz * ffy) * iaR - drl * nx
    dwy = -ey - (nz * ffx - nx * ffz) * iaR - drl * ny
    dwz = -ez - (nx * ffy - ny * ffx) * iaR - drl * nz
    # Friction's power in the rotating frame is f·v_s (0 while sticking); drilling's as rolling.
    power += ffx * vsx + ffy * vsy + ffz * vsz - alpha * R * R * drl * nw + rpower
    friction = math.sqrt(ffx * ffx + ffy * ffy + ffz * ffz)
    return (vx, vy, dwx, dwy, dwz, ax, ay, power, normal, friction, speed, growth, vsx, vsy, vsz,
            a0x, a0y, a0z)


@jit
def coulomb_contact(p, prof, t, y):
    """A coulomb ball's contact at (t, y) in its current phase, for the loop's phase decisions:
    (N/m, |f|, |v_s|, growth of |v_s|) as `coulomb_rates` defines them, the push |a0| [m/s²]
    the other forces give the slip, and the slip's part across a0, |v_s - (v_s·â0) â0| [m/s]
    (how far a slip that started along a0 lags behind a0's turning)."""
    Om, Omd, fx, fy = frame_terms(prof, t, p[P_TILT_FORCE])
    r = coulomb_rates(p[P_A], p[P_B], p[P_R], p[P_ALPHA], p[P_G], p[P_DRILL], p[P_DRAG_LINEAR],
                      p[P_DRAG_QUADRATIC], p[P_SURFACE_DRAG], p[P_RESIST], p[P_SPIN_BAND], p[P_MU], y[PHASE_SLOT], Om,
                      Omd, fx, fy, y[0], y[1], y[2], y[3], y[4], y[5], y[6])
    a0x, a0y, a0z = r[15], r[16], r[17]
    return (r[8], r[9], r[10], r[11], math.sqrt(a0x * a0x + a0y * a0y + a0z * a0z),
            slip_lag(r[12], r[13], r[14], a0x, a0y, a0z))


@inline
def slip_lag(vsx, vsy, vsz, a0x, a0y, a0z):
    """The slip velocity's part across the push a0, |v_s × a0|/|a0| [m/s] (0 without a push):
    computed as a cross product, free of the cancellation in |v_s|² - (v_s·â0)²."""
    push = math.sqrt(a0x * a0x + a0y * a0y + a0z * a0z)
    if push == 0.0:
        return 0.0
    kx = vsy * a0z - vsz * a0y
    ky = vsz * a0x - vsx * a0z
    kz = vsx * a0y - vsy * a0x
    return math.sqrt(kx * kx + ky * ky + kz * kz) / push


@jit
def stick_margin(p, prof, t, y):
    """μ_s N/m - |f| [m/s²] for the friction that would keep the ball sticking at (t, y):
    positive while static friction can hold it."""
    Om, Omd, fx, fy = frame_terms(prof, t, p[P_TILT_FORCE])
    r = coulomb_rates(p[P_A], p[P_B], p[P_R], p[P_ALPHA], p[P_G], p[P_DRILL], p[P_DRAG_LINEAR],
                      p[P_DRAG_QUADRATIC], p[P_SURFACE_DRAG], p[P_RESIST], p[P_SPIN_BAND], p[P_MU], STICK, Om, Omd,
                      fx, fy, y[0], y[1], y[2], y[3], y[4], y[5], y[6])
    return p[P_MU_STATIC] * r[8] - r[9]


@jit
def stop_slip(p, prof, t, y):
    """Stop a coulomb ball's (small) slip with the friction impulse that does it: Δċ = P,
    Δw = -n×P/(αR), P = -α v_s/(1 + α), so v_s becomes 0 exactly (P = -v_s and Δw = 0 for a
    ball that rolling resistance keeps from rolling); the kinetic energy this takes, of order
    |v_s|², is added to the work slot."""
    a, b, R, alpha = p[P_A], p[P_B], p[P_R], p[P_ALPHA]
    before = jacobi(COULOMB, p, prof, t, y)
    s, nx, ny, nz, cx, cy, cz, J1x, J1y, J1z, J2x, J2y, J2z = geometry(a, b, R, y[0], y[1])
    wx, wy, wz = y[2], y[3], y[4]
    k = -alpha / (1.0 + alpha)
    iaR = 1.0 / (alpha * R)
    if p[P_RESIST] != 0.0:
        wt = _rolling_part(nx, ny, nz, nx * wx + ny * wy + nz * wz, wx, wy, wz)[3]
        if _resting(R, p[P_SPIN_BAND], wt, wx, wy, wz):
            # A ball that does not roll slides like a slider (`coulomb_rates`): its slip stops
            # with its spin as it is (Δċ = -v_s; P = -v_s, and no Δw below).
            k, iaR = -1.0, 0.0
    Px = k * (J1x * y[5] + J2x * y[6] - R * (wy * nz - wz * ny))
    Py = k * (J1y * y[5] + J2y * y[6] - R * (wz * nx - wx * nz))
    Pz = k * (J1z * y[5] + J2z * y[6] - R * (wx * ny - wy * nx))
    y[2] -= (ny * Pz - nz * Py) * iaR
    y[3] -= (nz * Px - nx * Pz) * iaR
    y[4] -= (nx * Py - ny * Px) * iaR
    rolling_velocity(p, y, y)
    phase = y[PHASE_SLOT]
    y[PHASE_SLOT] = STICK  # the velocity now follows from the spin
    y[work_slot(COULOMB)] += jacobi(COULOMB, p, prof, t, y) - before
    y[PHASE_SLOT] = phase


@jit
def rolling_spin(p, y, dy):
    """A rolling or coulomb ball's rolling spin |w_t| [rad/s] (w_t = w - (n·w) n) and its
    rate d|w_t|/dt = ŵ_t·(ẇ - (n·w) ṅ) [rad/s²], from the state and its rates ``dy``
    (whose first two slots are the contact-point velocity for both models); (0, 0) for a
    ball that does not roll."""
    a, b, R = p[P_A], p[P_B], p[P_R]
    s, nx, ny, nz, cx, cy, cz, J1x, J1y, J1z, J2x, J2y, J2z = geometry(a, b, R, y[0], y[1])
    wx, wy, wz = y[2], y[3], y[4]
    nw = nx * wx + ny * wy + nz * wz
    wtx, wty, wtz, wt = _rolling_part(nx, ny, nz, nw, wx, wy, wz)
    if wt == 0.0:
        return 0.0, 0.0
    mdx, mdy, nm, ndx, ndy, ndz = _normal_rate(a, b, s, nx, ny, nz, dy[0], dy[1])
    return wt, (wtx * (dy[2] - nw * ndx) + wty * (dy[3] - nw * ndy)
                + wtz * (dy[4] - nw * ndz)) / wt


# The part of c_rr N/m / R (the most the static resistance gives, in ẇ's units) that a
# held ball's rolling spin may still change at (rounding), for `spin_held`.
HELD_SPIN_DRIFT = 1e-9


@jit
def spin_held(p, y, dy, normal):
    """Whether rolling resistance holds the ball at (y, its rates ``dy``, N/m ``normal``)
    from rolling: its rolling spin does not change, to HELD_SPIN_DRIFT of what the static
    torque can give."""
    a, b, R = p[P_A], p[P_B], p[P_R]
    s, nx, ny, nz, cx, cy, cz, J1x, J1y, J1z, J2x, J2y, J2z = geometry(a, b, R, y[0], y[1])
    mdx, mdy, nm, ndx, ndy, ndz = _normal_rate(a, b, s, nx, ny, nz, dy[0], dy[1])
    nw = nx * y[2] + ny * y[3] + nz * y[4]
    nd = nx * dy[2] + ny * dy[3] + nz * dy[4]
    ux, uy, uz = dy[2] - nd * nx - nw * ndx, dy[3] - nd * ny - nw * ndy, dy[4] - nd * nz - nw * ndz
    return (normal > 0.0 and math.sqrt(ux * ux + uy * uy + uz * uz)
            <= HELD_SPIN_DRIFT * p[P_RESIST] * normal / R)


@jit
def stop_rolling(model, p, prof, t, y):
    """Stop a (slow) rolling spin: w_t becomes 0, the spin about the normal is kept; the
    kinetic energy this takes, of order |w_t|², is added to the work slot. A sticking coulomb
    ball's contact-point velocity follows (it is then at rest)."""
    before = jacobi(model, p, prof, t, y)
    s, nx, ny, nz, cx, cy, cz, J1x, J1y, J1z, J2x, J2y, J2z = geometry(p[P_A], p[P_B], p[P_R],
                                                                      y[0], y[1])
    nw = nx * y[2] + ny * y[3] + nz * y[4]
    y[2], y[3], y[4] = nw * nx, nw * ny, nw * nz
    if model == COULOMB and y[PHASE_SLOT] == STICK:
        rolling_velocity(p, y, y)
    y[work_slot(model)] += jacobi(model, p, prof, t, y) - before


@jit
def rolling_velocity(p, y, out):
    """Write the rolling contact-point velocity, from the spin, into a coulomb state's (vx, vy)
    slots: the slip velocity is then exactly 0."""
    out[5], out[6] = contact_velocity(ROLLING, p, y)


# Layout of an ion's parameter row (saddle_env.iontrap.IonTrap.params); slot P_RIM (6) is
# the escape radius, as for a ball, so the loop's escape event serves both.
I_KQUAD, I_KDC, I_OMEGA_B, I_KSTATIC = range(4)


@jit
def ion_rates(model, p, prof, t, Om, Omd, x, y, vx, vy):
    """Acceleration per unit mass of a charged particle in an ideal quadrupole trap.

    ``ION_RRF``: the quadrupole -κ(x'² - y'²)/2 rotates at Ω(t); state in the frame rotating
    with it, so ẍ = (Ω² - Ωω_B - κ + κ_t) x + Ω̇ y + (2Ω - ω_B) ẏ and
    ÿ = (Ω² - Ωω_B + κ + κ_t) y - Ω̇ x - (2Ω - ω_B) ẋ (the paper's Eq. comp2).
    ``ION_PAUL``: the quadrupole flaps, (κ_dc + κ cos θ(t))(x² - y²)/2 with θ = ∫Ω dt; state
    in the laboratory. Both add the static term κ_t (x, y) and the Lorentz acceleration
    ω_B k×v_lab. κ = p[I_KQUAD], κ_dc = p[I_KDC], ω_B = p[I_OMEGA_B], κ_t = p[I_KSTATIC].
    """
    kq, wB, kt = p[I_KQUAD], p[I_OMEGA_B], p[I_KSTATIC]
    if model == ION_RRF:
        cor = 2.0 * Om - wB
        diag = Om * Om - Om * wB + kt
        return ((diag - kq) * x + Omd * y + cor * vy,
                (diag + kq) * y - Omd * x - cor * vx)
    k = p[I_KDC] + kq * math.cos(angle_at(prof, t))
    return (kt - k) * x - wB * vy, (kt + k) * y + wB * vx


@jit
def rhs(model, p, prof, t, y, dy, want_normal):
    """Write dy/dt into ``dy``; return N/m [m/s²] if ``want_normal`` else 0.

    Parameters
    ----------
    model : int
        ``ROLLING``, ``SLIPPING`` (the point model is slipping with p[P_R] = 0), ``COULOMB``
        (its phase in y[PHASE_SLOT]), or ``ION_RRF`` / ``ION_PAUL`` (state (x, y, vx, vy);
        no normal force: returns +inf).
    p : (N_PARAMS,) float64
        Packed scene parameters (Scene.params()).
    prof : (DRIVE_WIDTH,) float64
        Drive row (Ω profile, θ0, external force).
    t : float
        Time [s].
    y, dy : (STATE_WIDTH,) float64
        State and its derivative (the work slot's derivative
        is the dissipated power; 0 when nothing dissipates). A coulomb ball's phase slot
        of ``dy`` gets the stick margin μ_s N/m - |f| [m/s²] while it sticks, the slip's
        lag behind the push [m/s] at onset, else 0.
    want_normal : bool
        Whether to return the normal force per unit mass.
    """
    Om, Omd, fx, fy = frame_terms(prof, t, p[P_TILT_FORCE])
    if ROLLING_ON and model == ROLLING:
        dy[0], dy[1], dy[2], dy[3], dy[4], dy[5], normal = rolling_rates(
            p[P_A], p[P_B], p[P_R], p[P_ALPHA], p[P_G], p[P_DRILL], p[P_DRAG_LINEAR],
            p[P_DRAG_QUADRATIC], p[P_SURFACE_DRAG], p[P_RESIST], p[P_SPIN_BAND], Om, Omd, fx, fy, y[0], y[1], y[2],
            y[3], y[4])
    elif COULOMB_ON and model == COULOMB:
        phase = y[PHASE_SLOT]
        (dy[0], dy[1], dy[2], dy[3], dy[4], dy[5], dy[6], dy[7], normal, friction, _, _, vsx,
         vsy, vsz, a0x, a0y, a0z) = coulomb_rates(
            p[P_A], p[P_B], p[P_R], p[P_ALPHA], p[P_G], p[P_DRILL], p[P_DRAG_LINEAR],
            p[P_DRAG_QUADRATIC], p[P_SURFACE_DRAG], p[P_RESIST], p[P_SPIN_BAND], p[P_MU], phase, Om, Omd, fx, fy,
            y[0], y[1], y[2], y[3], y[4], y[5], y[6])
        # The phase is not integrated, so its slot carries what the loop checks a step with,
        # at no extra cost: sticking, the stick margin μ_s N/m - |f| (at every stage, so that
        # static friction giving way briefly inside a step is seen: `rk.stick_dip`);
        # at onset, the slip's lag behind the push (`integrators._onset_error`).
        if phase == STICK:
            dy[PHASE_SLOT] = p[P_MU_STATIC] * normal - friction
        elif phase == ONSET:
            dy[PHASE_SLOT] = slip_lag(vsx, vsy, vsz, a0x, a0y, a0z)
        else:
            dy[PHASE_SLOT] = 0.0
    elif ION_ON and (model == ION_RRF or model == ION_PAUL):
        dy[0], dy[1] = y[2], y[3]
        dy[2], dy[3] = ion_rates(model, p, prof, t, Om, Omd, y[0], y[1], y[2], y[3])
        for j in range(4, STATE_WIDTH):
            dy[j] = 0.0
        normal = np.inf
    elif SLIPPING_ON:
        dy[0], dy[1], dy[2], dy[3], dy[4], normal = slipping_rates(
            p[P_A], p[P_B], p[P_R], p[P_G], p[P_DRAG_LINEAR], p[P_DRAG_QUADRATIC],
            p[P_SURFACE_DRAG], Om, Omd,
            fx, fy, y[0], y[1], y[2], y[3])
        for j in range(5, STATE_WIDTH):
            dy[j] = 0.0
    else:  # a model this copy was not compiled for (`specialise`)
        for j in range(STATE_WIDTH):
            dy[j] = np.nan
        normal = np.nan
    return normal if want_normal else 0.0


@inline
def rolling_contact_velocity(R, g, wx, wy, wz):
    """Contact-point velocity (vx, vy) of a ball of radius ``R`` rolling with spin
    (wx, wy, wz) at the contact point of `Geometry` ``g`` (the rolling constraint ċ = R w × n,
    resolved along the Jacobian's columns)."""
    nx, ny, nz = g.nx, g.ny, g.nz
    return _solve_tangent(g.J1x, g.J1y, g.J1z, g.J2x, g.J2y, g.J2z,
                          R * (wy * nz - wz * ny), R * (wz * nx - wx * nz), R * (wx * ny - wy * nx))


@jit
def contact_velocity(model, p, y):
    """Contact-point velocity (vx, vy) in the rotating frame [m/s]."""
    if model == COULOMB:
        if y[PHASE_SLOT] != STICK:
            return y[5], y[6]
    elif model != ROLLING:
        return y[2], y[3]
    R = p[P_R]
    return rolling_contact_velocity(R, geometry(p[P_A], p[P_B], R, y[0], y[1]), y[2], y[3], y[4])


@jit
def jacobi(model, p, prof, t, y):
    """Jacobi integral per unit mass [J/kg] (conserved when Ω is constant).

    rolling and coulomb: ½|ċ|² + ½ α R² |w|² - ½ Ω² (cx² + cy²) + g cz; slipping: without
    the spin term (decoupled, and constant).
    """
    a, b, R, g = p[P_A], p[P_B], p[P_R], p[P_G]
    Om = omega_at(prof, t)[0]
    s, nx, ny, nz, cx, cy, cz, J1x, J1y, J1z, J2x, J2y, J2z = geometry(a, b, R, y[0], y[1])
    vx, vy = contact_velocity(model, p, y)
    cdx = J1x * vx + J2x * vy
    cdy = J1y * vx + J2y * vy
    cdz = J1z * vx + J2z * vy
    h = 0.5 * (cdx * cdx + cdy * cdy + cdz * cdz) - 0.5 * Om * Om * (cx * cx + cy * cy) + g * cz
    if model == ROLLING or model == COULOMB:
        h += 0.5 * p[P_ALPHA] * R * R * (y[2] * y[2] + y[3] * y[3] + y[4] * y[4])
    return h


@jit
def observables(model, p, prof, T, Y, want_normal, out):
    """Fill ``out[i]`` (OBS_WIDTH columns) for every row of the trajectory ``Y`` at times ``T``."""
    dy = np.empty(STATE_WIDTH)
    for i in range(T.shape[0]):
        y = Y[i]
        vx, vy = contact_velocity(model, p, y)
        out[i, OBS_VX] = vx
        out[i, OBS_VY] = vy
        out[i, OBS_N] = rhs(model, p, prof, T[i], y, dy, True) if want_normal else np.nan
        out[i, OBS_H] = jacobi(model, p, prof, T[i], y)
        geo = geometry(p[P_A], p[P_B], p[P_R], y[0], y[1])
        out[i, OBS_CX] = geo.cx
        out[i, OBS_CY] = geo.cy
        out[i, OBS_CZ] = geo.cz
        out[i, OBS_OMEGA] = omega_at(prof, T[i])[0]


@jit
def state_from_velocity(model, p, x, y, vx, vy, spin_normal, out):
    """Build a state from the contact point, its rotating-frame velocity and (rolling,
    coulomb) the spin about the normal relative to the saddle: w = n × ċ / R + spin_normal · n,
    so a coulomb ball starts rolling without slip. No work done yet."""
    for j in range(STATE_WIDTH):
        out[j] = 0.0
    out[0] = x
    out[1] = y
    if model != ROLLING and model != COULOMB:
        out[2] = vx
        out[3] = vy
        return
    if model == COULOMB:
        out[5] = vx
        out[6] = vy
    a, b, R = p[P_A], p[P_B], p[P_R]
    s, nx, ny, nz, cx, cy, cz, J1x, J1y, J1z, J2x, J2y, J2z = geometry(a, b, R, x, y)
    cdx = J1x * vx + J2x * vy
    cdy = J1y * vx + J2y * vy
    cdz = J1z * vx + J2z * vy
    out[2] = (ny * cdz - nz * cdy) / R + spin_normal * nx
    out[3] = (nz * cdx - nx * cdz) / R + spin_normal * ny
    out[4] = (nx * cdy - ny * cdx) / R + spin_normal * nz


@jit
def lab_rest_velocity(p, Om, x, y):
    """Contact-point velocity in the rotating frame of a ball placed at rest in the laboratory.

    The centre's rotating-frame velocity is the tangential part of -Ω k×c (its normal part
    cannot be matched by a ball that stays on the surface); returns the (vx, vy) that produce it.
    """
    a, b, R = p[P_A], p[P_B], p[P_R]
    s, nx, ny, nz, cx, cy, cz, J1x, J1y, J1z, J2x, J2y, J2z = geometry(a, b, R, x, y)
    return _solve_tangent(J1x, J1y, J1z, J2x, J2y, J2z, Om * cy, -Om * cx, 0.0)


specialisable(__name__)
