"""The compiled stepping loop: Runge–Kutta steps with error control, event location and a
coulomb ball's stick-slip and rolling-resistance stops.

Every method of ``METHODS`` (`saddle_env.rk`, which also holds what one step does) runs on
one compiled stepping loop, `integrate`, which the single-ball path calls directly and the
batch path calls once per ball, in parallel (`saddle_env.lockstep` reproduces its first step
for many balls at once, in SIMD lanes, for the environment). The loop:

* takes fixed steps (``dt > 0``) or adaptive steps (``dt == 0``: embedded error estimate,
  the usual step-size controller of Hairer, Nørsett & Wanner, Vol. I §II.4);
* lands exactly on every output time, so outputs are integrator steps, not interpolants;
* after each step checks the events — detachment (N crosses 0 from above) and escape (the
  contact point leaves the rim) — and, when one fired, finds its time by root-finding on
  the partial step (`rk.locate`), as accurate as the integrator itself.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numba as nb
import numpy as np

from .compilation.jit import inline, ir_inline, jit, python_entry, unmanaged
from .compilation.specialise import COULOMB_ON, RESIST_ON, specialisable
from .kernels import (
    ONSET,
    PHASE_SLOT,
    ROW_WIDTH,
    SLIP,
    STATE_WIDTH,
    STICK,
    coulomb_contact,
    integrated_size,
    rhs,
    rolling_spin,
    rolling_velocity,
    spin_held,
    stick_margin,
    stop_rolling,
    stop_slip,
    work_slot,
)
from .rk import (
    ERR_DOP853,
    ERR_EMBEDDED,
    ERR_NONE,
    EVENT_DETACH,
    EVENT_ESCAPE,
    EVENT_TIME_TOL,
    METHODS,
    STATUS_DETACH,
    STATUS_ESCAPE,
    TRANSITION,
    Method,
    Tableau,
    error_norm,
    event_fired,
    initial_step,
    locate,
    probe_dip,
    stages,
    stick_dip,
)
from .scene import (
    COULOMB,
    P_A,
    P_B,
    P_G,
    P_R,
    P_RESIST,
    P_SPIN_BAND,
    ROLLING,
)

# What callers of the loop read here, `rk`'s methods and event codes among it.
__all__ = ["ERR_DOP853", "ERR_EMBEDDED", "ERR_NONE", "EVENT_DETACH", "EVENT_ESCAPE",
           "EVENT_KINDS", "EVENT_TIME_TOL", "LOG_PHASE", "LOG_T", "METHODS", "STATUS_DETACH",
           "STATUS_DONE", "STATUS_ESCAPE", "STATUS_FAILED", "STATUS_MAX_STEPS", "Method",
           "Outcome", "StepControl", "Tableau", "integrate", "integrate_batch", "integrate_h",
           "reaches", "state_scale", "step_control", "step_factor", "transition_log", "unmanaged_tableau",
           "workspace"]

# The status codes `integrate` returns (detachment and escape: `rk`'s event kinds).
STATUS_DONE = 0
STATUS_FAILED, STATUS_MAX_STEPS = -1, -2
EVENT_KINDS = {STATUS_DETACH: "detach", STATUS_ESCAPE: "escape"}

# A coulomb ball's stick-slip transitions (docs/physics.md, "Coulomb friction"). Not a
# stopping event: the loop switches the phase and goes on.
# * stick -> slip: the friction the rolling constraint needs reaches μ_s N. The event
#   function μ_s N - |f| is smooth across it (the stick dynamics are the rolling model's), so
#   it is located like a detachment: kind TRANSITION in `rk.event_value`.
# * slip -> stick: the slip speed reaches 0. |v_s| only touches 0 (it does not change sign),
#   and the friction's direction v_s/|v_s| jumps there, so a step across it would chatter
#   (rejected, shrunk, rejected). Instead no slip step goes past the stop the slip's current
#   deceleration predicts: a step is cut to SLIP_STOP_FRACTION of |v_s|/(-d|v_s|/dt), so
#   |v_s| falls about a hundredfold per step (faster as the approach straightens), and once
#   it is at the integration's noise level (`_snap_speed`, SLIP_SNAP times the tolerance),
#   the rest of the slip is stopped by a friction impulse (`kernels.stop_slip`: the ball's
#   momentum and spin change as friction would change them, the energy that takes is added
#   to the dissipated work, so the Jacobi balance still closes), and the ball sticks if
#   static friction can hold it (`_settle_coulomb`; else slip restarts, along the push).
# * slip that has just started (ONSET): the friction opposes the push a0 that starts it, not
#   the slip itself. The slip's own direction is stiff while the slip is small: it turns
#   towards a0 at |a0|/|v_s|, so an explicit step that followed it would have to be shorter
#   than |v_s|/|a0|. The ONSET friction does not turn the slip as a0 turns, though, so the
#   slip falls behind a0 by its part across a0, q = |v_s × â0|; the slip's own friction
#   would turn it within that stiff time, so the ball ends up about q·h/2 from where it
#   would be after a step of h. An adaptive ONSET step counts that distance in its error
#   (`_onset_error`, measured: without it the benchmark's rtol 1e-10 run was 9e-6 m off,
#   with it 3e-10 m, at twice the steps). ONSET gives way to SLIP once the slip is ONSET_SPAN
#   times above the noise level (so its direction is known to 1e-4: handing over at the
#   noise level itself left an error in the slip that stayed, up to 1e-8 m/s with steps
#   capped at 10 µs) and, with a fixed step, once the step can follow its direction
#   (|v_s| ≥ |a0| dt); and at once when the slip decelerates, since a slip that shrinks is
#   no longer turned towards a0 and is stopped as a slip is (the cut above).
# * roll stop: rolling resistance stops a rolling spin w_t in finite time, and its torque
#   -c_rr R N ŵ_t flips there, so a step across the stop is wrong by up to c_rr R N times the
#   step (measured: a ball on flat ground that should roll to rest came out moving at up to
#   3 mm/s). The loop writes the spin its tolerance cannot tell from 0,
#   SLIP_SNAP·(atol·scale + rtol·|w|) (the band, `scene.P_SPIN_BAND`), and the rates treat a
#   spin within it as not rolling: held by the static torque if it can be, else starting to
#   roll against the push that starts it (the spin's own direction is stiff while it is
#   small: it turns towards the push at c_rr N/(m R |w_t|), faster than a step can follow;
#   measured before the band: the release from rest 1 % past the holding edge was 1e-4 m off
#   at rtol 1e-8). Where the ball will be held once stopped (`kernels.spin_held`, judged on
#   the state with its spin stopped), no step goes past the stop that the spin's
#   deceleration predicts, and within the band w_t is snapped to 0 (`kernels.stop_rolling`,
#   its energy booked as work). Where it will not be held, the spin passes zero and turns.
SLIP_STOP_FRACTION = 0.99
SLIP_SNAP = 100.0
ONSET_SPAN = 100.0

# Step-size controller constants (as in Hairer's codes and scipy).
SAFETY, MIN_FACTOR, MAX_FACTOR = 0.9, 0.2, 10.0

# The compiled loop's inputs and result travel as named records (namedtuples, which numba
# passes and caches like the plain arrays and numbers they hold) rather than long positional
# lists: which array is which, and which number is a tolerance, is then read off by name.
StepControl = namedtuple("StepControl", "dt rtol atol max_step events max_steps")
StepControl.__doc__ = """How the loop steps: ``dt`` [s] a fixed step (0: adaptive); ``rtol``,
``atol`` the tolerances (component j's error is measured against ``atol·scale[j] +
rtol·|y_j|``); ``max_step`` [s] the largest step; ``events`` the EVENT_* bit mask;
``max_steps`` give up (STATUS_MAX_STEPS) after this many steps. Build it with `step_control`,
which fixes the field types (one compiled specialisation for every caller)."""

Outcome = namedtuple("Outcome", "status t_final h_next normal")
Outcome.__doc__ = """What `integrate_h` returns: the STATUS_* code; the time of the final state
(the event time if an event fired); the step the controller would take next when the run
completed (otherwise the starting step passed in); N/m [m/s²] at the last accepted state —
the final state when the run completed — if detachment events are on, else NaN."""


def step_control(dt: float, rtol: float, atol: float, max_step: float, events: int,
                 max_steps: int) -> StepControl:
    """A `StepControl` with float and int fields as the compiled loop expects them.

    Parameters
    ----------
    dt : float
        Fixed step [s]; 0 for adaptive steps.
    rtol, atol : float
        Tolerances of the adaptive steps (see `StepControl`).
    max_step : float
        Largest step [s].
    events : int
        Bit mask of EVENT_DETACH and EVENT_ESCAPE.
    max_steps : int
        Steps after which the loop gives up (STATUS_MAX_STEPS).

    Returns
    -------
    StepControl
    """
    return StepControl(float(dt), float(rtol), float(atol), float(max_step), int(events),
                       int(max_steps))


@ir_inline
def _copy_row(dst, src):
    """dst[:] = src, element by element: numba compiles an array-to-slice assignment with a
    formatted shape-mismatch error (string formatting, ~2 s of a cold compile, measured in
    docs/coldstart.md), which a loop over rows of one length never needs."""
    for j in range(dst.shape[0]):
        dst[j] = src[j]


@jit
def reaches(t, h, target):
    """Whether a step reaches an output time (then it is clipped to land on it exactly).

    Parameters
    ----------
    t : float
        Time [s] the step starts at.
    h : float
        The step [s].
    target : float
        The output time [s].

    Returns
    -------
    bool
        True when ``t + h`` reaches ``target``; a sliver left over by rounding counts as
        reached.
    """
    return t + h >= target - 1e-13 * max(1.0, abs(target))


@jit
def step_factor(err, exponent):
    """How much the controller scales the step after an accepted one.

    Parameters
    ----------
    err : float
        The accepted step's scaled error norm (≤ 1).
    exponent : float
        The controller's exponent, -1/(error order + 1).

    Returns
    -------
    float
        ``SAFETY·err^exponent`` kept within [MIN_FACTOR, MAX_FACTOR] (MAX_FACTOR for
        ``err == 0``).
    """
    return MAX_FACTOR if err == 0.0 else min(MAX_FACTOR, max(MIN_FACTOR, SAFETY * err ** exponent))


@jit
def workspace(tab, log_rows=0):
    """Scratch memory for `integrate_h`.

    Parameters
    ----------
    tab : Tableau
        The method it is for.
    log_rows : int
        If > 0, it also keeps a log of up to this many stick-slip transitions of a coulomb
        ball (`transition_log`).

    Returns
    -------
    ndarray, shape (rows, STATE_WIDTH)
        Rows 0..s are the stages' rates, then the scratch states, then the log.
    """
    w = np.empty((tab.B.shape[0] + 5 + (log_rows + 1 if log_rows > 0 else 0), STATE_WIDTH))
    if log_rows > 0:
        w[tab.B.shape[0] + 5, 0] = 0.0
    return w


# Columns of a transition-log row: the time and the phase the ball switched to.
LOG_T, LOG_PHASE = 0, 1


@jit
def transition_log(tab, work):
    """The transitions a run with a logging `workspace` recorded.

    Parameters
    ----------
    tab : Tableau
        The method the workspace is for.
    work : ndarray
        The workspace, from `workspace` with ``log_rows`` > 0.

    Returns
    -------
    count : int
        Transitions that happened (those beyond the log's length are counted, not kept).
    rows : ndarray, shape (log_rows, STATE_WIDTH)
        The log: column LOG_T the time [s], LOG_PHASE the phase switched to (STICK or SLIP).
    """
    s = tab.B.shape[0]
    return int(work[s + 5, 0]), work[s + 6:]


@jit
def _log_switch(work, s, t, before, after):
    """Log a phase change as users see it: ONSET and SLIP are both slip."""
    if after >= 0.0 and (after == STICK) != (before == STICK):
        _record(work, s, t, STICK if after == STICK else SLIP)


@jit
def _record(work, s, t, phase):
    if work.shape[0] > s + 5:
        i = int(work[s + 5, 0])
        if s + 6 + i < work.shape[0]:
            work[s + 6 + i, LOG_T] = t
            work[s + 6 + i, LOG_PHASE] = phase
        work[s + 5, 0] = i + 1.0


@jit
def _snap_speed(p, y, atol, rtol, scale):
    """Slip speed [m/s] below which a coulomb ball's slip is integration noise: v_s = ċ - R w×n
    is a difference of integrated quantities, each known to about atol·scale + rtol·|value|."""
    R = p[P_R]
    speed = math.sqrt(y[5] * y[5] + y[6] * y[6])
    spin = math.sqrt(y[2] * y[2] + y[3] * y[3] + y[4] * y[4])
    return SLIP_SNAP * (atol * scale[5] + rtol * (speed + R * spin))


@jit
def _set_spin_band(p, y, atol, rtol, scale):
    """Write the rolling spin [rad/s] that the integration cannot tell from 0 at ``y`` into
    the parameter row (`scene.P_SPIN_BAND`; see roll stop above): SLIP_SNAP times the
    spin's tolerance, as `_snap_speed` does for a slip."""
    p[P_SPIN_BAND] = SLIP_SNAP * (atol * scale[2] + rtol * math.sqrt(
        y[2] * y[2] + y[3] * y[3] + y[4] * y[4]))


@jit
def _onset_error(lag, y, h, atol, rtol, scale):
    """An ONSET step's error from the slip's lag ``lag`` [m/s] behind a0 at its end state
    ``y`` (see ONSET above): q·h/2 against the position tolerance."""
    return 0.5 * lag * h / (atol * scale[1] + rtol * math.sqrt(y[0] * y[0] + y[1] * y[1]))


@jit
def _settle_coulomb(p, prof, t, y, speed_tol, hold, lag_limit):
    """Decide a coulomb ball's phase at (t, y) before a step; return ``(switched, speed,
    growth)``: the phase it switched to, or -1 if it kept its phase, and the slip speed
    [m/s] and its rate of growth [m/s²] it saw (before a stop; for the step's cut, and for
    the time a stopped slip would have reached 0). (The stick -> slip switch is an event
    inside a step.)

    Sticking, it stays stuck while static friction holds it and otherwise starts to slip
    (ONSET). Starting to slip, it sticks again as soon as static friction can hold it, and
    counts as slipping once its slip is above the noise level ``speed_tol`` [m/s] and: it
    decelerates, or its lag behind a0 exceeds ``lag_limit`` [m/s] (where onset's error would
    cut the next step), or it is ONSET_SPAN times above the noise level and above
    |a0|·``hold`` (the fixed step [s]; 0 when adaptive). Slipping,
    a slip that has fallen to the noise level and is still falling is stopped
    (`kernels.stop_slip`), and it sticks if static friction can hold it, else starts again."""
    old = y[PHASE_SLOT]
    if old == STICK:
        rolling_velocity(p, y, y)
        new = STICK if stick_margin(p, prof, t, y) >= 0.0 else ONSET
    else:
        contact = coulomb_contact(p, prof, t, y)
        speed, growth = contact[2], contact[3]
        if old == ONSET:
            if speed > speed_tol and (growth < 0.0 or contact[5] > lag_limit
                                      or (speed > ONSET_SPAN * speed_tol
                                          and speed >= contact[4] * hold)):
                new = SLIP
            elif speed <= speed_tol and stick_margin(p, prof, t, y) >= 0.0:
                stop_slip(p, prof, t, y)
                new = STICK
            else:
                return -1.0, speed, growth
        elif speed > speed_tol or growth >= 0.0:
            return -1.0, speed, growth
        else:
            stop_slip(p, prof, t, y)
            new = STICK if stick_margin(p, prof, t, y) >= 0.0 else ONSET
    y[PHASE_SLOT] = new
    if new == old:
        return -1.0, 0.0, 0.0
    if old == STICK:
        return new, 0.0, 0.0
    return new, speed, growth


@jit
def integrate(model, p, prof, y, t0, t_out, tab, ctl, scale, Y_out, stats):
    """Advance ``y`` (in place) from ``t0`` through the output times ``t_out``.

    `integrate_h` with no step-size hint and fresh scratch memory; the parameters are its.

    Returns
    -------
    status : int
        STATUS_DONE, STATUS_DETACH, STATUS_ESCAPE, STATUS_FAILED or STATUS_MAX_STEPS.
    t_final : float
        The time of the final state (the event time if an event fired).
    """
    res = integrate_h(model, p, prof, y, t0, t_out, tab, ctl, scale, Y_out, stats, 0.0,
                      workspace(tab))
    return res.status, res.t_final


@python_entry
@jit
def integrate_h(model, p, prof, y, t0, t_out, tab, ctl, scale, Y_out, stats, h_start, work):
    """Advance ``y`` (in place) from ``t0`` through the output times ``t_out``.

    Parameters
    ----------
    model : int
        ROLLING, SLIPPING or COULOMB (or an ion model, `saddle_env.iontrap`).
    p : ndarray, shape (N_PARAMS,)
        Packed scene parameters.
    prof : ndarray, shape (DRIVE_WIDTH,)
        Drive row (DRIVE_* in `saddle_env.kernels`).
    y : ndarray, shape (STATE_WIDTH,)
        State at ``t0``; on return, the state at the final time (or at the event).
    t0 : float
        Starting time [s].
    t_out : ndarray, shape (m,)
        Ascending output times, all ≥ ``t0``.
    tab : Tableau
        The method (`Method.tableau`).
    ctl : StepControl
        Fixed step or tolerances, largest step, events, step limit.
    scale : ndarray, shape (STATE_WIDTH,)
        Characteristic size of each state component (`state_scale`).
    Y_out : ndarray, shape (m, STATE_WIDTH)
        Written with the state at each output time reached.
    stats : ndarray of int64, shape (4,)
        Incremented: steps accepted, steps rejected, f evaluations, outputs written.
    h_start : float
        Adaptive only: the starting step if > 0 (a caller continuing a run, e.g. the
        environment's next control step, passes the last ``h_next`` back); 0 lets the
        starting-step heuristic choose.
    work : ndarray
        Scratch memory from `workspace(tab)`; a caller stepping many short intervals (the
        environment) passes the same one every time instead of allocating per call.

    Returns
    -------
    Outcome
        ``(status, t_final, h_next, normal)``: STATUS_DONE, STATUS_DETACH, STATUS_ESCAPE,
        STATUS_FAILED or STATUS_MAX_STEPS; the time of the final state (the event time if an
        event fired); the step to continue with; N/m at the last accepted state.
    """
    # The caller holds every array for the call, and no view of one outlives it: unmanaged,
    # the loop's views and calls cost no atomic reference counting (`unmanaged`).
    p, prof, y, t_out, scale = unmanaged(p), unmanaged(prof), unmanaged(y), unmanaged(t_out), \
        unmanaged(scale)
    Y_out, stats, work = unmanaged(Y_out), unmanaged(stats), unmanaged(work)
    tab = unmanaged_tableau(tab)
    s = tab.B.shape[0]
    K = work[:s + 1]
    want_normal = (ctl.events & EVENT_DETACH) != 0
    normal = _begin(model, p, prof, t0, y, K[0], ctl, scale, want_normal)
    stats[2] += 1
    accepted_normal = normal if want_normal else np.nan  # N/m at the last accepted state
    fired = event_fired(ctl.events, model, p, prof, t0, y, work[s + 3], normal)
    if fired:
        return Outcome(fired, t0, h_start, accepted_normal)
    k = 0
    while k < t_out.shape[0] and t_out[k] <= t0:
        _copy_row(Y_out[k], y)
        k += 1
    stats[3] += k
    if k == t_out.shape[0]:
        return Outcome(STATUS_DONE, t0, h_start, accepted_normal)
    h = _starting_step(model, p, prof, t0, y, K, tab, ctl, scale, h_start, work)
    return _march(model, p, prof, y, t0, t_out, k, h, tab, ctl, scale, Y_out, stats, h_start,
                  work, accepted_normal)


@ir_inline
def unmanaged_tableau(tab):
    """``tab`` with its arrays `unmanaged` (for a caller that holds the method's arrays)."""
    return Tableau(unmanaged(tab.C), unmanaged(tab.A), unmanaged(tab.B), unmanaged(tab.E),
                   unmanaged(tab.E3), tab.err_kind, tab.err_order)


@jit
def _begin(model, p, prof, t, y, f, ctl, scale, want_normal):
    """Ready the state at the start of a run (the spin band of rolling resistance; a coulomb
    ball's starting phase, not logged: it is no change) and write f(t, y) into ``f``; return
    N/m at y (if ``want_normal``)."""
    # the flags: see `compilation.specialise`
    coulomb = COULOMB_ON and model == COULOMB
    if RESIST_ON and (model == ROLLING or coulomb) and p[P_RESIST] != 0.0:
        _set_spin_band(p, y, ctl.atol, ctl.rtol, scale)
    if coulomb:
        hold = 0.0 if ctl.dt <= 0.0 else ctl.dt
        _settle_coulomb(p, prof, t, y, _snap_speed(p, y, ctl.atol, ctl.rtol, scale), hold,
                        np.inf)
    return rhs(model, p, prof, t, y, f, want_normal)


@jit
def _starting_step(model, p, prof, t, y, K, tab, ctl, scale, h_start, work):
    """The first step to try [s]: ``h_start`` where a caller continues an adaptive run,
    else Hairer's heuristic (adaptive) or the fixed step; never above the largest step."""
    if ctl.dt <= 0.0 and h_start > 0.0:
        return min(h_start, ctl.max_step)
    if ctl.dt <= 0.0:
        s = tab.B.shape[0]
        d = integrated_size(model, p)
        sc = work[s + 4]
        for j in range(d):
            sc[j] = ctl.atol * scale[j] + ctl.rtol * abs(y[j])
        return initial_step(model, p, prof, t, y, K[0], d, sc, tab.err_order, work[s + 1],
                             work[s + 3], ctl.max_step)
    return min(ctl.dt, ctl.max_step)


@jit
def _march(model, p, prof, y, t, t_out, k, h, tab, ctl, scale, Y_out, stats, h_start, work,
           accepted_normal):
    """The stepping loop of `integrate_h`, from output ``k`` on, with f(t, y) in the
    workspace's first row and ``h`` the step to try first; returns its `Outcome`.

    Each pass: cut the step at the next output, at a slip's stop, at a rolling spin's stop;
    take it; reject it (adaptive: shrink and retry) or accept it; stop at an event inside
    it, or go on from where slip starts inside it, or from its end."""
    d = integrated_size(model, p)
    s = tab.B.shape[0]
    # the scratch rows, made once per run (a view made per step costs reference counting)
    K, ytmp, ynew, dy, sc = work[:s + 1], work[s + 1], work[s + 2], work[s + 3], work[s + 4]
    adaptive = ctl.dt <= 0.0
    want_normal = (ctl.events & EVENT_DETACH) != 0
    coulomb = COULOMB_ON and model == COULOMB
    resisted = RESIST_ON and (model == ROLLING or coulomb) and p[P_RESIST] != 0.0
    exponent = -1.0 / (tab.err_order + 1.0) if adaptive else 0.0
    just_stopped = False  # a spin was just stopped: take a step before stopping one again
    n_steps = 0
    while k < t_out.shape[0]:
        if n_steps >= ctl.max_steps:
            return Outcome(STATUS_MAX_STEPS, t, h_start, accepted_normal)
        target = t_out[k]
        clipped = reaches(t, h, target)  # then the step lands on the output exactly
        hstep = target - t if clipped else h
        capped = False
        if coulomb or resisted:
            restart, just_stopped, hstep, capped = _before_step(
                model, p, prof, t, y, hstep, tab, ctl, scale, stats, K, ytmp, dy, work,
                just_stopped)
            if restart:
                continue
            if capped:  # cut short of a stop: it no longer lands on the output
                clipped = False
        if not (hstep > 1e-14 * max(1.0, abs(t))):
            return Outcome(STATUS_FAILED, t, h_start, accepted_normal)
        err, normal, stage_normal = _attempt(model, p, prof, t, y, hstep, d, tab, ctl, scale,
                                             stats, K, ytmp, ynew, sc)
        if not err <= 1.0:
            if not adaptive:
                return Outcome(STATUS_FAILED, t, h_start, accepted_normal)
            h = hstep * _shrink_factor(err, exponent)  # rejected: shrink and retry
            stats[1] += 1
            continue
        n_steps += 1
        stats[0] += 1
        switch_tau = -1.0
        if coulomb and y[PHASE_SLOT] == STICK:
            # the state where slip starts goes to sc, free until the next step's error
            switch_tau = _slip_start_in_step(model, p, prof, t, y, hstep, d, tab, K, ytmp, ynew,
                                             dy, sc)
        fired = event_fired(ctl.events, model, p, prof, t + hstep, ynew, dy,
                       normal) if ctl.events else 0
        if not fired and stage_normal < 0.0:
            dipped, tau = _detach_in_dip(model, p, prof, t, y, hstep, d, tab, stats, K, ytmp,
                                         ynew, dy)
            if dipped:
                return Outcome(STATUS_DETACH, t + tau, h_start, accepted_normal)
        if fired:
            kind, tau = _earliest_event(ctl.events, model, p, prof, t, y, hstep, d, tab,
                                        normal, switch_tau, stats, K, ytmp, ynew, dy)
            if kind:
                return Outcome(kind, t + tau, h_start, accepted_normal)
        if switch_tau >= 0.0:  # slip starts at t + switch_tau from v_s = 0: go on from there
            t = target if (clipped and switch_tau >= hstep) else t + switch_tau
            normal = _start_slip(model, p, prof, t, y, sc, s, want_normal, stats, K, work)
        else:
            t = target if clipped else t + hstep
            _accept(y, ynew, K, s, coulomb)
        if want_normal:
            accepted_normal = normal
        if clipped and t >= target:
            _copy_row(Y_out[k], y)
            k += 1
            stats[3] += 1
        if adaptive:
            h = _next_step(h, hstep, err, exponent, switch_tau, clipped or capped, ctl.max_step)
    return Outcome(STATUS_DONE, t, h, accepted_normal)


# The helpers the loop calls on every step (`_before_step` and what it calls, `_attempt`,
# `_next_step`, `_shrink_factor`) are `inline`: one call site each, so LLVM's inlining costs
# no code size, and a call per step costs time (measured: `_attempt` as a plain `jit` call
# made the rk4 loop 25 % slower, as `ir_inline` 12 %; see the commit).
@inline
def _before_step(model, p, prof, t, y, hstep, tab, ctl, scale, stats, K, ytmp, dy, work,
                 just_stopped):
    """Cut a step of ``hstep`` at a slip's stop (`_settle_slip`) and a rolling spin's stop
    (`_stop_roll`, skipped right after a spin was stopped: ``just_stopped``), or make the
    switch or the stop there. Returns ``(restart, stopped, hstep, cut)``: whether the loop
    starts the pass again (a phase switched or a spin stopped: the new f(t, y) is in K[0]),
    whether a spin was stopped, the step, and whether it was cut. ``K``, ``ytmp``, ``dy``
    and ``work`` are the workspace's rows (`integrate_h`)."""
    # the flags: see `compilation.specialise`
    coulomb = COULOMB_ON and model == COULOMB
    cut = False
    if coulomb and y[PHASE_SLOT] != STICK:
        switched, hstep, cut = _settle_slip(model, p, prof, t, y, hstep, tab, ctl, scale,
                                            stats, K, work)
        if switched:
            return True, just_stopped, hstep, cut
    if RESIST_ON and (model == ROLLING or coulomb) and p[P_RESIST] != 0.0 and not just_stopped:
        stopped, hstep, cut_here = _stop_roll(model, p, prof, t, y, hstep, ctl, scale, stats,
                                              K, ytmp, dy)
        if stopped:
            return True, True, hstep, cut
        cut = cut or cut_here
    return False, False, hstep, cut


@inline
def _shrink_factor(err, exponent):
    """How much the controller shrinks a rejected step with error norm ``err`` (> 1): an
    infinite or NaN error shrinks by the maximum."""
    return MIN_FACTOR if not math.isfinite(err) else max(MIN_FACTOR, SAFETY * err ** exponent)


@inline
def _next_step(h, hstep, err, exponent, switch_tau, shortened, max_step):
    """The step to try after an accepted one of ``hstep`` with error norm ``err`` (the step
    tried before it was ``h``): up to the slip's start where one started in it (at
    ``switch_tau`` ≥ 0), at least ``h`` where the step was ``shortened`` to land on an output
    or short of a stop, never above ``max_step``."""
    if switch_tau >= 0.0:
        return min(max(hstep * step_factor(err, exponent), switch_tau), max_step)
    hnew = hstep * step_factor(err, exponent)
    # A step shortened to hit an output says nothing against the natural step.
    return min(max(hnew, h) if shortened else hnew, max_step)


@inline
def _settle_slip(model, p, prof, t, y, hstep, tab, ctl, scale, stats, K, work):
    """A slipping coulomb ball before a step of ``hstep`` (slip -> stick above): switch its
    phase where `_settle_coulomb` says so, logging the change and writing the new f(t, y)
    into K[0]; else cut the step short of the stop that the slip's
    deceleration predicts. Returns ``(switched, hstep, cut)``: whether the phase changed
    (then the loop starts the pass again), the step, and whether it was cut."""
    atol, rtol = ctl.atol, ctl.rtol
    s = tab.B.shape[0]
    speed_tol = _snap_speed(p, y, atol, rtol, scale)
    before = y[PHASE_SLOT]
    # the lag at which an ONSET step of hstep would spend half its error on it
    lag_limit = ((atol * scale[1] + rtol * math.sqrt(y[0] * y[0] + y[1] * y[1]))
                 / hstep if ctl.dt <= 0.0 else np.inf)
    hold = 0.0 if ctl.dt <= 0.0 else ctl.dt  # how long an ONSET slip must follow itself
    switched, speed, growth = _settle_coulomb(p, prof, t, y, speed_tol, hold, lag_limit)
    if switched >= 0.0:
        # A slip stopped at the noise level is logged where it would have reached 0,
        # |v_s|/(-d|v_s|/dt) later (measured: up to 7e-9 s at rtol 1e-12 otherwise).
        _log_switch(work, s, t + speed / -growth if growth < 0.0 else t, before, switched)
        rhs(model, p, prof, t, y, K[0], (ctl.events & EVENT_DETACH) != 0)
        stats[2] += 1
        return True, hstep, False
    if growth < 0.0 and speed > speed_tol and hstep > SLIP_STOP_FRACTION * speed / -growth:
        return False, SLIP_STOP_FRACTION * speed / -growth, True
    return False, hstep, False


@inline
def _stop_roll(model, p, prof, t, y, hstep, ctl, scale, stats, K, ytmp, dy):
    """Rolling resistance before a step of ``hstep`` (roll stop above): where the rolling
    spin will be held once stopped, snap a spin within the band to 0 (its energy booked as
    work; the new f(t, y) written into K[0]), or cut the step at the
    stop that the spin's deceleration predicts. Returns ``(stopped, hstep, cut)``: whether
    the spin was stopped (then the loop starts the pass again), the step, and whether it
    was cut."""
    _set_spin_band(p, y, ctl.atol, ctl.rtol, scale)
    spin, rate = rolling_spin(p, y, K[0])
    at_stop = 0.0 < spin <= p[P_SPIN_BAND]
    if not (at_stop or rate < 0.0):
        return False, hstep, False
    cut = SLIP_STOP_FRACTION * spin / -rate if rate < 0.0 else np.inf
    if not (at_stop or hstep > cut):
        return False, hstep, False
    _copy_row(ytmp, y)
    stop_rolling(model, p, prof, t, ytmp)
    stats[2] += 1
    if not spin_held(p, ytmp, dy, rhs(model, p, prof, t, ytmp, dy, True)):
        return False, hstep, False  # it will not be held: the spin passes zero and turns
    if not at_stop:
        return False, cut, True
    _copy_row(y, ytmp)
    rhs(model, p, prof, t, y, K[0], (ctl.events & EVENT_DETACH) != 0)
    stats[2] += 1
    return True, hstep, False


@inline
def _attempt(model, p, prof, t, y, hstep, d, tab, ctl, scale, stats, K, ytmp, ynew, sc):
    """One RK step of ``hstep`` from (t, y), f(t, y) in K[0]: the new point goes to ``ynew``
    and f there to K[s] (``ytmp`` and ``sc`` are scratch). Returns ``(err, normal,
    stage_normal)``: the scaled error norm (adaptive; 0 with a fixed step), inf when the step
    is not finite; N/m at the new point and the lowest N/m at a stage point (if detachment
    events are on)."""
    s = tab.B.shape[0]
    want_normal = (ctl.events & EVENT_DETACH) != 0
    stage_normal = stages(model, p, prof, t, y, hstep, d, tab, K, ytmp, ynew, want_normal)
    normal = rhs(model, p, prof, t + hstep, ynew, K[s], want_normal)
    stats[2] += s
    finite = True
    for j in range(d):
        if not math.isfinite(ynew[j]) or not math.isfinite(K[s, j]):
            finite = False
    if not ctl.dt <= 0.0:  # a fixed step: no error estimate
        return 0.0 if finite else np.inf, normal, stage_normal
    for j in range(d):
        sc[j] = ctl.atol * scale[j] + ctl.rtol * max(abs(y[j]), abs(ynew[j]))
    err = error_norm(tab, hstep, d, K, sc) if finite else np.inf
    if COULOMB_ON and model == COULOMB and y[PHASE_SLOT] == ONSET and finite:
        # the lag at the end is in the phase slot of the end's rates (see `rhs`)
        err = max(err, _onset_error(K[s, PHASE_SLOT], ynew, hstep, ctl.atol, ctl.rtol, scale))
    return err, normal, stage_normal


@jit
def _slip_start_in_step(model, p, prof, t, y, hstep, d, tab, K, ytmp, ynew, dy, yswitch):
    """Where a sticking coulomb ball's static friction gave way inside the step just taken
    (stick -> slip above): at its end (the margin is in the phase slot of the end's rates),
    or only briefly inside it, which a stage point saw and a true partial step at a stage
    time confirms. Returns the time from t at which slip starts, its state written into
    ``yswitch`` (kept apart: locating a stopping event later overwrites the step's end), or
    -1 where the friction held. The step's end stays in ``ynew``."""
    s = tab.B.shape[0]
    reach = hstep if K[s, PHASE_SLOT] < 0.0 else 0.0
    if reach == 0.0 and stick_dip(K):
        yend = ynew.copy()
        reach = probe_dip(TRANSITION, model, p, prof, t, y, hstep, d, tab, K, ytmp, ynew, dy)
        _copy_row(ynew, yend)
    if not reach > 0.0:
        return -1.0
    yend = ynew.copy()
    tau = locate(TRANSITION, model, p, prof, t, y, reach, d, tab, K, ytmp, ynew, dy)
    _copy_row(yswitch, ynew)
    _copy_row(ynew, yend)
    return tau


@jit
def _detach_in_dip(model, p, prof, t, y, hstep, d, tab, stats, K, ytmp, ynew, dy):
    """N is positive at both ends of the step just taken but a stage point saw it negative:
    a brief dip inside the step. Probe with true partial steps at the stage times; the first
    negative one brackets a crossing, located as usual, and y becomes the state there.
    Returns ``(detached, tau)``, tau the time from t. A false alarm (the stage values are
    low-order estimates) redoes the full step, so ``ynew`` and K hold it as before."""
    s = tab.B.shape[0]
    tau_dip = probe_dip(STATUS_DETACH, model, p, prof, t, y, hstep, d, tab, K, ytmp, ynew, dy)
    if tau_dip > 0.0:
        tau = locate(STATUS_DETACH, model, p, prof, t, y, tau_dip, d, tab, K, ytmp, ynew, dy)
        _copy_row(y, ynew)
        stats[2] += 1
        return True, tau
    stages(model, p, prof, t, y, hstep, d, tab, K, ytmp, ynew, False)
    rhs(model, p, prof, t + hstep, ynew, K[s], False)
    return False, 0.0


@jit
def _earliest_event(events, model, p, prof, t, y, hstep, d, tab, normal, switch_tau, stats,
                    K, ytmp, ynew, dy):
    """Locate each stopping event that fired at the end of the step just taken, on the
    partial step from (t, y) (still in y, f(t, y) in K[0]); the
    earliest wins. Unless slip starts before it (at ``switch_tau`` ≥ 0 from t), y becomes the
    state at the event and ``(kind, tau)`` is returned, tau the time from t; else ``(0,
    tau)`` and the step goes on to the slip's start."""
    ybest = np.empty(STATE_WIDTH)
    yend = ynew.copy()
    best_tau = hstep
    best_kind = 0
    for kind in (STATUS_DETACH, STATUS_ESCAPE):
        if event_fired(events & kind, model, p, prof, t + hstep, yend, dy, normal) == kind:
            tau = locate(kind, model, p, prof, t, y, hstep, d, tab, K, ytmp, ynew, dy)
            if best_kind == 0 or tau < best_tau:
                best_tau, best_kind = tau, kind
                _copy_row(ybest, ynew)
    if switch_tau >= 0.0 and best_tau > switch_tau:
        return 0, best_tau
    _copy_row(y, ybest)
    stats[2] += 1
    return best_kind, best_tau


@jit
def _start_slip(model, p, prof, t, y, yswitch, s, want_normal, stats, K, work):
    """Slip starts at t from v_s = 0 in the state ``yswitch``: y becomes it, in phase ONSET
    with its rolling velocity, the switch is logged (``s`` the method's stages) and f(t, y)
    written into K[0]. Returns N/m there (if ``want_normal``)."""
    _copy_row(y, yswitch)
    y[PHASE_SLOT] = ONSET
    rolling_velocity(p, y, y)
    _record(work, s, t, SLIP)
    normal = rhs(model, p, prof, t, y, K[0], want_normal)
    stats[2] += 1
    return normal


@ir_inline
def _accept(y, ynew, K, s, coulomb):
    """Move to the accepted step's end: y = ynew and its rates K[0] = K[s]."""
    for j in range(ROW_WIDTH):  # constant length: see kernels.ROW_WIDTH
        y[j] = ynew[j]
        K[0, j] = K[s, j]
    if coulomb:
        for j in range(ROW_WIDTH, STATE_WIDTH):
            y[j] = ynew[j]
            K[0, j] = K[s, j]


@python_entry
@nb.njit(cache=True, nogil=True)
def integrate_batch(lo, hi, models, P, profiles, Y, t0, t_out, tab, ctl, scales, max_step,
                    active, Y_out, status, t_final, stats):
    """`integrate` for balls ``lo`` to ``hi - 1`` of a batch, on one thread without the GIL.

    Each ball has its own scene row, Ω profile and state; `runner.run_batch_checked` runs
    ranges on several threads (`compilation.threads.in_threads`). All balls start at
    ``t0`` and share the output times and ``ctl``, except that ball i's largest step is
    ``max_step[i]``.

    Parameters
    ----------
    lo, hi : int
        The range of balls to run.
    models : ndarray of int64, shape (n,)
        Model codes.
    P : ndarray, shape (n, N_PARAMS)
        Scene parameter rows.
    profiles : ndarray, shape (n, DRIVE_WIDTH)
        Drive rows.
    Y : ndarray, shape (n, STATE_WIDTH)
        States at ``t0``; on return, each ball's final state.
    t0 : float
        Starting time [s].
    t_out : ndarray, shape (m,)
        Output times.
    tab : Tableau
        The method.
    ctl : StepControl
        The step control (its ``max_step`` is replaced by ``max_step[i]``).
    scales : ndarray, shape (n, STATE_WIDTH)
        Each ball's `state_scale`.
    max_step : ndarray, shape (n,)
        Each ball's largest step [s].
    active : ndarray of bool, shape (n,)
        Balls with ``active[i] == False`` are not touched.
    Y_out : ndarray, shape (n, m, STATE_WIDTH)
        Written with each ball's outputs.
    status, t_final : ndarray, shape (n,)
        Written with each ball's `integrate` result.
    stats : ndarray of int64, shape (n, 4)
        Incremented with each ball's counts (see `integrate_h`).
    """
    for i in range(lo, hi):
        if active[i]:
            own = StepControl(ctl.dt, ctl.rtol, ctl.atol, max_step[i], ctl.events,
                              ctl.max_steps)
            status[i], t_final[i] = integrate(models[i], P[i], profiles[i], Y[i], t0, t_out,
                                              tab, own, scales[i], Y_out[i], stats[i])


def state_scale(p: np.ndarray, model: int) -> np.ndarray:
    """Characteristic size of each state component, so one tolerance fits all of them.

    Lengths scale with the saddle length a; velocities with a·ω₀ where ω₀ = sqrt(2g/a)
    (1 s⁻¹ when g = 0); a rolling ball's spin with a·ω₀/R; the dissipated work with (a·ω₀)².

    Parameters
    ----------
    p : ndarray, shape (N_PARAMS,)
        Packed scene parameters (`Scene.params`).
    model : int
        The contact model's code.

    Returns
    -------
    ndarray, shape (STATE_WIDTH,)

    Raises
    ------
    ValueError
        The scene's scales overflow (unphysical values).
    """
    # Python floats: an extreme scene (g = 1e308, R = 1e-320) overflows to inf here without
    # NumPy's RuntimeWarning, and is then reported as the clear error it is.
    a, b, g, R = float(p[P_A]), float(p[P_B]), float(p[P_G]), float(p[P_R])
    omega0 = math.sqrt(2.0 * g / a) if g > 0 else 1.0
    v = a * omega0
    sc = np.full(STATE_WIDTH, v)
    sc[0], sc[1] = a, min(a, b)
    if model == ROLLING or model == COULOMB:
        sc[2:5] = v / R
    sc[work_slot(model)] = v * v
    sc[STATE_WIDTH - 1] = 1.0  # a coulomb ball's phase (not integrated)
    if not (np.all(np.isfinite(sc)) and np.all(sc > 0)):
        raise ValueError(f"the scene's scales are out of floating-point range (a = {a:g} m, "
                         f"g = {g:g} m/s^2, R = {R:g} m give a speed scale of "
                         f"{sc[2]:g}): use physical values")
    return sc


specialisable(__name__)
