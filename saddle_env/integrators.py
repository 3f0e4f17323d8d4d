"""Explicit Runge–Kutta integrators with error control and event location.

Methods are named, declare their order and live in one registry, ``METHODS`` (the shape of
scipy's ``ivp.METHODS``). Every method runs on one compiled stepping loop, `integrate`,
which the single-ball path calls directly and the batch path calls once per ball, in
parallel (`saddle_env.lockstep` reproduces its first step for many balls at once, in SIMD
lanes, for the environment). The loop:

* takes fixed steps (``dt > 0``) or adaptive steps (``dt == 0``: embedded error estimate,
  the usual step-size controller of Hairer, Nørsett & Wanner, Vol. I §II.4);
* lands exactly on every output time, so outputs are integrator steps, not interpolants;
* after each step checks the events — detachment (N crosses 0 from above) and escape (the
  contact point leaves the rim) — and, when one fired, finds its time by root-finding on
  the partial step ``y(t_n + τ) = RK-step(y_n, τ)``. The event time is then as accurate as
  the integrator itself; the root-finder's own tolerance is ``EVENT_TIME_TOL``.

The Butcher tableaus of Dormand–Prince 5(4) and 8(5,3) are taken from scipy (a
dependency), so no coefficient is transcribed by hand.
"""

from __future__ import annotations

import importlib.util
import math
import types
from collections import namedtuple
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numba as nb
import numpy as np

from ._kernels import (
    ONSET,
    PHASE_SLOT,
    ROW_WIDTH,
    SLIP,
    STATE_WIDTH,
    STICK,
    coulomb_contact,
    integrated_size,
    rhs,
    rim_margin,
    rolling_spin,
    rolling_velocity,
    spin_held,
    stick_margin,
    stop_rolling,
    stop_slip,
    work_slot,
)
from .compilation.jit import ir_inline, jit, python_entry
from .compilation.specialise import COULOMB_ON, RESIST_ON, specialisable
from .scene import (
    COULOMB,
    P_A,
    P_B,
    P_G,
    P_R,
    P_RESIST,
    P_RIM,
    P_RIM_SQUARE,
    P_SPIN_BAND,
    ROLLING,
)

# Event flags (a bit mask) and the status codes `integrate` returns.
EVENT_DETACH, EVENT_ESCAPE = 1, 2
STATUS_DONE, STATUS_DETACH, STATUS_ESCAPE = 0, 1, 2
STATUS_FAILED, STATUS_MAX_STEPS = -1, -2
EVENT_KINDS = {STATUS_DETACH: "detach", STATUS_ESCAPE: "escape"}

EVENT_TIME_TOL = 1e-12  # [s] width of the final bracket around an event time

# A coulomb ball's stick-slip transitions (docs/physics.md, "Coulomb friction"). Not a
# stopping event: the loop switches the phase and goes on.
# * stick -> slip: the friction the rolling constraint needs reaches μ_s N. The event
#   function μ_s N - |f| is smooth across it (the stick dynamics are the rolling model's), so
#   it is located like a detachment: kind TRANSITION in `_event_value`.
# * slip -> stick: the slip speed reaches 0. |v_s| only touches 0 (it does not change sign),
#   and the friction's direction v_s/|v_s| jumps there, so a step across it would chatter
#   (rejected, shrunk, rejected). Instead no slip step goes past the stop the slip's current
#   deceleration predicts: a step is cut to SLIP_STOP_FRACTION of |v_s|/(-d|v_s|/dt), so
#   |v_s| falls about a hundredfold per step (faster as the approach straightens), and once
#   it is at the integration's noise level (`_snap_speed`, SLIP_SNAP times the tolerance),
#   the rest of the slip is stopped by a friction impulse (`_kernels.stop_slip`: the ball's
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
#   at rtol 1e-8). Where the ball will be held once stopped (`_kernels.spin_held`, judged on
#   the state with its spin stopped), no step goes past the stop that the spin's
#   deceleration predicts, and within the band w_t is snapped to 0 (`_kernels.stop_rolling`,
#   its energy booked as work). Where it will not be held, the spin passes zero and turns.
TRANSITION = 16
SLIP_STOP_FRACTION = 0.99
SLIP_SNAP = 100.0
ONSET_SPAN = 100.0

