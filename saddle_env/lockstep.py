"""One Runge–Kutta step for a block of balls at once, vectorised across the balls.

The environment advances every ball by the same control period, and a ball's adaptive
integrator usually takes that period as one step (its step-size hint is longer). That step
is then the same arithmetic for every ball, so here it is done on a block of balls laid
out as structure-of-arrays, ``X[component, lane]``, in loops over the lanes that the
compiler turns into SIMD instructions (4–8 balls per instruction with AVX2/AVX-512). The
rates are `kernels.rolling_rates` / `slipping_rates`, inlined — the same code `rhs` runs.

A lane's result is *accepted* only if `integrators.integrate_h` would have accepted exactly
this step: the state is finite, the error estimate is ≤ 1, no event holds at the start or
the end, and no stage point saw N < 0 (a dip inside the step). Every other ball is left for
`integrate_h` to redo, so an accepted lane is bit-for-bit the scalar integrator's result —
the operations and their order are the same, and no fused multiply-adds are allowed
(``fastmath=False``).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from .compilation.jit import jit
from .integrators import ERR_EMBEDDED, EVENT_DETACH, EVENT_ESCAPE, MAX_FACTOR, step_factor
from .kernels import (
    DRIVE_AMP,
    DRIVE_DECAY,
    DRIVE_FX,
    DRIVE_FY,
    DRIVE_RATE,
    DRIVE_W0,
    DRIVE_WIDTH,
    ROW_WIDTH,
    frame_terms,
    rim_margin,
    rolling_rates,
    sized,
    slipping_rates,
)
from .scene import (
    N_PARAMS,
    P_A,
    P_ALPHA,
    P_B,
    P_DRAG_LINEAR,
    P_DRAG_QUADRATIC,
    P_DRILL,
    P_G,
    P_R,
    P_RESIST,
    P_RIM,
    P_RIM_SQUARE,
    P_SPIN_BAND,
    P_SURFACE_DRAG,
    P_TILT_FORCE,
    ROLLING,
)

LANES = 64  # balls per block: the stage arrays of a block stay in the L1 cache
# The state slots a block steps: a rolling ball's five (a slipping ball's four) and the work
# slot. Coulomb balls never enter a block (`saddle_env.envs.control_step`).
BLOCK_WIDTH = ROW_WIDTH
PARAM_WIDTH = N_PARAMS
FRAME_WIDTH = 4  # Ω, Ω̇, fx, fy (saddle axes) at one stage time

# A block's arrays, carved from scratch memory by `carve_block` (see there).
Block = namedtuple("Block",
                   "P D Y0 Ynew Ytmp Sc K Fr Nstart Nstage Nmin Nend Err acc a5 a3 ok")


@jit
def block_size(stages):
    """Floats of scratch memory for one block with a method of ``stages`` stages."""
    return LANES * (PARAM_WIDTH + DRIVE_WIDTH + 4 * BLOCK_WIDTH
                    + (stages + 1) * (BLOCK_WIDTH + FRAME_WIDTH) + 9)


@jit
def take(buf, o, n):
    """The view ``buf[o:o + n]`` and the offset after it (for carving scratch buffers)."""
    return buf[o:o + n], o + n


@jit
def carve_block(buf, stages):
    """Views into ``buf`` (at least `block_size` floats) for one block of `LANES` lanes, a
    `Block` ``(P, D, Y0, Ynew, Ytmp, Sc, K, Fr, Nstart, Nstage, Nmin, Nend, Err, acc, a5, a3,
    ok)``:
    parameters (7, L), drive rows (L, DRIVE_WIDTH), start / end / stage states and state scales
    (5, L), stages (s + 1, 5, L), frame terms (s + 1, 4, L), N/m at the start, at the current
    stage, the smallest over the stages and at the end, error norms, three accumulators, and
    which lanes' steps are accepted (`accept_lanes`) (L,). Carving a caller-owned buffer
    keeps allocation off the per-step path."""
    L = LANES
    P, o = take(buf, 0, PARAM_WIDTH * L)
    D, o = take(buf, o, DRIVE_WIDTH * L)
    Y0, o = take(buf, o, BLOCK_WIDTH * L)
    Ynew, o = take(buf, o, BLOCK_WIDTH * L)
    Ytmp, o = take(buf, o, BLOCK_WIDTH * L)
    Sc, o = take(buf, o, BLOCK_WIDTH * L)
    K, o = take(buf, o, (stages + 1) * BLOCK_WIDTH * L)
    Fr, o = take(buf, o, (stages + 1) * FRAME_WIDTH * L)
    vec, o = take(buf, o, 9 * L)
    P, D, vec = P.reshape((PARAM_WIDTH, L)), D.reshape((L, DRIVE_WIDTH)), vec.reshape((9, L))
    Y0, Ynew = Y0.reshape((BLOCK_WIDTH, L)), Ynew.reshape((BLOCK_WIDTH, L))
    Ytmp, Sc = Ytmp.reshape((BLOCK_WIDTH, L)), Sc.reshape((BLOCK_WIDTH, L))
    K = K.reshape((stages + 1, BLOCK_WIDTH, L))
    Fr = Fr.reshape((stages + 1, FRAME_WIDTH, L))
    return Block(P, D, Y0, Ynew, Ytmp, Sc, K, Fr, vec[0], vec[1], vec[2], vec[3], vec[4], vec[5],
                 vec[6], vec[7], vec[8])


@jit
def _rates(model, m, P, fr, Y, Kout, Nout, dragged, work):
    """Rates and N/m of lanes 0..m-1 (the loops the compiler vectorises).

    ``dragged``: some lane has air drag or rolling resistance; ``work``: the block integrates
    the work slot. The
    loops are written out per case because the compiler vectorises only what is constant
    across lanes: a block without drag passes the drag coefficients as the constant 0, so
    the inlined rates lose their drag branch (a branch that may differ between lanes made
    the environment's step much slower), and a block without the work slot
    drops the power. A lane gets the same numbers in every case that applies to it."""
    if model == ROLLING and not dragged and not work:
        for q in range(m):
            (Kout[0, q], Kout[1, q], Kout[2, q], Kout[3, q], Kout[4, q], _,
             Nout[q]) = rolling_rates(
                P[P_A, q], P[P_B, q], P[P_R, q], P[P_ALPHA, q], P[P_G, q], P[P_DRILL, q],
                0.0, 0.0, 0.0, 0.0, 0.0, fr[0, q], fr[1, q], fr[2, q], fr[3, q], Y[0, q],
                Y[1, q], Y[2, q], Y[3, q], Y[4, q])
    elif model == ROLLING and not dragged:  # drilling friction only (of the dissipations)
        for q in range(m):
            (Kout[0, q], Kout[1, q], Kout[2, q], Kout[3, q], Kout[4, q], Kout[5, q],
             Nout[q]) = rolling_rates(
                P[P_A, q], P[P_B, q], P[P_R, q], P[P_ALPHA, q], P[P_G, q], P[P_DRILL, q],
                0.0, 0.0, 0.0, 0.0, 0.0, fr[0, q], fr[1, q], fr[2, q], fr[3, q], Y[0, q],
                Y[1, q], Y[2, q], Y[3, q], Y[4, q])
    elif model == ROLLING:
        for q in range(m):
            (Kout[0, q], Kout[1, q], Kout[2, q], Kout[3, q], Kout[4, q], Kout[5, q],
             Nout[q]) = rolling_rates(
                P[P_A, q], P[P_B, q], P[P_R, q], P[P_ALPHA, q], P[P_G, q], P[P_DRILL, q],
                P[P_DRAG_LINEAR, q], P[P_DRAG_QUADRATIC, q], P[P_SURFACE_DRAG, q],
                P[P_RESIST, q], P[P_SPIN_BAND, q], fr[0, q], fr[1, q], fr[2, q], fr[3, q],
                Y[0, q], Y[1, q], Y[2, q], Y[3, q], Y[4, q])
    elif not dragged:
        for q in range(m):
            (Kout[0, q], Kout[1, q], Kout[2, q], Kout[3, q], _, Nout[q]) = slipping_rates(
                P[P_A, q], P[P_B, q], P[P_R, q], P[P_G, q], 0.0, 0.0, 0.0, fr[0, q], fr[1, q],
                fr[2, q], fr[3, q], Y[0, q], Y[1, q], Y[2, q], Y[3, q])
    else:
        for q in range(m):
            (Kout[0, q], Kout[1, q], Kout[2, q], Kout[3, q], Kout[4, q], Nout[q]) = slipping_rates(
                P[P_A, q], P[P_B, q], P[P_R, q], P[P_G, q], P[P_DRAG_LINEAR, q],
                P[P_DRAG_QUADRATIC, q], P[P_SURFACE_DRAG, q], fr[0, q], fr[1, q], fr[2, q], fr[3, q], Y[0, q], Y[1, q],
                Y[2, q], Y[3, q])


@jit
def _combine(m, d, h, w, count, K, Y0, acc, Yout):
    """Yout = Y0 + h·Σ_{l < count} w[l]·K[l] for lanes 0..m-1, summed in the order `rk.stages`
    uses; components from d on (slots not integrated) are copied.

    A full block's ``d`` components are one run of ``d`` × `LANES` numbers in memory (the
    arrays are C-ordered (component, lane)) and are summed in one loop (`_combine_run`): a
    loop per component, 8 AVX-512 vectors long, spent more on entering the loop than in
    it (the stage sums were a fifth of the vector environment's step, perf, 1,024 balls).
    A partial block is summed component by component over its lanes, into ``acc``."""
    if m == LANES:
        width = BLOCK_WIDTH * LANES
        _combine_run(d * LANES, h, w, count, K.reshape((K.shape[0], width)),
                     Y0.reshape(width), Yout.reshape(width))
    else:
        for j in range(d):
            for q in range(m):
                acc[q] = 0.0
            for l in range(count):
                c = w[l]
                for q in range(m):
                    acc[q] += c * K[l, j, q]
            for q in range(m):
                Yout[j, q] = Y0[j, q] + h * acc[q]
    for j in range(d, BLOCK_WIDTH):
        for q in range(m):
            Yout[j, q] = Y0[j, q]


@jit
def _combine_run(n, h, w, count, Kf, Y0f, Yf):
    """`_combine` over the first ``n`` numbers of the flattened (component, lane) arrays,
    summed in the same order; Yf holds the running sums, then the new state. The loops
    start at 0: from an offset, numba's index wraparound kept the compiler from
    vectorising them."""
    for x in range(n):
        Yf[x] = 0.0
    # Four terms a pass (Python adds left to right: the same order), so the running sums go
    # through memory a quarter as often.
    whole = count - count % 4
    for l in range(0, whole, 4):
        c0, c1, c2, c3 = w[l], w[l + 1], w[l + 2], w[l + 3]
        for x in range(n):
            Yf[x] = (Yf[x] + c0 * Kf[l, x] + c1 * Kf[l + 1, x] + c2 * Kf[l + 2, x]
                     + c3 * Kf[l + 3, x])
    for l in range(whole, count):
        c = w[l]
        for x in range(n):
            Yf[x] += c * Kf[l, x]
    for x in range(n):
        Yf[x] = Y0f[x] + h * Yf[x]


@jit
def rk_step_block(model, m, h, tab, ctl, ws):
    """Take one step of size ``h`` from t = 0 for lanes 0..m-1 of the block ``ws`` with
    the method ``tab`` (`integrators.Tableau`) and the settings ``ctl`` (`StepControl`).

    The caller has filled P, D (drive rows), Y0 and Sc. Fills the stages, Ynew, the normal
    forces and (adaptive) the error norms, exactly as `integrators.integrate_h` computes
    them for its first step. Returns the number of state slots integrated: the largest
    `integrated_size` of the lanes (a lane with fewer is then not accepted: `accept_lanes`)."""
    P, D, Y0, Ynew, Ytmp, Sc, K, Fr, Nstart, Nstage, Nmin, Nend, Err, acc, a5, a3, ok = ws
    C, A, B = tab.C, tab.A, tab.B
    s = B.shape[0]
    d = 0
    dragged = False
    for q in range(m):
        d = max(d, sized(model, P[P_DRILL, q], P[P_DRAG_LINEAR, q], P[P_DRAG_QUADRATIC, q],
                         P[P_RESIST, q], P[P_SURFACE_DRAG, q]))
        dragged |= (P[P_DRAG_LINEAR, q] != 0.0 or P[P_DRAG_QUADRATIC, q] != 0.0
                    or P[P_RESIST, q] != 0.0 or P[P_SURFACE_DRAG, q] != 0.0)
    work = d > sized(model, 0.0, 0.0, 0.0, 0.0, 0.0)  # more than the dynamics
    # Drive terms at the stage times (trigonometry only with ripple or an external force).
    # A block whose motors all ramp linearly, without ripple, force or tilt (most levels'),
    # takes `frame_terms`'s first branch in every lane: written out as loops over the lanes,
    # the same arithmetic vectorises (a call per lane and stage was a fourteenth of the step).
    plain = True
    for q in range(m):
        plain &= (D[q, DRIVE_DECAY] == 0.0 and D[q, DRIVE_AMP] == 0.0
                  and D[q, DRIVE_FX] + P[P_TILT_FORCE, q] == 0.0 and D[q, DRIVE_FY] == 0.0)
    if plain:
        for i in range(s + 1):
            t = 0.0 + C[i] * h if i < s else 0.0 + h
            for q in range(m):
                Fr[i, 0, q] = D[q, DRIVE_W0] + D[q, DRIVE_RATE] * t
                Fr[i, 1, q] = D[q, DRIVE_RATE]
                Fr[i, 2, q] = 0.0
                Fr[i, 3, q] = 0.0
    else:
        for q in range(m):
            prof = D[q]
            tilt = P[P_TILT_FORCE, q]
            for i in range(s):
                Fr[i, 0, q], Fr[i, 1, q], Fr[i, 2, q], Fr[i, 3, q] = frame_terms(
                    prof, 0.0 + C[i] * h, tilt)
            Fr[s, 0, q], Fr[s, 1, q], Fr[s, 2, q], Fr[s, 3, q] = frame_terms(prof, 0.0 + h,
                                                                             tilt)
    _rates(model, m, P, Fr[0], Y0, K[0], Nstart, dragged, work)
    for q in range(m):
        Nmin[q] = np.inf
    for i in range(1, s):
        _combine(m, d, h, A[i], i, K, Y0, acc, Ytmp)
        _rates(model, m, P, Fr[i], Ytmp, K[i], Nstage, dragged, work)
        for q in range(m):
            if Nstage[q] < Nmin[q]:
                Nmin[q] = Nstage[q]
    _combine(m, d, h, B, s, K, Y0, acc, Ynew)
    _rates(model, m, P, Fr[s], Ynew, K[s], Nend, dragged, work)
    if ctl.dt <= 0.0:  # adaptive
        _error_norms(m, d, h, tab, ctl.rtol, ctl.atol, ws)
    return d


@jit
def _error_norms(m, d, h, tab, rtol, atol, ws):
    """`rk.error_norm` for every lane (same operations, same order)."""
    P, D, Y0, Ynew, Ytmp, Sc, K, Fr, Nstart, Nstage, Nmin, Nend, Err, acc, a5, a3, ok = ws
    E, E3, err_kind = tab.E, tab.E3, tab.err_kind
    s1 = K.shape[0]
    # Sc holds the state scales; the error scale of component j is built per lane.
    for q in range(m):
        Nstage[q] = 0.0  # e5 (or the embedded sum of squares)
        acc[q] = 0.0     # e3
    for j in range(d):
        for q in range(m):
            a5[q] = 0.0
            a3[q] = 0.0
        whole = s1 - s1 % 4
        for l in range(0, whole, 4):  # four terms a pass, in order (as `_combine`)
            e0, e1, e2, e3 = E[l], E[l + 1], E[l + 2], E[l + 3]
            f0, f1, f2, f3 = E3[l], E3[l + 1], E3[l + 2], E3[l + 3]
            for q in range(m):
                k0, k1, k2, k3 = K[l, j, q], K[l + 1, j, q], K[l + 2, j, q], K[l + 3, j, q]
                a5[q] = a5[q] + e0 * k0 + e1 * k1 + e2 * k2 + e3 * k3
                a3[q] = a3[q] + f0 * k0 + f1 * k1 + f2 * k2 + f3 * k3
        for l in range(whole, s1):
            c5 = E[l]
            c3 = E3[l]
            for q in range(m):
                a5[q] += c5 * K[l, j, q]
                a3[q] += c3 * K[l, j, q]
        for q in range(m):
            sc = atol * Sc[j, q] + rtol * max(abs(Y0[j, q]), abs(Ynew[j, q]))
            if err_kind == ERR_EMBEDDED:
                e = a5[q] * (h / sc)
                Nstage[q] += e * e
            else:
                Nstage[q] += (a5[q] / sc) ** 2
                acc[q] += (a3[q] / sc) ** 2
    for q in range(m):
        if err_kind == ERR_EMBEDDED:
            Err[q] = math.sqrt(Nstage[q] / d)
        elif Nstage[q] == 0.0 and acc[q] == 0.0:
            Err[q] = 0.0
        else:
            Err[q] = abs(h) * Nstage[q] / math.sqrt((Nstage[q] + 0.01 * acc[q]) * d)


@jit
def accept_lanes(model, m, d, adaptive, events, ws):
    """Mark in ``ws.ok`` (1.0, else 0.0) the lanes 0..m-1 whose step `integrate_h` would
    accept as it stands and stop there: the lane integrates the ``d`` slots `rk_step_block`
    did, its end state and rates are finite, (adaptive) its error norm is ≤ 1, and no event
    holds at the start or the end, nor N < 0 at a stage point. Loops over the lanes, which
    the compiler vectorises: asked lane by lane (a call per lane, the block passed to each),
    the test was a sixth of the vector environment's step (measured at 1,024 balls)."""
    P, D, Y0, Ynew, Ytmp, Sc, K, Fr, Nstart, Nstage, Nmin, Nend, Err, acc, a5, a3, ok = ws
    s = K.shape[0] - 1
    detach, escape = (events & EVENT_DETACH) != 0, (events & EVENT_ESCAPE) != 0
    for q in range(m):
        # a lane without the work slot the block integrated is not this step's
        good = sized(model, P[P_DRILL, q], P[P_DRAG_LINEAR, q], P[P_DRAG_QUADRATIC, q],
                     P[P_RESIST, q], P[P_SURFACE_DRAG, q]) == d
        if adaptive:
            good &= Err[q] <= 1.0
        if detach:  # (a NaN N is no detachment, as in `integrate_h`)
            good &= not (Nstart[q] < 0.0 or Nend[q] < 0.0 or Nmin[q] < 0.0)
        if escape:
            rim, square = P[P_RIM, q], P[P_RIM_SQUARE, q]
            good &= not (rim_margin(rim, square, Y0[0, q], Y0[1, q]) < 0.0
                         or rim_margin(rim, square, Ynew[0, q], Ynew[1, q]) < 0.0)
        ok[q] = 1.0 if good else 0.0
    for j in range(d):
        for q in range(m):
            if not (math.isfinite(Ynew[j, q]) and math.isfinite(K[s, j, q])):
                ok[q] = 0.0


@jit
def next_step(err, h, h_hint, err_order, max_step):
    """The step-size hint `integrate_h` leaves after accepting a (clipped) step of ``h`` with
    error norm ``err`` (a lane's ``Err``), tried as ``h_hint`` ≤ ``max_step``."""
    if min(h * MAX_FACTOR, max_step) <= h_hint:
        # The hint wins whatever the error: `step_factor` is at most MAX_FACTOR, so the
        # grown step is at most h·MAX_FACTOR ≤ h_hint, or the hint is max_step already.
        # Most steps land here (the hint sits at max_step), and skip the factor's pow.
        return h_hint
    return min(max(h * step_factor(err, -1.0 / (err_order + 1.0)), h_hint), max_step)
