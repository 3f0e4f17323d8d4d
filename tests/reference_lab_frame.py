"""Independent LAB-FRAME reference model of a ball on a rotating saddle.

Used only by tests, to cross-check the production simulator (which works in the
rotating frame). Everything here is derived in the inertial (laboratory) frame so that
it shares no algebra with a rotating-frame implementation: no centrifugal, Coriolis or
Euler forces appear anywhere below.

Geometry (body = saddle-fixed coordinates):
    f(x, y) = x^2/a - y^2/b,  o = (x, y, f),  n = (-2x/a, 2y/b, 1)/|.|,  c = o + R n.
The saddle turns about the vertical lab axis k by theta(t), theta' = Omega(t), so a body
vector v appears in the lab as Rz(theta) v.  m = 1 throughout (forces are per unit mass).

Contact models
--------------
coulomb : the slipping model's holonomic orbit plus the absolute spin, coupled by a
    regularised Coulomb friction force at the contact (see the section below).
slipping / point : holonomic. The centre is a particle constrained to the moving offset
    surface c_lab(q, t) = Rz(theta(t)) c(q). Euler-Lagrange equations of the lab
    Lagrangian L = 1/2 |d c_lab/dt|^2 - g c_lab_z are derived with sympy.
    Frictionless contact => the spin never couples to the orbit, so it is not integrated.
rolling : nonholonomic. Newton + Euler about the centre in the lab, with the rolling
    constraint "ball material point at the contact moves with the saddle material point
    there" differentiated in time to close the system for the absolute spin omega_lab.

Air drag (both models): a force per unit mass f = -(k1 + k2 |v|) v on the centre, v the
centre's velocity in the laboratory (the air is still there). Slipping: the generalised
force f . dc_lab/dq joins the Euler-Lagrange equations. Rolling: f joins Newton's law.

Only numpy / scipy / sympy are used; nothing is imported from the production package.
"""

from functools import lru_cache

import numpy as np
import sympy as sp
from scipy.integrate import solve_ivp

__all__ = [
    "simulate_lab_frame",
    "body_geometry",
    "jacobi_integral",
]

_K = np.array([0.0, 0.0, 1.0])