# Error-estimate kinds.
ERR_NONE, ERR_EMBEDDED, ERR_DOP853 = 0, 1, 2

# Step-size controller constants (as in Hairer's codes and scipy).
SAFETY, MIN_FACTOR, MAX_FACTOR = 0.9, 0.2, 10.0

# The compiled loop's inputs and result travel as named records (namedtuples, which numba
# passes and caches like the plain arrays and numbers they hold) rather than long positional
# lists: which array is which, and which number is a tolerance, is then read off by name.
Tableau = namedtuple("Tableau", "C A B E E3 err_kind err_order")
Tableau.__doc__ = """A method as the compiled loop sees it (`Method.tableau`): nodes C (s,),
coefficients A (s, s), weights B (s,), error weights E and E3 (s + 1,), the error-estimate
kind (ERR_*) and the estimator's order (sets the controller exponent)."""

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
    """A `StepControl` with float and int fields as the compiled loop expects them."""
    return StepControl(float(dt), float(rtol), float(atol), float(max_step), int(events),
                       int(max_steps))


@dataclass(frozen=True)
class Method:
    """An explicit Runge–Kutta method.

    Attributes
    ----------
    name : str
    order : int
        Order of the propagated solution (what a fixed-step convergence test measures).
    adaptive : bool
        Whether it carries an embedded error estimate (usable with ``rtol``).
    error_order : int
        Order of the error estimator (sets the controller exponent), 0 when none.
    C, A, B : ndarray
        Butcher tableau (nodes, coefficients, weights), ``s`` stages.
    E, E3 : ndarray
        Error-estimate weights over the ``s + 1`` stages (the last is f at the new point).
    """

    name: str
    order: int
    adaptive: bool
    error_order: int
    err_kind: int
    C: np.ndarray
    A: np.ndarray
    B: np.ndarray
    E: np.ndarray
    E3: np.ndarray
    description: str

    @property
    def stages(self) -> int:
        return len(self.B)

    @property
    def tableau(self) -> Tableau:
        """The record the compiled loop takes."""
        return Tableau(self.C, self.A, self.B, self.E, self.E3, int(self.err_kind),
                       int(self.error_order))


def _rk4() -> Method:
    A = np.zeros((4, 4))
    A[1, 0] = A[2, 1] = 0.5
    A[3, 2] = 1.0
    return Method("rk4", 4, False, 0, ERR_NONE, np.array([0.0, 0.5, 0.5, 1.0]), A,
                  np.array([1 / 6, 1 / 3, 1 / 3, 1 / 6]), np.zeros(5), np.zeros(5),
                  "classical 4th-order Runge–Kutta, fixed step only")


def _scipy_ivp_module(name: str) -> types.ModuleType:
    """scipy's ``scipy.integrate._ivp.<name>``. A module that imports nothing from scipy
    (the DOP853 coefficients) is loaded from its file alone: importing it the usual way runs
    ``scipy.integrate``'s ``__init__``, which took 0.33 s of the 0.70 s ``import saddle_env``
    (measured with ``python -X importtime``)."""
    import scipy
    path = Path(scipy.__file__).parent / "integrate" / "_ivp" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"saddle_env._scipy_ivp_{name}", path)
    assert spec is not None and spec.loader is not None  # a .py file's spec has a loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _dopri5() -> Method:
    from scipy.integrate._ivp import rk  # imports scipy.integrate: built on first use only
    s = rk.RK45
    A = np.zeros((6, 6))
    A[:, :5] = s.A
    return Method("dopri5", 5, True, s.error_estimator_order, ERR_EMBEDDED, np.array(s.C, float),
                  A, np.array(s.B, float), np.array(s.E, float), np.zeros(7),
                  "Dormand–Prince 5(4), adaptive (or fixed step with dt)")


