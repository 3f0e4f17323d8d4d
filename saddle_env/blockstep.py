"""Many balls advanced together: one adaptive step size for a block of balls, the arithmetic
of each step done for the whole block at once, vectorised across the balls.

`integrators.integrate_batch` gives every ball its own steps, so no two balls do the same
arithmetic at the same time and the compiler cannot use the CPU's vector instructions across
them. Balls of one batch usually need about the same steps (the same saddle, nearby releases),
so here a block of up to `lockstep.LANES` balls shares each step: the step is accepted when
every ball's error estimate accepts it, and the next one is sized for the ball that needs the
smallest. The rates, the stage sums and the error norms are `lockstep`'s loops over the lanes
(4–8 balls per instruction with AVX2/AVX-512), and the first stage of a step is the last of
the step before (Dormand–Prince's "first same as last").

Each ball's error is then held to the tolerance at every step, as in `integrate_batch`, but at
steps no longer than its own, so a ball's trajectory differs from `simulate`'s by about the
tolerance rather than matching it bit for bit (`simulate_batch(..., shared_steps=False)` keeps
that). Where a ball would meet anything that needs the scalar loop's care, it leaves the block
and `integrators.integrate_h` finishes it from the start of that step: an event (N < 0 at the
end of the step or at a stage point, the rim), a state that is not finite. A scene the block
does not step (a coulomb ball, rolling resistance, the ion models) runs in the scalar loop
from the start.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .compilation.jit import jit, python_entry, unmanaged
from .compilation.specialise import specialisable
from .integrators import (
    EVENT_DETACH,
    EVENT_ESCAPE,
    MIN_FACTOR,
    SAFETY,
    STATUS_DONE,
    STATUS_FAILED,
    STATUS_MAX_STEPS,
    StepControl,
    integrate,
    integrate_h,
    reaches,
    step_factor,
    unmanaged_tableau,
    workspace,
)
from .kernels import STATE_WIDTH, frame_terms, rhs, rim_margin, sized
from .lockstep import (
    BLOCK_WIDTH,
    LANES,
    _combine,
    _error_norms,
    _rates,
    accept_lanes,
    block_size,
    carve_block,
)
from .rk import initial_step
from .scene import (
    P_DRAG_LINEAR,
    P_DRAG_QUADRATIC,
    P_DRILL,
    P_RESIST,
    P_RIM,
    P_RIM_SQUARE,
    P_SURFACE_DRAG,
    P_TILT_FORCE,
    ROLLING,
    SLIPPING,
)


@jit
def blockable(model, p):
    """Whether a ball with model code ``model`` and scene row ``p`` can share a block's steps:
    a rolling ball without rolling resistance, or a slipping ball (the point model too)."""
    return (model == ROLLING and p[P_RESIST] == 0.0) or model == SLIPPING


@jit
def _size(model, p):
    """The number of state slots the ball integrates (`kernels.sized`)."""
    return sized(model, p[P_DRILL], p[P_DRAG_LINEAR], p[P_DRAG_QUADRATIC], p[P_RESIST],
                 p[P_SURFACE_DRAG])


@jit
def _dragged(p):
    return (p[P_DRAG_LINEAR] != 0.0 or p[P_DRAG_QUADRATIC] != 0.0 or p[P_RESIST] != 0.0
            or p[P_SURFACE_DRAG] != 0.0)


@jit
def _frame(m, t, P, D, Fr_i, shared):
    """Ω, Ω̇ and the force in the saddle's axes at time ``t`` for lanes 0..m-1; once for
    all of them where they share one drive row and tilt (``shared``, the usual batch)."""
    if shared:
        f0, f1, f2, f3 = frame_terms(D[0], t, P[P_TILT_FORCE, 0])
        for q in range(m):
            Fr_i[0, q], Fr_i[1, q], Fr_i[2, q], Fr_i[3, q] = f0, f1, f2, f3
        return
    for q in range(m):
        Fr_i[0, q], Fr_i[1, q], Fr_i[2, q], Fr_i[3, q] = frame_terms(D[q], t, P[P_TILT_FORCE, q])


@jit
def _one_drive(m, P, D):
    """Whether lanes 0..m-1 share one drive row and one tilt."""
    for q in range(1, m):
        if P[P_TILT_FORCE, q] != P[P_TILT_FORCE, 0]:
            return False
        for r in range(D.shape[1]):
            if D[q, r] != D[0, r]:
                return False
    return True


@jit
def _step(model, m, d, t, h, tab, ctl, ws, dragged, work, shared):
    """One step of ``h`` from ``t`` for lanes 0..m-1, f(t, Y0) already in K[0]: Ynew, K[s],
    the normal forces at the stage points and the end, and (adaptive) the error norms."""
    P, D, Y0, Ynew, Ytmp, Sc, K, Fr, Nstart, Nstage, Nmin, Nend, Err, acc, a5, a3, ok = ws
    C, A, B = tab.C, tab.A, tab.B
    s = B.shape[0]
    for q in range(m):
        Nmin[q] = np.inf
    for i in range(1, s):
        _combine(m, d, h, A[i], i, K, Y0, acc, Ytmp)
        _frame(m, t + C[i] * h, P, D, Fr[i], shared)
        _rates(model, m, P, Fr[i], Ytmp, K[i], Nstage, dragged, work)
        for q in range(m):
            if Nstage[q] < Nmin[q]:
                Nmin[q] = Nstage[q]
    _combine(m, d, h, B, s, K, Y0, acc, Ynew)
    _frame(m, t + h, P, D, Fr[s], shared)
    _rates(model, m, P, Fr[s], Ynew, K[s], Nend, dragged, work)
    if ctl.dt <= 0.0:
        _error_norms(m, d, h, tab, ctl.rtol, ctl.atol, ws)


@jit
def _leave(q, i, k, t, h, steps, rejected, live, models, P, profiles, Y, t_out, tab, ctl,
           scales, max_step, ws, Y_out, status, t_final, stats):
    """Ball i (lane q) leaves the block at time t, before output k, having shared ``steps``
    accepted and ``rejected`` steps: the scalar loop finishes it from the lane's state there,
    trying a step of ``h`` first. Returns 1 (the live lanes it takes away)."""
    live[q] = False
    _count(stats[i], steps, rejected, tab.B.shape[0])
    stats[i, 3] += k  # the outputs the block wrote for it
    y = Y[i]
    for j in range(BLOCK_WIDTH):
        y[j] = ws.Y0[j, q]
    own = StepControl(ctl.dt, ctl.rtol, ctl.atol, max_step[i], ctl.events, ctl.max_steps)
    res = integrate_h(models[i], P[i], profiles[i], y, t, t_out[k:], tab, own, scales[i],
                      Y_out[i, k:], stats[i], h if ctl.dt <= 0.0 else 0.0, workspace(tab))
    status[i], t_final[i] = res.status, res.t_final
    return 1


@jit
def _count(row, steps, rejected, s):
    """Add a ball's share of the block's steps to its counts (`integrate_h`'s stats row):
    steps accepted and rejected, and f evaluations (the first, then s per step)."""
    row[0] += steps
    row[1] += rejected
    row[2] += 1 + s * (steps + rejected)


@jit
def _starts_clean(q, d, events, ws):
    """Whether lane q's start is finite and no event holds there (the scalar loop stops at
    once where one does)."""
    for j in range(d):
        if not math.isfinite(ws.Y0[j, q]) or not math.isfinite(ws.K[0, j, q]):
            return False
    if events & EVENT_DETACH and ws.Nstart[q] < 0.0:
        return False
    rim, square = ws.P[P_RIM, q], ws.P[P_RIM_SQUARE, q]
    return not (events & EVENT_ESCAPE and rim_margin(rim, square, ws.Y0[0, q], ws.Y0[1, q]) < 0.0)


@jit
def _load(idx, m, P, profiles, Y, scales, ws):
    for q in range(m):
        i = idx[q]
        for r in range(P.shape[1]):
            ws.P[r, q] = P[i, r]
        for r in range(profiles.shape[1]):
            ws.D[q, r] = profiles[i, r]
        for j in range(BLOCK_WIDTH):
            ws.Y0[j, q] = Y[i, j]
            ws.Sc[j, q] = scales[i, j]


@jit
def _first_step(model, idx, m, t0, P, profiles, Y, tab, ctl, scales, hmax):
    """The block's first step: the smallest of the lanes' starting steps (`rk.initial_step`,
    as the scalar loop takes), or the fixed step."""
    if ctl.dt > 0.0:
        return min(ctl.dt, hmax)
    f0 = np.empty(STATE_WIDTH)
    f1 = np.empty(STATE_WIDTH)
    ytmp = np.empty(STATE_WIDTH)
    sc = np.empty(STATE_WIDTH)
    h = hmax
    for q in range(m):
        i = idx[q]
        d = _size(model, P[i])
        rhs(model, P[i], profiles[i], t0, Y[i], f0, False)
        for j in range(d):
            sc[j] = ctl.atol * scales[i, j] + ctl.rtol * abs(Y[i, j])
        h = min(h, initial_step(model, P[i], profiles[i], t0, Y[i], f0, d, sc, tab.err_order,
                                ytmp, f1, hmax))
    return h


@jit
def _run_block(model, idx, m, models, P, profiles, Y, t0, t_out, tab, ctl, scales, max_step,
               Y_out, status, t_final, stats, ws):
    """Advance the balls ``idx[:m]`` (one model, one integrated size, all blockable) through
    the output times, sharing each step."""
    s = tab.B.shape[0]
    K, Y0, Ynew = ws.K, ws.Y0, ws.Ynew
    _load(idx, m, P, profiles, Y, scales, ws)
    d = _size(model, P[idx[0]])
    dragged = False
    hmax = np.inf
    for q in range(m):
        dragged |= _dragged(P[idx[q]])
        hmax = min(hmax, max_step[idx[q]])
    work = d > sized(model, 0.0, 0.0, 0.0, 0.0, 0.0)
    adaptive = ctl.dt <= 0.0
    exponent = -1.0 / (tab.err_order + 1.0) if adaptive else 0.0
    live = np.ones(m, dtype=np.bool_)
    n_live = m
    shared = _one_drive(m, ws.P, ws.D)
    _frame(m, t0, ws.P, ws.D, ws.Fr[0], shared)
    _rates(model, m, ws.P, ws.Fr[0], Y0, K[0], ws.Nstart, dragged, work)
    h = _first_step(model, idx, m, t0, P, profiles, Y, tab, ctl, scales, hmax)
    t = t0
    steps = 0
    rejected = 0
    # An event at the start, or a start that is not finite: the scalar loop reports it.
    for q in range(m):
        if not _starts_clean(q, d, ctl.events, ws):
            n_live -= _leave(q, idx[q], 0, t, h, 0, 0, live, models, P, profiles, Y, t_out,
                             tab, ctl, scales, max_step, ws, Y_out, status, t_final, stats)
    k = 0
    while k < t_out.shape[0] and t_out[k] <= t0:  # outputs at the start
        for q in range(m):
            if live[q]:
                Y_out[idx[q], k, :] = Y[idx[q], :]
        k += 1
    outcome = STATUS_DONE
    while k < t_out.shape[0] and n_live > 0:
        if steps >= ctl.max_steps:
            outcome = STATUS_MAX_STEPS
            break
        target = t_out[k]
        clipped = reaches(t, h, target)
        hstep = target - t if clipped else h
        if not (hstep > 1e-14 * max(1.0, abs(t))):
            outcome = STATUS_FAILED
            break
        _step(model, m, d, t, hstep, tab, ctl, ws, dragged, work, shared)
        worst = 0.0
        if adaptive:
            for q in range(m):
                if live[q] and not math.isfinite(ws.Err[q]):
                    # a step this ball cannot take at all (it left the model's range): its
                    # own loop shrinks it, not the block's
                    n_live -= _leave(q, idx[q], k, t, hstep, steps, rejected, live, models, P,
                                     profiles, Y, t_out, tab, ctl, scales, max_step, ws, Y_out,
                                     status, t_final, stats)
                elif live[q]:
                    worst = max(worst, ws.Err[q])
            if n_live == 0:
                break
            if not worst <= 1.0:  # some ball rejects it: shrink for the worst and retry
                h = hstep * max(MIN_FACTOR, SAFETY * worst ** exponent)
                rejected += 1
                continue
        steps += 1
        # A ball the step cannot be accepted for as it stands leaves for the scalar loop.
        accept_lanes(model, m, d, adaptive, ctl.events, ws)
        for q in range(m):
            if live[q] and ws.ok[q] == 0.0:
                n_live -= _leave(q, idx[q], k, t, hstep, steps - 1, rejected, live, models, P,
                                 profiles, Y, t_out, tab, ctl, scales, max_step, ws, Y_out,
                                 status, t_final, stats)
        t = target if clipped else t + hstep
        for j in range(BLOCK_WIDTH):
            for q in range(m):
                Y0[j, q] = Ynew[j, q]
                K[0, j, q] = K[s, j, q]
        if clipped:
            for q in range(m):
                if live[q]:
                    i = idx[q]
                    for j in range(BLOCK_WIDTH):
                        Y_out[i, k, j] = Y0[j, q]
                    for j in range(BLOCK_WIDTH, STATE_WIDTH):
                        Y_out[i, k, j] = Y[i, j]
            k += 1
        if adaptive:
            hnew = hstep * step_factor(worst, exponent)
            h = min(max(hnew, h) if clipped else hnew, hmax)
    for q in range(m):
        if live[q]:
            i = idx[q]
            for j in range(BLOCK_WIDTH):
                Y[i, j] = Y0[j, q]
            status[i] = outcome
            t_final[i] = t
            _count(stats[i], steps, rejected, s)
            stats[i, 3] += k


@python_entry
@nb.njit(cache=True, nogil=True)
def integrate_batch_shared(lo, hi, models, P, profiles, Y, t0, t_out, tab, ctl, scales,
                           max_step, active, Y_out, status, t_final, stats):
    """`integrators.integrate_batch` (same arguments, same results up to the tolerance) with
    the steps shared by blocks of balls: consecutive active balls with one contact model and
    one integrated size form a block of up to `LANES`; a ball no block can step runs in
    `integrators.integrate` alone."""
    buf = np.empty(block_size(tab.B.shape[0]))
    idx = np.empty(LANES, dtype=np.int64)
    _shared_range(lo, hi, models, P, profiles, Y, t0, t_out, tab, ctl, scales, max_step,
                  active, Y_out, status, t_final, stats, buf, idx)


@jit
def _shared_range(lo, hi, models, P, profiles, Y, t0, t_out, tab, ctl, scales, max_step,
                  active, Y_out, status, t_final, stats, buf, idx):
    """`integrate_batch_shared`'s work, with its scratch memory ``buf`` and ``idx``."""
    # The caller holds every array for the call and no view outlives it: unmanaged, the
    # block's views and calls cost no atomic reference counting (`unmanaged`).
    U = unmanaged
    models, P, profiles, Y, t_out = U(models), U(P), U(profiles), U(Y), U(t_out)
    scales, max_step, active, Y_out = U(scales), U(max_step), U(active), U(Y_out)
    status, t_final, stats, buf, idx = U(status), U(t_final), U(stats), U(buf), U(idx)
    tab = unmanaged_tableau(tab)
    ws = carve_block(buf, tab.B.shape[0])
    i = lo
    while i < hi:
        if not active[i]:
            i += 1
            continue
        if not blockable(models[i], P[i]):
            own = StepControl(ctl.dt, ctl.rtol, ctl.atol, max_step[i], ctl.events,
                              ctl.max_steps)
            status[i], t_final[i] = integrate(models[i], P[i], profiles[i], Y[i], t0, t_out,
                                              tab, own, scales[i], Y_out[i], stats[i])
            i += 1
            continue
        model = models[i]
        size = _size(model, P[i])
        m = 0
        while i < hi and m < LANES:
            if active[i]:
                if models[i] != model or not blockable(model, P[i]) or _size(model, P[i]) != size:
                    break
                idx[m] = i
                m += 1
            i += 1
        _run_block(model, idx, m, models, P, profiles, Y, t0, t_out, tab, ctl, scales,
                   max_step, Y_out, status, t_final, stats, ws)


specialisable(__name__)