# ----------------------------------------------------------------------------------
# Symbolic derivation (done once, cached).  a, b, R, g are kept symbolic so that one
# lambdified function serves every parameter set.
# ----------------------------------------------------------------------------------
def _rz(th):
    c, s = sp.cos(th), sp.sin(th)
    return sp.Matrix([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _body_geometry_sym(x, y, a, b, R):
    """Contact point o, unit normal n and centre c in body axes (sympy)."""
    f = x**2 / a - y**2 / b
    o = sp.Matrix([x, y, f])
    grad = sp.Matrix([-2 * x / a, 2 * y / b, 1])
    n = grad / sp.sqrt(grad.dot(grad))
    return o, n, o + R * n


@lru_cache(maxsize=None)
def _slipping_symbolic():
    """Lab-frame Lagrangian -> M(q, ...) q'' = rhs, plus the lab acceleration of c.

    theta is a genuine function of time here (theta' = Omega, theta'' = Omegadot), so the
    time dependence of the constraint c_lab(q, t) enters exactly as in the inertial
    Lagrangian; nothing about rotating frames is assumed.
    Returns the sympy expressions; _slipping_functions and _coulomb_functions lambdify them.
    """
    t = sp.Symbol("t")
    a, b, R, g = sp.symbols("a b R g", positive=True)
    xf, yf, thf = (sp.Function(s)(t) for s in ("x", "y", "theta"))

    _, n_body, c_body = _body_geometry_sym(xf, yf, a, b, R)
    c_lab = _rz(thf) * c_body
    v_lab = c_lab.diff(t)
    L = sp.Rational(1, 2) * v_lab.dot(v_lab) - g * c_lab[2]

    # Plain symbols to replace derivatives after differentiation.
    x, y, vx, vy, ax, ay, th, Om, Omd = sp.symbols("x y vx vy ax ay th Om Omd")
    subs_order = [  # highest derivatives first, so lower ones are not clobbered
        (xf.diff(t, 2), ax), (yf.diff(t, 2), ay), (thf.diff(t, 2), Omd),
        (xf.diff(t), vx), (yf.diff(t), vy), (thf.diff(t), Om),
        (xf, x), (yf, y), (thf, th),
    ]

    def to_syms(expr):
        for old, new in subs_order:
            expr = expr.subs(old, new)
        return expr

    el = []
    for qf in (xf, yf):
        eq = sp.diff(sp.diff(L, qf.diff(t)), t) - sp.diff(L, qf)
        el.append(to_syms(eq))

    # Euler-Lagrange is linear in (ax, ay): split into mass matrix and right-hand side.
    M = sp.Matrix([[sp.diff(e, acc) for acc in (ax, ay)] for e in el])
    rhs = sp.Matrix([-e.subs({ax: 0, ay: 0}) for e in el])

    acc_lab = to_syms(c_lab.diff(t, 2))   # needs ax, ay for the normal force
    n_lab = to_syms(_rz(thf) * n_body)
    # For drag: the lab velocity of the centre and dc_lab/dq (generalised forces).
    v_sym = to_syms(v_lab)
    J_sym = to_syms(c_lab.jacobian(sp.Matrix([xf, yf])))

    args = (x, y, vx, vy, th, Om, Omd, a, b, R, g)
    c_sym = to_syms(c_lab)
    return args, (ax, ay), M, rhs, acc_lab, n_lab, v_sym, J_sym, c_sym


@lru_cache(maxsize=None)
def _slipping_functions():
    args, (ax, ay), M, rhs, acc_lab, n_lab, v_sym, J_sym, _ = _slipping_symbolic()
    x, y, vx, vy, th, Om, Omd, a, b, R, g = args
    # M and rhs share most subexpressions: one flat function [M11, M12, M21, M22, r1, r2].
    f_Mrhs = sp.lambdify(args, list(M) + list(rhs), modules="math", cse=True)
    f_acc = sp.lambdify(args + (ax, ay), acc_lab, modules="numpy", cse=True)
    f_n = sp.lambdify((x, y, th, a, b), n_lab, modules="numpy", cse=True)
    f_vJ = sp.lambdify((x, y, vx, vy, th, Om, a, b, R), list(v_sym) + list(J_sym),
                       modules="math", cse=True)
    return f_Mrhs, f_acc, f_n, f_vJ


@lru_cache(maxsize=None)
def _coulomb_functions():
    """The slipping model's lab-frame Lagrangian terms, plus what friction needs.

    One flat function of (x, y, vx, vy, th, Om, Omd, a, b, R, g) returning
    [M (4), rhs (2), c'' at q'' = 0 (3), n (3), c' (3), J_lab = dc_lab/dq (3x2), c (3)],
    lab axes.  c'' at q'' = 0 gives N: n . J_lab = 0, so q'' (hence the friction) does not
    enter n . c''.
    """
    args, (ax, ay), M, rhs, acc_lab, n_lab, v_sym, J_sym, c_sym = _slipping_symbolic()
    acc0 = acc_lab.subs({ax: 0, ay: 0})
    flat = list(M) + list(rhs) + list(acc0) + list(n_lab) + list(v_sym) + list(J_sym) \
        + list(c_sym)
    return sp.lambdify(args, flat, modules="math", cse=True)


def _drag(v, drag):
    """Drag force per unit mass on a centre moving at lab velocity v; drag = (k1, k2)."""
    k1, k2 = drag
    return -(k1 + k2 * np.sqrt(v @ v)) * v


@lru_cache(maxsize=None)
def _rolling_functions():
    """Lab-frame o, n, c and the partial derivatives the rolling model needs.

    One lambdified function of (x, y, theta; a, b, R) returning a flat length-30 array
    [o(3), n(3), J_lab = dc_lab/dq (3x2), do/dq (3x2), do/dtheta (3), dn/dq (3x2),
    dn/dtheta (3)], all in lab axes.  Flat output keeps the per-call overhead small
    (the right-hand side is evaluated ~10^5-10^6 times per run).
    """
    x, y, th = sp.symbols("x y th")
    a, b, R = sp.symbols("a b R", positive=True)
    o_b, n_b, c_b = _body_geometry_sym(x, y, a, b, R)
    Rz = _rz(th)
    o, n, c = Rz * o_b, Rz * n_b, Rz * c_b
    q = sp.Matrix([x, y])
    parts = [o, n, c.jacobian(q), o.jacobian(q), o.diff(th), n.jacobian(q), n.diff(th)]
    flat = [e for part in parts for e in part]          # row-major for the 3x2 blocks
    return sp.lambdify((x, y, th, a, b, R), flat, modules="math", cse=True)


@lru_cache(maxsize=None)
def _body_functions():
    """Body-frame c and J = dc/dq and n (for initial conditions and invariants)."""
    x, y = sp.symbols("x y")
    a, b, R = sp.symbols("a b R", positive=True)
    _, n_b, c_b = _body_geometry_sym(x, y, a, b, R)
    J = c_b.jacobian(sp.Matrix([x, y]))
    return sp.lambdify((x, y, a, b, R), [c_b, J, n_b], modules="numpy", cse=True)


# ----------------------------------------------------------------------------------
# Small numeric helpers
# ----------------------------------------------------------------------------------
def _rz_num(th):
    c, s = np.cos(th), np.sin(th)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _cross(u, v):
    # np.cross costs ~30 us on 3-vectors; this is ~10x cheaper and is in the hot loop.
    return np.array([u[1] * v[2] - u[2] * v[1],
                     u[2] * v[0] - u[0] * v[2],
                     u[0] * v[1] - u[1] * v[0]])


def _vec(m):
    return np.asarray(m, dtype=float).reshape(-1)


def body_geometry(a, b, R, x, y):
    """(c, J, n) in body axes at contact point (x, y): centre, dc/dq (3x2), normal."""
    c, J, n = _body_functions()(float(x), float(y), a, b, R)
    return _vec(c), np.asarray(J, dtype=float), _vec(n)


def _check_params(contact, a, b, R):
    if contact not in ("rolling", "slipping", "point", "coulomb"):
        raise ValueError(f"unknown contact model {contact!r}")
    if a <= 0 or b <= 0:
        raise ValueError("a and b must be positive")
    if R < 0:
        raise ValueError("R must be >= 0")
    # The only direction in which the surface is concave towards the ball is x (the
    # valley, curvature 2/a at the centre, its maximum).  Along y the surface falls
    # away from the ball, so b imposes no limit.  R >= a/2 makes c(q) singular.
    if R >= a / 2:
        raise ValueError(f"R={R} must be < a/2={a / 2} (offset surface singular)")
    if contact in ("rolling", "coulomb") and R == 0:
        raise ValueError(f"{contact} needs R > 0 (use contact='point' for a mass point)")


# ----------------------------------------------------------------------------------
# Slipping / point
# ----------------------------------------------------------------------------------
def _simulate_slipping(a, b, R, g, omega, omega_dot, q0, qdot0, t_eval, theta0,
                       rtol, atol, drag):
    f_Mrhs, f_acc, f_n, f_vJ = _slipping_functions()

    def drag_force(t, s):
        x, y, vx, vy, th = (float(v) for v in s)
        vJ = np.array(f_vJ(x, y, vx, vy, th, omega(t), a, b, R))
        return _drag(vJ[:3], drag), vJ[3:].reshape(3, 2)

    def accel(t, s):
        x, y, vx, vy, th = (float(v) for v in s)
        m11, m12, m21, m22, r1, r2 = f_Mrhs(x, y, vx, vy, th, omega(t), omega_dot(t),
                                            a, b, R, g)
        if drag != (0.0, 0.0):
            f, J = drag_force(t, s)
            r1, r2 = r1 + f @ J[:, 0], r2 + f @ J[:, 1]
        return np.linalg.solve([[m11, m12], [m21, m22]], [r1, r2])

    def deriv(t, s):
        qdd = accel(t, s)
        return [s[2], s[3], qdd[0], qdd[1], omega(t)]

    s0 = [q0[0], q0[1], qdot0[0], qdot0[1], theta0]
    sol = _integrate(deriv, s0, t_eval, rtol, atol, ESCAPE_FACTOR * max(a, b))

    n_out = len(t_eval)
    N = np.full(n_out, np.nan)
    for i, (t, s) in enumerate(zip(t_eval, sol.T)):
        if np.isnan(s).any():      # after an escape
            continue
        x, y, vx, vy, th = s
        qdd = accel(t, s)
        acc = _vec(f_acc(x, y, vx, vy, th, omega(t), omega_dot(t), a, b, R, g,
                         qdd[0], qdd[1]))
        n = _vec(f_n(x, y, th, a, b))
        # m c'' = F + m f - m g k; frictionless so F = N n and N = n.(c'' + g k - f).
        f = drag_force(t, s)[0] if drag != (0.0, 0.0) else np.zeros(3)
        N[i] = n @ (acc + g * _K - f)
    return {
        "t": np.asarray(t_eval, dtype=float),
        "x": sol[0], "y": sol[1], "vx": sol[2], "vy": sol[3],
        "theta": sol[4],
        "N_over_mg": N / g,
    }


# ----------------------------------------------------------------------------------
# Rolling
# ----------------------------------------------------------------------------------
def _rolling_eval(t, s, a, b, R, alpha, g, omega, omega_dot, drag=(0.0, 0.0)):
    """Everything the rolling model needs at one state: returns (qdot, wdot, F, n), F the
    contact force per unit mass."""
    x, y, th = s[0], s[1], s[2]
    w = np.asarray(s[3:6], dtype=float)          # absolute spin, lab axes
    Om, Omd = omega(t), omega_dot(t)
    G = np.array(_rolling_functions()(float(x), float(y), float(th), a, b, R))
    o, n = G[0:3], G[3:6]
    J, do_dq = G[6:12].reshape(3, 2), G[12:18].reshape(3, 2)
    do_dth = G[18:21]
    dn_dq, dn_dth = G[21:27].reshape(3, 2), G[27:30]
    c = o + R * n

    # Rolling: v_c + w x (-R n) = Omega k x o  (ball point at contact = saddle point).
    # With c_lab = Rz(theta) c(q):  J q' + Omega k x c = Omega k x o + R w x n.
    # The right side minus Omega k x c is tangent to the offset surface, so the normal
    # equations recover q' exactly (residual is round-off).
    rhs = _cross(Om * _K, o) + R * _cross(w, n) - _cross(Om * _K, c)
    qdot = np.linalg.solve(J.T @ J, J.T @ rhs)

    # Time derivatives of the lab contact point and lab normal along the motion.
    thdot = Om
    odot = do_dq @ qdot + do_dth * thdot
    ndot = dn_dq @ qdot + dn_dth * thdot

    # Differentiate v_c = Omega k x o + R w x n:
    #   c'' = Omegadot k x o + Omega k x o' + R w' x n + R w x n'
    #       = R w' x n + known_part
    known = _cross(Omd * _K, o) + _cross(Om * _K, odot) + R * _cross(w, ndot)
    # Drag on the centre, whose lab velocity is the rolling constraint's Omega k x o + R w x n.
    f = _drag(_cross(Om * _K, o) + R * _cross(w, n), drag)
    # Newton:  F = c'' + g k - f  (m = 1).  Euler about the centre: I w' = (-R n) x F.
    #   alpha R^2 w' = -R n x (R w' x n + known + g k - f)
    #   n x (w' x n) = w' - n (n.w')  =>
    #   [(alpha+1) R^2 1 - R^2 n n^T] w' = -R n x (known + g k - f)
    A = (alpha + 1.0) * R**2 * np.eye(3) - R**2 * np.outer(n, n)
    wdot = np.linalg.solve(A, -R * _cross(n, known + g * _K - f))
    F = R * _cross(wdot, n) + known + g * _K - f
    return qdot, wdot, F, n


def _simulate_rolling(a, b, R, alpha, g, omega, omega_dot, q0, qdot0, t_eval,
                      spin_normal, theta0, rtol, atol, drag):
    # Initial spin: relative to the saddle, rolling needs R w_rel x n = c_rot'.
    # w_rel = n x c_rot'/R satisfies it (c_rot' is tangent); spin about n is free.
    _, Jb, nb = body_geometry(a, b, R, q0[0], q0[1])
    c_rot_dot = Jb @ np.asarray(qdot0, dtype=float)
    w_rel = _cross(nb, c_rot_dot) / R + spin_normal * nb
    w_abs_lab = _rz_num(theta0) @ (w_rel + omega(0.0) * _K)

    def deriv(t, s):
        qdot, wdot, _, _ = _rolling_eval(t, s, a, b, R, alpha, g, omega, omega_dot, drag)
        return [qdot[0], qdot[1], omega(t), wdot[0], wdot[1], wdot[2]]

    s0 = [q0[0], q0[1], theta0, *w_abs_lab]
    sol = _integrate(deriv, s0, t_eval, rtol, atol, ESCAPE_FACTOR * max(a, b))

    n_out = len(t_eval)
    vx, vy, N = np.full(n_out, np.nan), np.full(n_out, np.nan), np.full(n_out, np.nan)
    w_body = np.full((n_out, 3), np.nan)
    for i, (t, s) in enumerate(zip(t_eval, sol.T)):
        if np.isnan(s).any():      # after an escape
            continue
        qdot, _, F, n = _rolling_eval(t, s, a, b, R, alpha, g, omega, omega_dot, drag)
        vx[i], vy[i] = qdot
        N[i] = F @ n
        # Back to saddle axes and subtract the saddle's own rotation.
        w_body[i] = _rz_num(-s[2]) @ s[3:6] - omega(t) * _K
    return {
        "t": np.asarray(t_eval, dtype=float),
        "x": sol[0], "y": sol[1], "vx": vx, "vy": vy,
        "w": w_body,
        "N_over_mg": N / g,
        "theta": sol[2],
    }


# ----------------------------------------------------------------------------------
# Coulomb friction, regularised
# ----------------------------------------------------------------------------------
# Holonomic part as for slipping (the centre on the moving offset surface, q = (x, y)),
# plus the absolute spin omega_lab (lab axes) as a state.  Forces per unit mass on the
# ball: N n (normal), f (friction, tangential, at the contact point), drag (at the
# centre), -g k.
#   Slip velocity (ball material point at the contact minus the saddle's material point
#   there, lab):  v_s = c' + omega x (-R n) - Omega k x o,   o = c - R n.
#   Friction, regularised Coulomb:  f = -mu N v_s / sqrt(|v_s|^2 + eps^2).
#   Normal force: n . (c'' + g k - drag) with c'' = J_lab q'' + (terms without q''), and
#       n . J_lab = 0, so N needs no q''; n . f = 0 (v_s is tangent) so f does not enter.
#   Orbit: Euler-Lagrange with the generalised force (f + drag) . dc_lab/dq.
#   Spin (about the centre):  alpha R^2 omega' = (-R n) x f.
# For |v_s| >> eps this is kinetic Coulomb friction; for |v_s| <~ eps it is a stiff
# viscous law, so "stick" is a creep at |v_s| = eps r / sqrt(1 - r^2), r = |f| / (mu N)
# the fraction of the friction cone the motion needs.  That makes the system stiff
# (relaxation rate ~ mu g (1 + 1/alpha) / eps): integrated with an implicit method.
def _coulomb_eval(t, s, a, b, R, alpha, g, mu, eps, omega, omega_dot, drag):
    """(q'', omega', N, v_s, f) at one state s = (x, y, vx, vy, theta, omega_lab)."""
    x, y, vx, vy, th = (float(v) for v in s[:5])
    w = np.asarray(s[5:8], dtype=float)
    Om = omega(t)
    G = _coulomb_functions()(x, y, vx, vy, th, Om, omega_dot(t), a, b, R, g)
    m11, m12, m21, m22, r1, r2 = G[0:6]
    acc0 = np.array(G[6:9])
    n = np.array(G[9:12])
    v = np.array(G[12:15])
    J = np.array(G[15:21]).reshape(3, 2)
    o = np.array(G[21:24]) - R * n
    fd = _drag(v, drag) if drag != (0.0, 0.0) else np.zeros(3)
    N = n @ (acc0 + g * _K - fd)
    vs = v - R * _cross(w, n) - Om * np.array([-o[1], o[0], 0.0])
    f = -mu * N * vs / np.sqrt(vs @ vs + eps * eps)
    F = f + fd
    r1, r2 = r1 + F @ J[:, 0], r2 + F @ J[:, 1]
    det = m11 * m22 - m12 * m21
    qdd = ((m22 * r1 - m12 * r2) / det, (m11 * r2 - m21 * r1) / det)
    wdot = -_cross(n, f) / (alpha * R)
    return qdd, wdot, N, vs, f


def _simulate_coulomb(a, b, R, alpha, g, omega, omega_dot, q0, qdot0, t_eval,
                      spin_normal, spin, theta0, rtol, atol, drag, mu, eps, method,
                      slip_threshold):
    # Initial relative spin: given, or rolling without slip (as the rolling model).
    _, Jb, nb = body_geometry(a, b, R, q0[0], q0[1])
    if spin is None:
        w_rel = _cross(nb, Jb @ np.asarray(qdot0, dtype=float)) / R + spin_normal * nb
    else:
        w_rel = np.asarray(spin, dtype=float)
    w_abs_lab = _rz_num(theta0) @ (w_rel + omega(0.0) * _K)
    args = (a, b, R, alpha, g, mu, eps, omega, omega_dot, drag)

    def deriv(t, s):
        qdd, wdot, _, _, _ = _coulomb_eval(t, s, *args)
        return [s[2], s[3], qdd[0], qdd[1], omega(t), wdot[0], wdot[1], wdot[2]]

    events = []
    if slip_threshold is not None:
        def slip_crossing(t, s):
            vs = _coulomb_eval(t, s, *args)[3]
            return np.sqrt(vs @ vs) - slip_threshold
        events.append(slip_crossing)

    s0 = [q0[0], q0[1], qdot0[0], qdot0[1], theta0, *w_abs_lab]
    record = {}
    sol = _integrate(deriv, s0, t_eval, rtol, atol, ESCAPE_FACTOR * max(a, b),
                     method=method, events=events, record=record)

    n_out = len(t_eval)
    N, slip = np.full(n_out, np.nan), np.full(n_out, np.nan)
    cone = np.full(n_out, np.nan)
    w_body = np.full((n_out, 3), np.nan)
    for i, (t, s) in enumerate(zip(t_eval, sol.T)):
        if np.isnan(s).any():      # after an escape
            continue
        _, _, Ni, vs, f = _coulomb_eval(t, s, *args)
        N[i], slip[i] = Ni, np.sqrt(vs @ vs)
        cone[i] = np.sqrt(f @ f) / (mu * abs(Ni)) if mu > 0 and Ni != 0 else 0.0
        w_body[i] = _rz_num(-s[4]) @ s[5:8] - omega(t) * _K
    out = {
        "t": np.asarray(t_eval, dtype=float),
        "x": sol[0], "y": sol[1], "vx": sol[2], "vy": sol[3],
        "theta": sol[4],
        "w": w_body,
        "N_over_mg": N / g,
        "slip": slip,
        "friction_over_muN": cone,
        "nfev": record.get("nfev"),
    }
    if slip_threshold is not None:
        # Crossings of |v_s| = slip_threshold: +1 going up (stick -> slip), -1 down.
        tc = np.asarray(record.get("t_events", [[]])[0], dtype=float)
        ys = record.get("y_events", [[]])[0]
        up = [np.sign(_slip_rate(t, y, args)) for t, y in zip(tc, ys)]
        out["slip_crossings"] = (tc, np.asarray(up))
    return out


def _slip_rate(t, s, args, h=1e-9):
    """d|v_s|/dt at (t, s) by a one-sided difference along the flow (sign only used)."""
    def speed(t_, s_):
        vs = _coulomb_eval(t_, s_, *args)[3]
        return np.sqrt(vs @ vs)
    qdd, wdot, _, _, _ = _coulomb_eval(t, s, *args)
    omega = args[7]
    ds = np.array([s[2], s[3], qdd[0], qdd[1], omega(t), *wdot])
    return speed(t + h, np.asarray(s) + h * ds) - speed(t, s)


# The model saddle is unbounded, so an escaping ball runs off to kilometres with ever
# smaller steps (minutes of CPU).  Nothing physical happens that far out; stop there.
ESCAPE_FACTOR = 10.0


def _integrate(deriv, s0, t_eval, rtol, atol, r_escape, method="DOP853", events=(),
               record=None):
    """DOP853 (or `method`) on [0, t_eval[-1]]; states after an escape (|q| > r_escape)
    are NaN.  Extra non-terminal `events` are located; with a dict `record`, their
    t_events / y_events (escape excluded) and nfev are stored there."""
    t_eval = np.asarray(t_eval, dtype=float)
    if t_eval.ndim != 1 or t_eval.size == 0 or t_eval[0] != 0.0:
        raise ValueError("t_eval must be a non-empty 1-D array starting at 0")
    if np.any(np.diff(t_eval) <= 0):
        raise ValueError("t_eval must be strictly increasing")
    out = np.full((len(s0), t_eval.size), np.nan)
    out[:, 0] = s0
    if t_eval.size == 1:
        return out

    def escaped(t, s):
        return np.hypot(s[0], s[1]) - r_escape
    escaped.terminal = True

    sol = solve_ivp(deriv, (0.0, float(t_eval[-1])), s0, method=method,
                    t_eval=t_eval, rtol=rtol, atol=atol, events=[escaped, *events])
    if sol.status < 0:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    if record is not None:
        record.update(t_events=sol.t_events[1:], y_events=sol.y_events[1:], nfev=sol.nfev)
    out[:, :sol.t.size] = sol.y
    return out


# ----------------------------------------------------------------------------------
# Public API
# ----------------------------------------------------------------------------------
def simulate_lab_frame(contact, a, b, R, alpha, g, omega, omega_dot, q0, qdot0, t_eval,
                       spin_normal=0.0, theta0=0.0, rtol=None, atol=None,
                       drag_linear=0.0, drag_quadratic=0.0, mu=None, eps=1e-6,
                       spin=None, method="LSODA", slip_threshold=None):
    """contact in {"rolling", "slipping", "point", "coulomb"} ("point" means R is treated
    as 0, slipping).
    omega, omega_dot: callables t -> float (Omega(t), dOmega/dt).
    q0 = (x0, y0): contact point, body coords [m].
    qdot0 = (vx0, vy0): contact point velocity RELATIVE TO THE ROTATING SADDLE, body coords [m/s].
    spin_normal (rolling only): initial angular velocity about the normal n, RELATIVE to the saddle [rad/s].
    For rolling, the initial angular velocity relative to the saddle is w_rel = n x c_rot' / R + spin_normal n,
    where c_rot' = J q' is the centre velocity relative to the saddle (J = dc/dq); the absolute one is
    w_rel + Omega(0) k (then rotated by theta0 into lab axes).
    t_eval: 1-D array of output times starting at 0.
    drag_linear [1/s], drag_quadratic [1/m]: air drag per unit mass -(k1 + k2 |v|) v on the
    centre, v its velocity in the laboratory.
    Returns dict of arrays, one entry per t_eval, all expressed back in the ROTATING (body) frame:
      "t", "x", "y" (contact point, body coords),
      "vx", "vy" (contact point velocity relative to the saddle, body coords),
      "w" (shape (n, 3): rolling only - ball angular velocity RELATIVE to the saddle, in body
           axes: Rz(-theta) omega_lab - Omega k),
      "N_over_mg" (normal force / (m g)),
      "theta".
    Slipping results have no "w": with a frictionless contact the spin is decoupled and constant.
    rtol, atol: default 1e-12, 1e-14 (coulomb: 1e-10, 1e-11; atol 1e-11 m/s is far below eps).

    contact="coulomb": regularised Coulomb friction f = -mu N v_s / sqrt(|v_s|^2 + eps^2),
    v_s the slip velocity [m/s] of the ball's material point at the contact relative to
    the saddle's material point there.  One coefficient mu (regularisation has no separate
    static one).  Integrated with solve_ivp `method` (stiff: "Radau" or "LSODA").
    spin: initial angular velocity RELATIVE to the saddle in body axes (3,) [rad/s];
    None means rolling without slip, as for "rolling" (with spin_normal).
    Extra outputs: "w" (as rolling), "slip" = |v_s| [m/s], "friction_over_muN" = |f|/(mu N)
    (-> 1 when slipping), "nfev"; with slip_threshold [m/s], "slip_crossings" =
    (times, +1 when |v_s| rises through it (stick -> slip) / -1 when it falls).
    If the ball escapes (|q| > ESCAPE_FACTOR * max(a, b)) integration stops and all
    later entries (except "t") are NaN.
    Mass m = 1 (results are independent of m).  Omega(t) should be smooth between output
    times for DOP853 to reach its tolerance efficiently (kinks are handled, just slowly).
    """
    if contact == "point":
        R = 0.0
    _check_params(contact, a, b, R)
    drag = (float(drag_linear), float(drag_quadratic))
    if contact == "coulomb":
        if mu is None or mu < 0 or eps <= 0:
            raise ValueError("coulomb needs mu >= 0 and eps > 0")
        return _simulate_coulomb(a, b, R, alpha, g, omega, omega_dot, q0, qdot0, t_eval,
                                 spin_normal, spin, theta0,
                                 1e-10 if rtol is None else rtol,
                                 1e-11 if atol is None else atol, drag, float(mu),
                                 float(eps), method, slip_threshold)
    rtol = 1e-12 if rtol is None else rtol
    atol = 1e-14 if atol is None else atol
    if contact == "rolling":
        return _simulate_rolling(a, b, R, alpha, g, omega, omega_dot, q0, qdot0, t_eval,
                                 spin_normal, theta0, rtol, atol, drag)
    return _simulate_slipping(a, b, R, g, omega, omega_dot, q0, qdot0, t_eval, theta0,
                              rtol, atol, drag)


def jacobi_integral(res, a, b, R, alpha, g, Omega, contact):
    """Jacobi integral per unit mass from body-frame results (constant Omega only).

    rolling : 1/2|c_rot'|^2 + 1/2 alpha R^2 |w_rel|^2 - 1/2 Omega^2 (c_x^2+c_y^2) + g c_z
    slipping: the same without the spin term.
    """
    if contact == "point":
        R = 0.0
    h = np.empty(len(res["t"]))
    for i in range(len(h)):
        c, J, _ = body_geometry(a, b, R, res["x"][i], res["y"][i])
        cdot = J @ np.array([res["vx"][i], res["vy"][i]])
        h[i] = 0.5 * cdot @ cdot - 0.5 * Omega**2 * (c[0]**2 + c[1]**2) + g * c[2]
        if contact == "rolling":
            w = res["w"][i]
            h[i] += 0.5 * alpha * R**2 * (w @ w)
    return h
