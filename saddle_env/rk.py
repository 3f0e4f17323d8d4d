"""Runge–Kutta methods and what one step of them does.

Methods are named, declare their order and live in one registry, ``METHODS`` (the shape of
scipy's ``ivp.METHODS``); the Butcher tableaus of Dormand–Prince 5(4) and 8(5,3) are taken
from scipy (a dependency), so no coefficient is transcribed by hand. The compiled pieces
here act on one step from a state (t, y) with its rates in K[0]: the step itself
(`stages`), its error norm, Hairer's starting step, the event functions (detachment,
escape, a coulomb ball's static friction giving way) and the location of an event inside
the step by root-finding on the partial step ``y(t + τ) = RK-step(y, τ)``, so an event's
time is as accurate as the integrator itself (the root-finder's own tolerance is
``EVENT_TIME_TOL``). The stepping loop that uses them is `saddle_env.integrators`.
"""

from __future__ import annotations

import importlib.util
import math
import types
from collections import namedtuple
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .compilation.jit import inline, jit
from .compilation.specialise import COULOMB_ON, specialisable
from .kernels import PHASE_SLOT, ROW_WIDTH, STATE_WIDTH, rhs, rim_margin, stick_margin
from .scene import COULOMB, P_RIM, P_RIM_SQUARE

# Event flags (a bit mask of the events a run stops at) and the event kinds, which are also
# the status codes `integrators.integrate` returns when one stopped it; TRANSITION, a coulomb
# ball's static friction giving way, is located as they are but stops nothing.
EVENT_DETACH, EVENT_ESCAPE = 1, 2
STATUS_DETACH, STATUS_ESCAPE = 1, 2
TRANSITION = 16

EVENT_TIME_TOL = 1e-12  # [s] width of the final bracket around an event time

# Error-estimate kinds.
ERR_NONE, ERR_EMBEDDED, ERR_DOP853 = 0, 1, 2

Tableau = namedtuple("Tableau", "C A B E E3 err_kind err_order")
Tableau.__doc__ = """A method as the compiled loop sees it (`Method.tableau`): nodes C (s,),
coefficients A (s, s), weights B (s,), error weights E and E3 (s + 1,), the error-estimate
kind (ERR_*) and the estimator's order (sets the controller exponent)."""


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
        """Number of stages ``s`` of the tableau."""
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


@inline
def _stage_sums(a, count, h, d, K, y, out):
    """out[j] = y[j] + h·Σ_{l < count} a[l]·K[l, j] for the first d ≤ ROW_WIDTH slots, each sum
    over l in order. The ROW_WIDTH sums are kept in registers and advanced together: one sum
    at a time waited on each addition in turn, and sums kept in ``out`` went through memory
    (same operations, same order, same bits either way). Slots d.. of K are finite (the
    rates write every slot of a row), so summing them costs nothing but time."""
    s0 = s1 = s2 = s3 = s4 = s5 = 0.0
    for l in range(count):
        c = a[l]
        s0 += c * K[l, 0]
        s1 += c * K[l, 1]
        s2 += c * K[l, 2]
        s3 += c * K[l, 3]
        s4 += c * K[l, 4]
        s5 += c * K[l, 5]
    out[0] = y[0] + h * s0
    out[1] = y[1] + h * s1
    out[2] = y[2] + h * s2
    out[3] = y[3] + h * s3
    if d > 4:
        out[4] = y[4] + h * s4
    if d > 5:
        out[5] = y[5] + h * s5


@jit
def stages(model, p, prof, t, y, h, d, tab, K, ytmp, ynew, want_normal):
    """Stages 2..s of one explicit RK step from (t, y) with K[0] = f(t, y) given; the
    new point goes to ``ynew``. Returns the smallest normal force per unit mass seen at the
    stage points (a by-product of the right-hand side) if ``want_normal``, else +inf."""
    C, A, B = tab.C, tab.A, tab.B
    s = B.shape[0]
    full = COULOMB_ON and model == COULOMB
    lowest = np.inf
    for i in range(1, s):
        if d <= ROW_WIDTH:
            _stage_sums(A[i], i, h, d, K, y, ytmp)
        else:
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
    if d <= ROW_WIDTH:
        _stage_sums(B, s, h, d, K, y, ynew)
    else:
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
def error_norm(tab, h, d, K, sc):
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
def event_value(kind, model, p, prof, t, y, dy):
    """Signed event function: positive while nothing has happened."""
    if kind == STATUS_DETACH:
        return rhs(model, p, prof, t, y, dy, True)
    if COULOMB_ON and kind == TRANSITION:
        return stick_margin(p, prof, t, y)
    return rim_margin(p[P_RIM], p[P_RIM_SQUARE], y[0], y[1])


@jit
def event_fired(events, model, p, prof, t, y, dy, normal):
    """Which event (status code) holds at (t, y), detachment first; 0 if none."""
    if events & EVENT_DETACH and normal < 0.0:
        return STATUS_DETACH
    if events & EVENT_ESCAPE and event_value(STATUS_ESCAPE, model, p, prof, t, y, dy) < 0.0:
        return STATUS_ESCAPE
    return 0


@jit
def probe_dip(kind, model, p, prof, t, y, hstep, d, tab, K, ytmp, yout, dy):
    """First stage time τ = c_i·h at which a true partial step has event ``kind``'s function
    negative (N < 0, or static friction giving way), or 0 if none."""
    s = tab.B.shape[0]
    for i in range(1, s):
        tau = tab.C[i] * hstep
        if tau <= 0.0 or tau >= hstep:
            continue
        stages(model, p, prof, t, y, tau, d, tab, K, ytmp, yout, False)
        if event_value(kind, model, p, prof, t + tau, yout, dy) < 0.0:
            return tau
    return 0.0


@jit
def stick_dip(K):
    """Whether a sticking coulomb ball's stick margin (which `rhs` leaves in the phase slot of
    each stage's rates) went negative at a stage point of the step just taken."""
    for i in range(1, K.shape[0] - 1):
        if K[i, PHASE_SLOT] < 0.0:
            return True
    return False


@jit
def locate(kind, model, p, prof, t, y, hstep, d, tab, K, ytmp, yout, dy):
    """Smallest τ in (0, hstep] with event function < 0 at RK-step(y, τ).

    Illinois regula falsi with a bisection fall-back, on the partial step from (t, y);
    K[0] must hold f(t, y). Leaves the state at the returned τ in ``yout``.
    """
    lo, hi = 0.0, hstep
    flo = event_value(kind, model, p, prof, t, y, dy)
    stages(model, p, prof, t, y, hi, d, tab, K, ytmp, yout, False)
    fhi = event_value(kind, model, p, prof, t + hi, yout, dy)
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
        stages(model, p, prof, t, y, tm, d, tab, K, ytmp, yout, False)
        fm = event_value(kind, model, p, prof, t + tm, yout, dy)
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
    stages(model, p, prof, t, y, hi, d, tab, K, ytmp, yout, False)
    return hi


@jit
def initial_step(model, p, prof, t, y, f0, d, sc, order, ytmp, f1, hmax):
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


specialisable(__name__)
