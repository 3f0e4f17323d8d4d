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
coulomb_exact : exact Coulomb friction as a hybrid model: the rolling model while the ball
    sticks, the coulomb model with f = -mu_k N v_s/|v_s| while it slips, switched at
    located events (see "Coulomb friction, exact" below).
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
Rolling resistance (rolling): a torque -c_rr R N w_t/|w_t| about the centre joins Euler's
law, w_t the spin relative to the turning saddle without its part along n.

Only numpy / scipy / sympy are used; nothing is imported from the production package.
"""

from functools import cache

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


@cache
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


@cache
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


@cache
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
    """Force per unit mass on a centre moving at lab velocity v besides gravity and the
    contact: drag = (k1, k2) air drag, or (k1, k2, fx, fy) with a constant horizontal force
    fixed in the laboratory (a tilted saddle's share of gravity) added."""
    k1, k2 = drag[0], drag[1]
    f = -(k1 + k2 * np.sqrt(v @ v)) * v
    if len(drag) > 2:
        f = f + np.array([drag[2], drag[3], 0.0])
    return f


@cache
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


@cache
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
    if contact not in ("rolling", "slipping", "point", "coulomb", "coulomb_exact"):
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
    if contact in ("rolling", "coulomb", "coulomb_exact") and R == 0:
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
        if any(drag):
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
        f = drag_force(t, s)[0] if any(drag) else np.zeros(3)
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
def _rolling_eval(t, s, a, b, R, alpha, g, omega, omega_dot, drag=(0.0, 0.0), c_rr=0.0):
    """Everything the rolling model needs at one state: returns (qdot, wdot, F, n), F the
    contact force per unit mass. ``c_rr``: rolling resistance, a torque c_rr R N against
    the rolling part of the spin relative to the saddle (undefined at zero: not used there)."""
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
    torque = -R * _cross(n, known + g * _K - f)
    if c_rr:
        # Rolling resistance: tau = -c_rr R N w_t/|w_t| about the centre, with N = F.n, which
        # w' does not enter ((w' x n).n = 0), and w_t the spin relative to the turning saddle
        # (lab axes) without its part along n.
        w_rel = w - Om * _K
        w_t = w_rel - (n @ w_rel) * n
        torque = torque - c_rr * R * ((known + g * _K - f) @ n) * w_t / np.linalg.norm(w_t)
    wdot = np.linalg.solve(A, torque)
    F = R * _cross(wdot, n) + known + g * _K - f
    return qdot, wdot, F, n


def _simulate_rolling(a, b, R, alpha, g, omega, omega_dot, q0, qdot0, t_eval,
                      spin_normal, theta0, rtol, atol, drag, c_rr=0.0):
    # Initial spin: relative to the saddle, rolling needs R w_rel x n = c_rot'.
    # w_rel = n x c_rot'/R satisfies it (c_rot' is tangent); spin about n is free.
    _, Jb, nb = body_geometry(a, b, R, q0[0], q0[1])
    c_rot_dot = Jb @ np.asarray(qdot0, dtype=float)
    w_rel = _cross(nb, c_rot_dot) / R + spin_normal * nb
    w_abs_lab = _rz_num(theta0) @ (w_rel + omega(0.0) * _K)

    def deriv(t, s):
        qdot, wdot, _, _ = _rolling_eval(t, s, a, b, R, alpha, g, omega, omega_dot, drag,
                                         c_rr)
        return [qdot[0], qdot[1], omega(t), wdot[0], wdot[1], wdot[2]]

    s0 = [q0[0], q0[1], theta0, *w_abs_lab]
    sol = _integrate(deriv, s0, t_eval, rtol, atol, ESCAPE_FACTOR * max(a, b))

    n_out = len(t_eval)
    vx, vy, N = np.full(n_out, np.nan), np.full(n_out, np.nan), np.full(n_out, np.nan)
    w_body = np.full((n_out, 3), np.nan)
    for i, (t, s) in enumerate(zip(t_eval, sol.T)):
        if np.isnan(s).any():      # after an escape
            continue
        qdot, _, F, n = _rolling_eval(t, s, a, b, R, alpha, g, omega, omega_dot, drag, c_rr)
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
    fd = _drag(v, drag) if any(drag) else np.zeros(3)
    N = n @ (acc0 + g * _K - fd)
    vs = v - R * _cross(w, n) - Om * np.array([-o[1], o[0], 0.0])
    f = -mu * N * vs / np.sqrt(vs @ vs + eps * eps)
    F = f + fd
    r1, r2 = r1 + F @ J[:, 0], r2 + F @ J[:, 1]
    det = m11 * m22 - m12 * m21
    qdd = ((m22 * r1 - m12 * r2) / det, (m11 * r2 - m21 * r1) / det)
    wdot = -_cross(n, f) / (alpha * R)
    return qdd, wdot, N, vs, f


def _initial_lab_spin(a, b, R, q0, qdot0, spin, spin_normal, theta0, omega):
    """The ball's absolute spin at t = 0 in lab axes: ``spin`` (relative to the saddle, in its
    axes) if given, else the rolling spin of the start plus ``spin_normal`` about the normal
    (as the rolling model starts)."""
    _, Jb, nb = body_geometry(a, b, R, q0[0], q0[1])
    if spin is None:
        w_rel = _cross(nb, Jb @ np.asarray(qdot0, dtype=float)) / R + spin_normal * nb
    else:
        w_rel = np.asarray(spin, dtype=float)
    return _rz_num(theta0) @ (w_rel + omega(0.0) * _K)


def _simulate_coulomb(a, b, R, alpha, g, omega, omega_dot, q0, qdot0, t_eval,
                      spin_normal, spin, theta0, rtol, atol, drag, mu, eps, method,
                      slip_threshold):
    w_abs_lab = _initial_lab_spin(a, b, R, q0, qdot0, spin, spin_normal, theta0, omega)
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


# ----------------------------------------------------------------------------------
# Coulomb friction, exact: a hybrid (event-driven) stick / slip model
# ----------------------------------------------------------------------------------
# Smooth ODEs switched at located events (scipy solve_ivp, terminal events).  Nothing
# here follows the production loop: the phases are the lab-frame models above, the
# switches are events on their own states.
#   STICK: the lab-frame ROLLING model (_rolling_eval, state (x, y, theta, omega_lab)).
#       The friction it needs is the tangential part of its contact force F,
#       f = F - (F.n) n, N = F.n.  Event: mu_s N - |f| falls through 0 -> slip.
#   SLIP: the holonomic orbit + spin with exact kinetic friction f = -mu_k N v_s/|v_s|
#       (_coulomb_eval with eps = 0; state (x, y, vx, vy, theta, omega_lab)).
#   A friction impulse P (tangent, at the contact, per unit mass) changes the state by
#       dc' = P,  d omega = (-R n) x P / (alpha R^2) = -n x P / (alpha R),
#       d v_s = dc' - R d omega x n = P + P/alpha = k P,   k = 1 + 1/alpha.
#   Slip -> stick: |v_s| falls through delta (near the stop |v_s| falls at
#       k mu_k N - v_s^.a0 > 0, so the event has a non-zero slope).  The slip left is
#       removed by the impulse P = -v_s/k: the friction impulse the last delta/|d|v_s|/dt|
#       seconds of slip would deliver, to first order.  It arrives early by that time, so
#       it moves the ball by ~ delta^2/(2 |d|v_s|/dt|); the velocities change at second
#       order (measured: halving delta changes the outputs by < 1e-14).  The stop's time
#       is recorded extrapolated to |v_s| = 0: t + delta/|d|v_s|/dt| (without that the
#       time is delta/|d|v_s|/dt| early, 3e-8 s at a stop where |v_s| falls at 0.03 m/s^2).
#       Then: stick if static friction can hold the ball (mu_s N >= |f| of the rolling
#       model there), else the slip starts again at once (a "restart", no change of phase).
#   Stick -> slip: at the event the rolling model needs |f| = mu_s N.  In the slip model
#       with v_s = 0, v_s' = a0 - k mu_k N u for a friction direction u; the rolling
#       model's f keeps v_s' = 0, so a0 = -k f, and a slip consistent with its own
#       friction (v_s' parallel to u) has u = a0/|a0| = -f/|f|: it starts along the excess
#       push and grows at v_s' . u = k (|f| - mu_k N) >= 0 (0 at the instant when
#       mu_s = mu_k, so then |v_s| grows as t^2; with mu_s > mu_k linearly).
#       Its direction is undefined at v_s = 0 and stiff just after (it turns towards a0
#       at ~ k mu_k N / |v_s|), so the slip model cannot start from v_s = 0 exactly.  It
#       starts from v_s = delta0 u (impulse P = delta0 u / k), at a time chosen so that the
#       impulse replaces the slip that would have grown by then: from the event the stick
#       model goes on (PRESLIP) with one more state z, z' = k (|f| - mu_k N), the slip
#       speed the exact model would have reached (to first order: it is v_s' . u
#       integrated); when z = delta0 the slip model takes over with v_s = delta0 u.
#       Starting instead at the event with the impulse (onset="impulse") leaves the slip
#       delta0 too large for the rest of the slip phase: measured 8e-10 m/s and 6e-11 m at
#       delta0 = 1e-10, changing in proportion to delta0; the delayed start removes that
#       first-order error (measured below).  The stick -> slip time recorded is the event's.
#   ONSET: a young slip's direction is stiff (~ 1e9 /s at delta0 = 1e-10 m/s), so until
#       |v_s| reaches v_switch the slip is integrated with an implicit method (Radau),
#       then with the explicit one.  A slip that dies in onset (|v_s| falls through
#       delta0/2 without having reached delta) is stopped as at delta.
# Phase changes are recorded as (t, "stick" | "slip"); "restarts" counts the slips that
# stopped and started again at once, "touches" the PRESLIPs whose z fell back to 0
# (static friction regained before any slip grew: no change of phase), "stops" the
# (time, -d|v_s|/dt [m/s^2]) of every stop (a small rate makes the stop's time
# ill-conditioned: an error e in v_s moves it by e / rate).
STICK_PHASE, SLIP_PHASE, ONSET_PHASE, PRESLIP_PHASE = 0, 1, 2, 3


def _simulate_coulomb_exact(a, b, R, alpha, g, omega, omega_dot, q0, qdot0, t_eval,
                            spin_normal, spin, theta0, rtol, atol, drag, mu_k, mu_s,
                            delta, delta0, v_switch, method, onset_method, onset):
    kf = 1.0 + 1.0 / alpha
    t_eval = np.asarray(t_eval, dtype=float)
    if t_eval.ndim != 1 or t_eval.size == 0 or t_eval[0] != 0.0:
        raise ValueError("t_eval must be a non-empty 1-D array starting at 0")
    if np.any(np.diff(t_eval) <= 0):
        raise ValueError("t_eval must be strictly increasing")
    r_escape = ESCAPE_FACTOR * max(a, b)
    geom = _rolling_functions()
    slip_args = (a, b, R, alpha, g, mu_k, 0.0, omega, omega_dot, drag)

    def rolling(t, s):
        return _rolling_eval(t, s, a, b, R, alpha, g, omega, omega_dot, drag)

    def slip_eval(t, s):
        with np.errstate(invalid="ignore", divide="ignore"):   # v_s = 0 only at trial points
            return _coulomb_eval(t, s, *slip_args)

    def slip_velocity(t, s):
        return _coulomb_eval(t, s, a, b, R, alpha, g, 0.0, 1.0, omega, omega_dot, drag)[3]

    def friction_needed(t, s):
        qdot, wdot, F, n = rolling(t, s)
        N = F @ n
        return qdot, wdot, F - N * n, N, n

    def stick_deriv(t, s):
        qdot, wdot, _, _ = rolling(t, s)
        return [qdot[0], qdot[1], omega(t), wdot[0], wdot[1], wdot[2]]

    def preslip_deriv(t, s):
        qdot, wdot, f, N, _ = friction_needed(t, s)
        return [qdot[0], qdot[1], omega(t), wdot[0], wdot[1], wdot[2],
                kf * (np.sqrt(f @ f) - mu_k * N)]

    def slip_deriv(t, s):
        qdd, wdot, _, _, _ = slip_eval(t, s)
        return [s[2], s[3], qdd[0], qdd[1], omega(t), wdot[0], wdot[1], wdot[2]]

    def margin(t, s):                       # mu_s N - |f| of the rolling model
        _, _, f, N, _ = friction_needed(t, s)
        return mu_s * N - np.sqrt(f @ f)

    def start_slip(t, s, speed):
        """Rolling state -> slip state with v_s = speed along the push a0 = -k f."""
        qdot, _, f, _, n = friction_needed(t, s)
        u = -f / np.sqrt(f @ f)
        J = np.array(geom(float(s[0]), float(s[1]), float(s[2]), a, b, R)[6:12]).reshape(3, 2)
        P = speed * u / kf
        dq = np.linalg.solve(J.T @ J, J.T @ P)
        w = np.asarray(s[3:6], dtype=float) - _cross(n, P) / (alpha * R)
        return np.array([s[0], s[1], qdot[0] + dq[0], qdot[1] + dq[1], s[2], *w])

    def stop_slip(t, s):
        """Slip state -> rolling state: the impulse P = -v_s/k removes the slip."""
        vs = slip_velocity(t, s)
        n = np.array(geom(float(s[0]), float(s[1]), float(s[4]), a, b, R)[3:6])
        w = np.asarray(s[5:8], dtype=float) + _cross(n, vs / kf) / (alpha * R)
        return np.array([s[0], s[1], s[4], *w])

    def time_to_stop(t, s):
        """|v_s| / (-d|v_s|/dt): v_s' by a central difference along the slip flow (v_s, a
        vector, is smooth through 0 even where |v_s| is not)."""
        h = 1e-7
        ds = h * np.asarray(slip_deriv(t, s))
        vs_dot = (slip_velocity(t + h, s + ds) - slip_velocity(t - h, s - ds)) / (2 * h)
        vs = slip_velocity(t, s)
        speed = np.sqrt(vs @ vs)
        return speed / max(-(vs @ vs_dot) / speed, 1e-300)

    def speed_event(level, direction):
        def ev(t, s):
            vs = slip_velocity(t, s)
            return np.sqrt(vs @ vs) - level
        ev.terminal, ev.direction = True, direction
        return ev

    def escaped(t, s):
        return np.hypot(s[0], s[1]) - r_escape
    escaped.terminal = True

    def stick_limit(t, s):
        return margin(t, s)
    stick_limit.terminal, stick_limit.direction = True, -1

    def slip_grown(t, s):                   # PRESLIP: z reached delta0
        return s[6] - delta0
    slip_grown.terminal, slip_grown.direction = True, 1

    def held(t, s):                         # PRESLIP: z back to 0
        return s[6]
    held.terminal, held.direction = True, -1

    stopped = speed_event(delta, -1)
    grown = speed_event(v_switch, +1)
    died = speed_event(0.5 * delta0, -1)
    plans = {  # phase -> (rhs, events (escape first), method)
        STICK_PHASE: (stick_deriv, [escaped, stick_limit], method),
        PRESLIP_PHASE: (preslip_deriv, [escaped, slip_grown, held], method),
        SLIP_PHASE: (slip_deriv, [escaped, stopped], method),
        ONSET_PHASE: (slip_deriv, [escaped, grown, stopped, died], onset_method),
    }

    def begin_slip(t, s_roll):
        if onset == "delayed":
            return PRESLIP_PHASE, np.array([*s_roll, 0.0])
        return ONSET_PHASE, start_slip(t, s_roll, delta0)

    def settle(t, s_slip):
        """After a stop (or at the start): stick if static friction holds, else slip again."""
        s_roll = stop_slip(t, s_slip)
        if margin(t, s_roll) >= 0.0:
            return STICK_PHASE, s_roll
        return begin_slip(t, s_roll)

    # the start: the given spin (slip unless it is the rolling one) or the rolling spin
    w_lab = _initial_lab_spin(a, b, R, q0, qdot0, spin, spin_normal, theta0, omega)
    s = np.array([q0[0], q0[1], qdot0[0], qdot0[1], theta0, *w_lab], dtype=float)
    vs0 = slip_velocity(0.0, s)
    transitions = []
    stats = {"restarts": 0, "touches": 0, "nfev": 0, "steps": 0, "onset_nfev": 0,
             "stops": []}
    if np.sqrt(vs0 @ vs0) > delta:
        phase = SLIP_PHASE if np.sqrt(vs0 @ vs0) >= v_switch else ONSET_PHASE
    else:
        phase, s = settle(0.0, s)

    def describe(t, phase, s):
        """(x, y, vx, vy, theta, w_body (3), N/g, |v_s|, phase) at one state."""
        if phase in (STICK_PHASE, PRESLIP_PHASE):
            qdot, _, F, n = rolling(t, s[:6])
            x, y, th, w, N = s[0], s[1], s[2], s[3:6], F @ n
            speed = 0.0 if phase == STICK_PHASE else s[6]
        else:
            _, _, N, vs, _ = slip_eval(t, s)
            x, y, qdot, th, w, speed = s[0], s[1], s[2:4], s[4], s[5:8], np.sqrt(vs @ vs)
        w_body = _rz_num(-th) @ np.asarray(w, dtype=float) - omega(t) * _K
        return [x, y, qdot[0], qdot[1], th, *w_body, N / g,
                speed, STICK_PHASE if phase == STICK_PHASE else SLIP_PHASE]

    rows = np.full((t_eval.size, 11), np.nan)
    rows[0] = describe(0.0, phase, s)
    t, i = 0.0, 1
    while i < t_eval.size:
        if t >= t_eval[i]:                                  # an event right at an output
            rows[i] = describe(t, phase, s)
            i += 1
            continue
        fun, events, meth = plans[phase]
        sol = solve_ivp(fun, (t, float(t_eval[i])), s, method=meth, rtol=rtol, atol=atol,
                        events=events)
        if sol.status < 0:
            raise RuntimeError(f"solve_ivp failed: {sol.message}")
        stats["nfev"] += sol.nfev
        stats["steps"] += sol.t.size - 1
        if phase == ONSET_PHASE:
            stats["onset_nfev"] += sol.nfev
        t, s = float(sol.t[-1]), sol.y[:, -1]
        if sol.status == 0:                                 # reached the output time
            rows[i] = describe(t, phase, s)
            i += 1
            continue
        ev = events[next(k for k, te in enumerate(sol.t_events) if te.size)]
        if ev is escaped:
            break
        if ev is stick_limit:
            transitions.append((t, "slip"))
            phase, s = begin_slip(t, s)
        elif ev is slip_grown:
            phase, s = ONSET_PHASE, start_slip(t, s[:6], s[6])
        elif ev is held:
            transitions.pop()
            stats["touches"] += 1
            phase, s = STICK_PHASE, s[:6]
        elif ev is grown:
            phase = SLIP_PHASE
        else:                                               # stopped, or died in onset
            t_left = time_to_stop(t, s)
            t_stop = t + t_left
            stats["stops"].append((t_stop, (delta if ev is stopped else 0.5 * delta0) / t_left))
            phase, s = settle(t, s)
            if phase == STICK_PHASE:
                transitions.append((t_stop, "stick"))
            else:
                stats["restarts"] += 1
    return {
        "t": t_eval,
        "x": rows[:, 0], "y": rows[:, 1], "vx": rows[:, 2], "vy": rows[:, 3],
        "theta": rows[:, 4], "w": rows[:, 5:8], "N_over_mg": rows[:, 8],
        "slip": rows[:, 9], "phase": rows[:, 10],
        "transitions": transitions, "stats": stats,
    }


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
                       spin=None, method=None, slip_threshold=None, mu_static=None,
                       delta=1e-9, delta0=1e-10, v_switch=1e-6, onset_method="Radau",
                       onset="delayed", rolling_resistance=0.0, force=(0.0, 0.0)):
    """contact in {"rolling", "slipping", "point", "coulomb"} ("point" means R is treated
    as 0, slipping).
    omega, omega_dot: callables t -> float (Omega(t), dOmega/dt).
    q0 = (x0, y0): contact point, body coords [m].
    qdot0 = (vx0, vy0): contact point velocity RELATIVE TO THE ROTATING SADDLE, body coords [m/s].
    spin_normal (rolling only): initial angular velocity about the normal n, RELATIVE to the saddle
    [rad/s]. For rolling, the initial angular velocity relative to the saddle is w_rel = n x c_rot'
    / R + spin_normal n, where c_rot' = J q' is the centre velocity relative to the saddle (J =
    dc/dq); the absolute one is w_rel + Omega(0) k (then rotated by theta0 into lab axes).
    t_eval: 1-D array of output times starting at 0.
    drag_linear [1/s], drag_quadratic [1/m]: air drag per unit mass -(k1 + k2 |v|) v on the
    centre, v its velocity in the laboratory.
    force: (fx, fy) [m/s^2], a constant horizontal force per unit mass fixed in the
    laboratory (with g reduced to g cos(tilt), a saddle whose axis is tilted).
    rolling_resistance (rolling only): c_rr, a torque c_rr R N against the rolling part of
    the spin relative to the saddle, for a ball that keeps rolling (no static hold).
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
    static one).  Integrated with solve_ivp `method` (stiff: "Radau" or "LSODA", the default).
    spin: initial angular velocity RELATIVE to the saddle in body axes (3,) [rad/s];
    None means rolling without slip, as for "rolling" (with spin_normal).
    Extra outputs: "w" (as rolling), "slip" = |v_s| [m/s], "friction_over_muN" = |f|/(mu N)
    (-> 1 when slipping), "nfev"; with slip_threshold [m/s], "slip_crossings" =
    (times, +1 when |v_s| rises through it (stick -> slip) / -1 when it falls).
    contact="coulomb_exact": exact Coulomb friction, a hybrid stick (the rolling model) /
    slip (f = -mu N v_s/|v_s|) model switched at located events (see the section above
    _simulate_coulomb_exact).  mu: kinetic coefficient; mu_static (default mu) >= mu.
    delta [m/s]: a slip that falls to |v_s| = delta is stopped by the impulse that removes
    it; delta0 [m/s]: a slip starts at |v_s| = delta0 along the push (onset="delayed":
    when the slip would have grown to delta0; "impulse": at the stick -> slip event, an
    O(delta0) error kept for measuring that); v_switch [m/s]: the
    onset of a slip is integrated with `onset_method` (implicit) until |v_s| = v_switch,
    everything else with `method` (default "DOP853" here).  rtol, atol default 1e-12,
    1e-15.  spin as for "coulomb".  Outputs as "coulomb" ("w", "slip" = |v_s|), plus
    "phase" (0 stick, 1 slip per output), "transitions" [(t, "stick" | "slip")] and
    "stats" (nfev, steps, onset_nfev, restarts = slips stopped and restarted at once,
    touches, stops = [(t, -d|v_s|/dt)]).
    If the ball escapes (|q| > ESCAPE_FACTOR * max(a, b)) integration stops and all
    later entries (except "t") are NaN.
    Mass m = 1 (results are independent of m).  Omega(t) should be smooth between output
    times for DOP853 to reach its tolerance efficiently (kinks are handled, just slowly).
    """
    if contact == "point":
        R = 0.0
    _check_params(contact, a, b, R)
    drag = (float(drag_linear), float(drag_quadratic))
    if force != (0.0, 0.0):
        drag = (*drag, float(force[0]), float(force[1]))
    if contact == "coulomb":
        if mu is None or mu < 0 or eps <= 0:
            raise ValueError("coulomb needs mu >= 0 and eps > 0")
        return _simulate_coulomb(a, b, R, alpha, g, omega, omega_dot, q0, qdot0, t_eval,
                                 spin_normal, spin, theta0,
                                 1e-10 if rtol is None else rtol,
                                 1e-11 if atol is None else atol, drag, float(mu),
                                 float(eps), "LSODA" if method is None else method,
                                 slip_threshold)
    if contact == "coulomb_exact":
        if mu is None or mu < 0:
            raise ValueError("coulomb_exact needs mu >= 0")
        mu_s = float(mu) if mu_static is None else float(mu_static)
        if mu_s < mu:
            raise ValueError("mu_static must be >= mu")
        if not 0 < delta0 < delta < v_switch:
            raise ValueError("need 0 < delta0 < delta < v_switch")
        if onset not in ("delayed", "impulse"):
            raise ValueError(f"unknown onset {onset!r}")
        return _simulate_coulomb_exact(
            a, b, R, alpha, g, omega, omega_dot, q0, qdot0, t_eval, spin_normal, spin,
            theta0, 1e-12 if rtol is None else rtol, 1e-15 if atol is None else atol, drag,
            float(mu), mu_s, float(delta), float(delta0), float(v_switch),
            "DOP853" if method is None else method, onset_method, onset)
    rtol = 1e-12 if rtol is None else rtol
    atol = 1e-14 if atol is None else atol
    if contact == "rolling":
        return _simulate_rolling(a, b, R, alpha, g, omega, omega_dot, q0, qdot0, t_eval,
                                 spin_normal, theta0, rtol, atol, drag,
                                 float(rolling_resistance))
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