def _dop853() -> Method:
    t = _scipy_ivp_module("dop853_coefficients")
    n = t.N_STAGES
    return Method("dop853", 8, True, 7, ERR_DOP853, np.array(t.C[:n]), np.array(t.A[:n, :n]),
                  np.array(t.B), np.array(t.E5), np.array(t.E3),
                  "Dormand–Prince 8(5,3), adaptive (or fixed step with dt)")


class _Methods(Mapping):
    """The method registry, each method made on first lookup (dopri5's tableau is read from
    scipy's RK45, whose import costs what `_scipy_ivp_module` avoids)."""

    def __init__(self, makers):
        self._makers = makers
        self._made: dict[str, Method] = {}

    def __getitem__(self, name: str) -> Method:
        if name not in self._made:
            self._made[name] = self._makers[name]()  # KeyError for an unknown name
        return self._made[name]

    def __iter__(self):
        return iter(self._makers)

    def __len__(self) -> int:
        return len(self._makers)


METHODS: Mapping[str, Method] = _Methods({"rk4": _rk4, "dopri5": _dopri5, "dop853": _dop853})


@ir_inline
def _copy_row(dst, src):
    """dst[:] = src, element by element: numba compiles an array-to-slice assignment with a
    formatted shape-mismatch error (string formatting, ~2 s of a cold compile, measured in
    docs/coldstart.md), which a loop over rows of one length never needs."""
    for j in range(dst.shape[0]):
        dst[j] = src[j]


@jit
def reaches(t, h, target):
    """Whether a step h from t reaches the output time ``target`` (then it is clipped to land
    on it exactly; a sliver left over by rounding counts as reached)."""
    return t + h >= target - 1e-13 * max(1.0, abs(target))


@jit
def step_factor(err, exponent):
    """How much the controller scales the step after an accepted one with error norm err."""
    return MAX_FACTOR if err == 0.0 else min(MAX_FACTOR, max(MIN_FACTOR, SAFETY * err ** exponent))


@jit
def _stages(model, p, prof, t, y, h, d, tab, K, ytmp, ynew, want_normal):
    """Stages 2..s of one explicit RK step from (t, y) with K[0] = f(t, y) given; the
    new point goes to ``ynew``. Returns the smallest normal force per unit mass seen at the
    stage points (a by-product of the right-hand side) if ``want_normal``, else +inf."""
    C, A, B = tab.C, tab.A, tab.B
    s = B.shape[0]
    full = COULOMB_ON and model == COULOMB
    lowest = np.inf
    for i in range(1, s):
        for j in range(d):
            acc = 0.0
            for l in range(i):
                acc += A[i, l] * K[l, j]
            ytmp[j] = y[j] + h * acc
        # Slots not integrated ride along (work slot; a coulomb ball's phase, which rhs reads).
        for j in range(d, ROW_WIDTH):
            ytmp[j] = y[j]
        if full:
            ytmp[PHASE_SLOT] = y[PHASE_SLOT]
        n = rhs(model, p, prof, t + C[i] * h, ytmp, K[i], want_normal)
        if want_normal and n < lowest:
            lowest = n
    for j in range(d):
        acc = 0.0
        for l in range(s):
            acc += B[l] * K[l, j]
        ynew[j] = y[j] + h * acc
    for j in range(d, ROW_WIDTH):
        ynew[j] = y[j]
    if full:
        ynew[PHASE_SLOT] = y[PHASE_SLOT]
    return lowest


@jit
def _error_norm(tab, h, d, K, sc):
    """Scaled error norm of the step just taken (≤ 1 means accept)."""
    E, E3 = tab.E, tab.E3
    s1 = K.shape[0]
    if tab.err_kind == ERR_EMBEDDED:
        acc = 0.0
        for j in range(d):
            e = 0.0
            for l in range(s1):
                e += E[l] * K[l, j]
            e *= h / sc[j]
            acc += e * e
        return math.sqrt(acc / d)
    # Dormand–Prince 8(5,3): the 5th-order estimate, damped by the 3rd-order one.
    e5 = 0.0
    e3 = 0.0
    for j in range(d):
        a5 = 0.0
        a3 = 0.0
        for l in range(s1):
            a5 += E[l] * K[l, j]
            a3 += E3[l] * K[l, j]
        e5 += (a5 / sc[j]) ** 2
        e3 += (a3 / sc[j]) ** 2
    if e5 == 0.0 and e3 == 0.0:
        return 0.0
    return abs(h) * e5 / math.sqrt((e5 + 0.01 * e3) * d)


@jit
def _event_value(kind, model, p, prof, t, y, dy):
    """Signed event function: positive while nothing has happened."""
    if kind == STATUS_DETACH:
        return rhs(model, p, prof, t, y, dy, True)
    if COULOMB_ON and kind == TRANSITION:
        return stick_margin(p, prof, t, y)
    return rim_margin(p[P_RIM], p[P_RIM_SQUARE], y[0], y[1])


@jit
def _fired(events, model, p, prof, t, y, dy, normal):
    """Which event (status code) holds at (t, y), detachment first; 0 if none."""
    if events & EVENT_DETACH and normal < 0.0:
        return STATUS_DETACH
    if events & EVENT_ESCAPE and _event_value(STATUS_ESCAPE, model, p, prof, t, y, dy) < 0.0:
        return STATUS_ESCAPE
    return 0


@jit
def _probe_dip(kind, model, p, prof, t, y, hstep, d, tab, K, ytmp, yout, dy):
    """First stage time τ = c_i·h at which a true partial step has event ``kind``'s function
    negative (N < 0, or static friction giving way), or 0 if none."""
    s = tab.B.shape[0]
    for i in range(1, s):
        tau = tab.C[i] * hstep
        if tau <= 0.0 or tau >= hstep:
            continue
        _stages(model, p, prof, t, y, tau, d, tab, K, ytmp, yout, False)
        if _event_value(kind, model, p, prof, t + tau, yout, dy) < 0.0:
            return tau
    return 0.0


@jit
def _stick_dip(K):
    """Whether a sticking coulomb ball's stick margin (which `rhs` leaves in the phase slot of
    each stage's rates) went negative at a stage point of the step just taken."""
    for i in range(1, K.shape[0] - 1):
        if K[i, PHASE_SLOT] < 0.0:
            return True
    return False


@jit
def _locate(kind, model, p, prof, t, y, hstep, d, tab, K, ytmp, yout, dy):
    """Smallest τ in (0, hstep] with event function < 0 at RK-step(y, τ).

    Illinois regula falsi with a bisection fall-back, on the partial step from (t, y);
    K[0] must hold f(t, y). Leaves the state at the returned τ in ``yout``.
    """
    lo, hi = 0.0, hstep
    flo = _event_value(kind, model, p, prof, t, y, dy)
    _stages(model, p, prof, t, y, hi, d, tab, K, ytmp, yout, False)
    fhi = _event_value(kind, model, p, prof, t + hi, yout, dy)
    side = 0
    width = hi - lo
    for _ in range(200):
        if hi - lo <= EVENT_TIME_TOL:
            break
        tm = (lo * fhi - hi * flo) / (fhi - flo)
        # Bisect when regula falsi stalls (bracket not halved in two tries) or misbehaves.
        if not (lo < tm < hi) or (side != 0 and hi - lo > 0.5 * width):
            tm = 0.5 * (lo + hi)
            width = hi - lo
        _stages(model, p, prof, t, y, tm, d, tab, K, ytmp, yout, False)
        fm = _event_value(kind, model, p, prof, t + tm, yout, dy)
        if fm < 0.0:
            hi, fhi = tm, fm
            if side == -1:
                flo *= 0.5
            side = -1
        else:
            lo, flo = tm, fm
            if side == 1:
                fhi *= 0.5
            side = 1
    _stages(model, p, prof, t, y, hi, d, tab, K, ytmp, yout, False)
    return hi


@jit
def _initial_step(model, p, prof, t, y, f0, d, sc, order, ytmp, f1, hmax):
    """Hairer's starting-step heuristic (Vol. I, §II.4)."""
    d0 = 0.0
    d1 = 0.0
    for j in range(d):
        d0 += (y[j] / sc[j]) ** 2
        d1 += (f0[j] / sc[j]) ** 2
    d0 = math.sqrt(d0 / d)
    d1 = math.sqrt(d1 / d)
    h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
    h0 = min(h0, hmax)
    for j in range(STATE_WIDTH):
        ytmp[j] = y[j] + h0 * f0[j] if j < d else y[j]
    rhs(model, p, prof, t + h0, ytmp, f1, False)
    d2 = 0.0
    for j in range(d):
        d2 += ((f1[j] - f0[j]) / sc[j]) ** 2
    d2 = math.sqrt(d2 / d) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** (1.0 / (order + 1))
    return min(100.0 * h0, h1, hmax)


@jit
def workspace(tab, log_rows=0):
    """Scratch memory for `integrate_h` with the method ``tab`` (a `Tableau`); with
    ``log_rows`` > 0 it also keeps a log of a coulomb ball's stick-slip transitions (`log`)."""
    w = np.empty((tab.B.shape[0] + 5 + (log_rows + 1 if log_rows > 0 else 0), STATE_WIDTH))
    if log_rows > 0:
        w[tab.B.shape[0] + 5, 0] = 0.0
    return w


# Columns of a transition-log row: the time and the phase the ball switched to.
LOG_T, LOG_PHASE = 0, 1


@jit
def transition_log(tab, work):
    """The transitions a run with a logging `workspace` recorded: (count, rows); rows beyond
    the log's length are counted but not kept."""
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
    (`_kernels.stop_slip`), and it sticks if static friction can hold it, else starts again."""
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
    """Advance ``y`` (in place) from ``t0`` through the output times ``t_out``; return
    ``(status, t_final)``.

    See `integrate_h`, which this calls with no step-size hint and fresh scratch memory."""
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
        Drive row (DRIVE_* in `saddle_env._kernels`).
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
    s = tab.B.shape[0]
    K = work[:s + 1]
    want_normal = (ctl.events & EVENT_DETACH) != 0
    normal = _begin(model, p, prof, t0, y, K[0], ctl, scale, want_normal)
    stats[2] += 1
    accepted_normal = normal if want_normal else np.nan  # N/m at the last accepted state
    fired = _fired(ctl.events, model, p, prof, t0, y, work[s + 3], normal)
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
        return _initial_step(model, p, prof, t, y, K[0], d, sc, tab.err_order, work[s + 1],
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
    K, ynew = work[:s + 1], work[s + 2]
    adaptive = ctl.dt <= 0.0
    want_normal = (ctl.events & EVENT_DETACH) != 0
    coulomb = COULOMB_ON and model == COULOMB
    exponent = -1.0 / (tab.err_order + 1.0) if adaptive else 0.0
    just_stopped = False  # a spin was just stopped: take a step before stopping one again
    n_steps = 0
    while k < t_out.shape[0]:
        if n_steps >= ctl.max_steps:
            return Outcome(STATUS_MAX_STEPS, t, h_start, accepted_normal)
        target = t_out[k]
        clipped = reaches(t, h, target)  # then the step lands on the output exactly
        hstep = target - t if clipped else h
        restart, just_stopped, hstep, capped = _before_step(model, p, prof, t, y, hstep, tab,
                                                            ctl, scale, stats, work,
                                                            just_stopped)
        if restart:
            continue
        if capped:  # cut short of a stop: it no longer lands on the output
            clipped = False
        if not (hstep > 1e-14 * max(1.0, abs(t))):
            return Outcome(STATUS_FAILED, t, h_start, accepted_normal)
        err, normal, stage_normal = _attempt(model, p, prof, t, y, hstep, d, tab, ctl, scale,
                                             stats, work)
        if not err <= 1.0:
            if not adaptive:
                return Outcome(STATUS_FAILED, t, h_start, accepted_normal)
            # Rejected: shrink and retry (an infinite/NaN error shrinks by the maximum).
            h = hstep * (MIN_FACTOR if not math.isfinite(err) else max(
                MIN_FACTOR, SAFETY * err ** exponent))
            stats[1] += 1
            continue
        n_steps += 1
        stats[0] += 1
        switch_tau, yswitch = -1.0, ynew
        if coulomb and y[PHASE_SLOT] == STICK:
            switch_tau, yswitch = _slip_start_in_step(model, p, prof, t, y, hstep, d, tab, work)
        fired = _fired(ctl.events, model, p, prof, t + hstep, ynew, work[s + 3],
                       normal) if ctl.events else 0
        if not fired and stage_normal < 0.0:
            dipped, tau = _detach_in_dip(model, p, prof, t, y, hstep, d, tab, stats, work)
            if dipped:
                return Outcome(STATUS_DETACH, t + tau, h_start, accepted_normal)
        if fired:
            kind, tau = _earliest_event(ctl.events, model, p, prof, t, y, hstep, d, tab,
                                        normal, switch_tau, stats, work)
            if kind:
                return Outcome(kind, t + tau, h_start, accepted_normal)
        if switch_tau >= 0.0:  # slip starts at t + switch_tau from v_s = 0: go on from there
            t = target if (clipped and switch_tau >= hstep) else t + switch_tau
            normal = _start_slip(model, p, prof, t, y, yswitch, s, want_normal, stats, work)
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


@jit
def _before_step(model, p, prof, t, y, hstep, tab, ctl, scale, stats, work, just_stopped):
    """Cut a step of ``hstep`` at a slip's stop (`_settle_slip`) and a rolling spin's stop
    (`_stop_roll`, skipped right after a spin was stopped: ``just_stopped``), or make the
    switch or the stop there. Returns ``(restart, stopped, hstep, cut)``: whether the loop
    starts the pass again (a phase switched or a spin stopped: the new f(t, y) is in the
    workspace's first row), whether a spin was stopped, the step, and whether it was cut."""
    # the flags: see `compilation.specialise`
    coulomb = COULOMB_ON and model == COULOMB
    cut = False
    if coulomb and y[PHASE_SLOT] != STICK:
        switched, hstep, cut = _settle_slip(model, p, prof, t, y, hstep, tab, ctl, scale,
                                            stats, work)
        if switched:
            return True, just_stopped, hstep, cut
    if RESIST_ON and (model == ROLLING or coulomb) and p[P_RESIST] != 0.0 and not just_stopped:
        stopped, hstep, cut_here = _stop_roll(model, p, prof, t, y, hstep, tab, ctl, scale,
                                              stats, work)
        if stopped:
            return True, True, hstep, cut
        cut = cut or cut_here
    return False, False, hstep, cut


@jit
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


@jit
def _settle_slip(model, p, prof, t, y, hstep, tab, ctl, scale, stats, work):
    """A slipping coulomb ball before a step of ``hstep`` (slip -> stick above): switch its
    phase where `_settle_coulomb` says so, logging the change and writing the new f(t, y)
    into the workspace's first row; else cut the step short of the stop that the slip's
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
        rhs(model, p, prof, t, y, work[0], (ctl.events & EVENT_DETACH) != 0)
        stats[2] += 1
        return True, hstep, False
    if growth < 0.0 and speed > speed_tol and hstep > SLIP_STOP_FRACTION * speed / -growth:
        return False, SLIP_STOP_FRACTION * speed / -growth, True
    return False, hstep, False


@jit
def _stop_roll(model, p, prof, t, y, hstep, tab, ctl, scale, stats, work):
    """Rolling resistance before a step of ``hstep`` (roll stop above): where the rolling
    spin will be held once stopped, snap a spin within the band to 0 (its energy booked as
    work; the new f(t, y) written into the workspace's first row), or cut the step at the
    stop that the spin's deceleration predicts. Returns ``(stopped, hstep, cut)``: whether
    the spin was stopped (then the loop starts the pass again), the step, and whether it
    was cut."""
    s = tab.B.shape[0]
    ytmp, dy = work[s + 1], work[s + 3]
    _set_spin_band(p, y, ctl.atol, ctl.rtol, scale)
    spin, rate = rolling_spin(p, y, work[0])
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
    rhs(model, p, prof, t, y, work[0], (ctl.events & EVENT_DETACH) != 0)
    stats[2] += 1
    return True, hstep, False


@jit
def _attempt(model, p, prof, t, y, hstep, d, tab, ctl, scale, stats, work):
    """One RK step of ``hstep`` from (t, y), f(t, y) in the workspace's first row: the new
    point goes to its row ``s + 2`` and f there to row ``s``. Returns ``(err, normal,
    stage_normal)``: the scaled error norm (adaptive; 0 with a fixed step), inf when the step
    is not finite; N/m at the new point and the lowest N/m at a stage point (if detachment
    events are on)."""
    s = tab.B.shape[0]
    K, ytmp, ynew, sc = work[:s + 1], work[s + 1], work[s + 2], work[s + 4]
    want_normal = (ctl.events & EVENT_DETACH) != 0
    stage_normal = _stages(model, p, prof, t, y, hstep, d, tab, K, ytmp, ynew, want_normal)
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
    err = _error_norm(tab, hstep, d, K, sc) if finite else np.inf
    if COULOMB_ON and model == COULOMB and y[PHASE_SLOT] == ONSET and finite:
        # the lag at the end is in the phase slot of the end's rates (see `rhs`)
        err = max(err, _onset_error(K[s, PHASE_SLOT], ynew, hstep, ctl.atol, ctl.rtol, scale))
    return err, normal, stage_normal


@jit
def _slip_start_in_step(model, p, prof, t, y, hstep, d, tab, work):
    """Where a sticking coulomb ball's static friction gave way inside the step just taken
    (stick -> slip above): at its end (the margin is in the phase slot of the end's rates),
    or only briefly inside it, which a stage point saw and a true partial step at a stage
    time confirms. Returns ``(tau, state)``: the time from t at which slip starts and a copy
    of the state there (located: locating a stopping event later overwrites the step's end),
    or ``(-1, end)`` where the friction held. The step's end stays in the workspace."""
    s = tab.B.shape[0]
    K, ytmp, ynew, dy = work[:s + 1], work[s + 1], work[s + 2], work[s + 3]
    reach = hstep if K[s, PHASE_SLOT] < 0.0 else 0.0
    if reach == 0.0 and _stick_dip(K):
        yend = ynew.copy()
        reach = _probe_dip(TRANSITION, model, p, prof, t, y, hstep, d, tab, K, ytmp, ynew, dy)
        _copy_row(ynew, yend)
    if not reach > 0.0:
        return -1.0, ynew
    yend = ynew.copy()
    tau = _locate(TRANSITION, model, p, prof, t, y, reach, d, tab, K, ytmp, ynew, dy)
    yswitch = ynew.copy()
    _copy_row(ynew, yend)
    return tau, yswitch


@jit
def _detach_in_dip(model, p, prof, t, y, hstep, d, tab, stats, work):
    """N is positive at both ends of the step just taken but a stage point saw it negative:
    a brief dip inside the step. Probe with true partial steps at the stage times; the first
    negative one brackets a crossing, located as usual, and y becomes the state there.
    Returns ``(detached, tau)``, tau the time from t. A false alarm (the stage values are
    low-order estimates) redoes the full step, so the workspace holds it as before."""
    s = tab.B.shape[0]
    K, ytmp, ynew, dy = work[:s + 1], work[s + 1], work[s + 2], work[s + 3]
    tau_dip = _probe_dip(STATUS_DETACH, model, p, prof, t, y, hstep, d, tab, K, ytmp, ynew, dy)
    if tau_dip > 0.0:
        tau = _locate(STATUS_DETACH, model, p, prof, t, y, tau_dip, d, tab, K, ytmp, ynew, dy)
        _copy_row(y, ynew)
        stats[2] += 1
        return True, tau
    _stages(model, p, prof, t, y, hstep, d, tab, K, ytmp, ynew, False)
    rhs(model, p, prof, t + hstep, ynew, K[s], False)
    return False, 0.0


@jit
def _earliest_event(events, model, p, prof, t, y, hstep, d, tab, normal, switch_tau, stats,
                    work):
    """Locate each stopping event that fired at the end of the step just taken, on the
    partial step from (t, y) (still in y, f(t, y) in the workspace's first row); the
    earliest wins. Unless slip starts before it (at ``switch_tau`` ≥ 0 from t), y becomes the
    state at the event and ``(kind, tau)`` is returned, tau the time from t; else ``(0,
    tau)`` and the step goes on to the slip's start."""
    s = tab.B.shape[0]
    K, ytmp, ynew, dy = work[:s + 1], work[s + 1], work[s + 2], work[s + 3]
    ybest = np.empty(STATE_WIDTH)
    yend = ynew.copy()
    best_tau = hstep
    best_kind = 0
    for kind in (STATUS_DETACH, STATUS_ESCAPE):
        if _fired(events & kind, model, p, prof, t + hstep, yend, dy, normal) == kind:
            tau = _locate(kind, model, p, prof, t, y, hstep, d, tab, K, ytmp, ynew, dy)
            if best_kind == 0 or tau < best_tau:
                best_tau, best_kind = tau, kind
                _copy_row(ybest, ynew)
    if switch_tau >= 0.0 and best_tau > switch_tau:
        return 0, best_tau
    _copy_row(y, ybest)
    stats[2] += 1
    return best_kind, best_tau


@jit
def _start_slip(model, p, prof, t, y, yswitch, s, want_normal, stats, work):
    """Slip starts at t from v_s = 0 in the state ``yswitch``: y becomes it, in phase ONSET
    with its rolling velocity, the switch is logged (``s`` the method's stages) and f(t, y)
    written into the workspace's first row. Returns N/m there (if ``want_normal``)."""
    _copy_row(y, yswitch)
    y[PHASE_SLOT] = ONSET
    rolling_velocity(p, y, y)
    _record(work, s, t, SLIP)
    normal = rhs(model, p, prof, t, y, work[0], want_normal)
    stats[2] += 1
    return normal


@ir_inline
def _accept(y, ynew, K, s, coulomb):
    """Move to the accepted step's end: y = ynew and its rates K[0] = K[s]."""
    for j in range(ROW_WIDTH):  # constant length: see _kernels.ROW_WIDTH
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
    """`integrate` for balls ``lo`` to ``hi - 1`` of a batch, each with its own scene row, Ω
    profile and state, on one thread without the GIL (`runner.run_batch` runs ranges on
    several: `compilation.threads.in_threads`).

    All balls start at ``t0`` and share the output times and ``ctl``, except that ball i's
    largest step is ``max_step[i]``. Balls with ``active[i] == False`` are not touched.
    Arrays are indexed by ball first: models (n,), P (n, N_PARAMS), profiles (n, DRIVE_WIDTH) drive
    rows, Y (n, STATE_WIDTH), scales (n, STATE_WIDTH), max_step (n,), Y_out (n, m,
    STATE_WIDTH), status (n,), t_final (n,), stats (n, 4).
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
