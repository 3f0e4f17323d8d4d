"""BENCHMARK PEER — the equations of motion written as a scientist would, in plain numpy.

This module is *not* used by the simulator. It is the peer that `saddle-bench` hands to
``scipy.integrate.solve_ivp`` (the baseline the compiled integrators are measured
against), and a third, independent cross-check of the kernels (``tests/test_workprecision.py``
checks that it agrees with ``saddle_env.kernels.rhs`` to ~1e-12).

It is deliberately written from docs/physics.md, not from ``kernels.py``: vectors are numpy
arrays, cross products are ``np.cross``, the 3×3 spin system and the 2×2 tangent system
are solved with ``np.linalg.solve`` (the kernels invert them in closed form), and the
second derivative of the unit normal comes from the chain rule on n = m/|m| (the kernels
use a projected form).

State layout as in the simulator: rolling ``(x, y, wx, wy, wz)``, slipping/point
``(x, y, vx, vy)`` — contact point [m] in the rotating frame, and the spin relative to the
saddle [rad/s] or the contact point's velocity [m/s].
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

K_HAT = np.array([0.0, 0.0, 1.0])


class PeerModel:
    """The rotating-saddle ball, per unit mass, as plain numpy.

    Parameters
    ----------
    a, b, R, alpha, g : float
        Scene parameters (``R = 0`` for the mass point).
    rolling : bool
        Pure rolling (5 states) or frictionless slipping (4 states).
    omega : (w0, rate, amp, freq, phase[, decay, decay_rate])
        Ω(t) = w0 + rate·t + amp·sin(freq·t + phase) + decay·exp(−decay_rate·t), the last term
        being a voltage-driven motor relaxing to its steady speed.
    drilling_friction : float
        Rate [1/s] relaxing the spin about the normal (rolling).
    force : (fx, fy)
        Lab-frame horizontal force per unit mass [m/s²].
    theta0 : float
        The saddle angle at t = 0 [rad].
    """

    def __init__(self, a: float, b: float, R: float, alpha: float, g: float, rolling: bool,
                 omega: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0),
                 drilling_friction: float = 0.0, force: tuple[float, float] = (0.0, 0.0),
                 theta0: float = 0.0) -> None:
        self.a, self.b, self.R, self.alpha, self.g = a, b, R, alpha, g
        self.rolling = rolling
        (self.w0, self.rate, self.amp, self.freq, self.phase, self.decay,
         self.decay_rate) = (list(omega) + [0.0] * 7)[:7]
        self.drill = drilling_friction
        self.force = np.array([force[0], force[1], 0.0])
        self.theta0 = theta0

    @classmethod
    def from_scene(cls, scene, omega=(0.0,), force=(0.0, 0.0), theta0=0.0) -> PeerModel:
        """Build from a `saddle_env.Scene` (its parameters only) and an Ω profile tuple."""
        return cls(scene.a, scene.b, scene.radius, scene.alpha, scene.g, scene.rolling,
                   tuple(omega), scene.drilling_friction, force, theta0)

    # -- the saddle's motion -----------------------------------------------------------
    def Omega(self, t: float) -> tuple[float, float]:
        """Ω(t) and dΩ/dt [rad/s, rad/s²]."""
        ph = self.freq * t + self.phase
        motor = self.decay * np.exp(-self.decay_rate * t)
        return (self.w0 + self.rate * t + self.amp * np.sin(ph) + motor,
                self.rate + self.amp * self.freq * np.cos(ph) - self.decay_rate * motor)

    def angle(self, t: float) -> float:
        """The saddle's angle θ(t) [rad], Ω integrated from ``theta0``."""
        th = self.theta0 + self.w0 * t + 0.5 * self.rate * t * t
        if self.decay != 0.0:  # ∫₀ᵗ decay·e^{−k s} ds
            th += self.decay * (1.0 - np.exp(-self.decay_rate * t)) / self.decay_rate
        if self.freq != 0.0:
            return th - self.amp / self.freq * (np.cos(self.freq * t + self.phase) - np.cos(self.phase))
        return th + self.amp * np.sin(self.phase) * t

    # -- geometry ---------------------------------------------------------------------
    def surface(self, x: float, y: float):
        """Unnormalised normal m = (−f_x, −f_y, 1), its rates dm/dx and dm/dy, and |m|."""
        m = np.array([-2.0 * x / self.a, 2.0 * y / self.b, 1.0])
        return m, np.array([-2.0 / self.a, 0.0, 0.0]), np.array([0.0, 2.0 / self.b, 0.0])

    def frame(self, q: np.ndarray):
        """n, c and J = dc/dq (3×2) at contact point q, and (m, dm/dx, dm/dy, |m|) for `rates`."""
        x, y = q
        m, mx, my = self.surface(x, y)
        s = np.linalg.norm(m)
        n = m / s
        o = np.array([x, y, x * x / self.a - y * y / self.b])
        c = o + self.R * n
        # dn/dq_i = dm_i/s − m (m·dm_i)/s³
        dn_dx = mx / s - m * (m @ mx) / s**3
        dn_dy = my / s - m * (m @ my) / s**3
        do_dx = np.array([1.0, 0.0, 2.0 * x / self.a])
        do_dy = np.array([0.0, 1.0, -2.0 * y / self.b])
        J = np.column_stack([do_dx + self.R * dn_dx, do_dy + self.R * dn_dy])
        return n, c, J, (m, mx, my, s)

    def rates(self, geo, qd: np.ndarray):
        """ṅ and J̇ q̇ (= c̈ when q̈ = 0) for contact-point velocity q̇, by the chain rule on
        n = m/|m| (m is affine in q, so m̈ = 0 when q̈ = 0)."""
        m, mx, my, s = geo
        md = mx * qd[0] + my * qd[1]
        sd = (m @ md) / s                            # ṡ
        sdd = (md @ md) / s - (m @ md) ** 2 / s**3   # s̈
        nd = md / s - m * sd / s**2
        ndd = -2.0 * md * sd / s**2 - m * sdd / s**2 + 2.0 * m * sd**2 / s**3
        odd = np.array([0.0, 0.0, 2.0 * qd[0] ** 2 / self.a - 2.0 * qd[1] ** 2 / self.b])
        return nd, odd + self.R * ndd

    def g_eff(self, t: float, c: np.ndarray, cd: np.ndarray) -> np.ndarray:
        """Gravity, Euler, Coriolis and centrifugal accelerations (+ the lab force)."""
        Om, Omd = self.Omega(t)
        k = K_HAT
        out = (-self.g * k - Omd * np.cross(k, c) - 2.0 * Om * np.cross(k, cd)
               - Om * Om * np.cross(k, np.cross(k, c)))
        if self.force.any():
            th = self.angle(t)
            rot = np.array([[np.cos(th), np.sin(th), 0.0], [-np.sin(th), np.cos(th), 0.0],
                            [0.0, 0.0, 1.0]])
            out = out + rot @ self.force
        return out

    # -- right-hand side --------------------------------------------------------------
    def contact_velocity(self, y: np.ndarray) -> np.ndarray:
        """The contact point's velocity (ẋ, ẏ) from the state ``y``."""
        if not self.rolling:
            return np.asarray(y[2:4], dtype=float)
        n, c, J, _ = self.frame(y[:2])
        cd = self.R * np.cross(y[2:5], n)
        return np.linalg.solve(J.T @ J, J.T @ cd)

    def derivatives(self, t: float, y: np.ndarray) -> tuple[np.ndarray, float]:
        """(dy/dt, N/m) at time t."""
        y = np.asarray(y, dtype=float)
        q = y[:2]
        if self.rolling:
            w = y[2:5]
            n, c, J, geo = self.frame(q)
            cd = self.R * np.cross(w, n)
            qd = np.linalg.solve(J.T @ J, J.T @ cd)
            nd, _ = self.rates(geo, qd)
            ge = self.g_eff(t, c, cd)
            Om, Omd = self.Omega(t)
            I, R = self.alpha * self.R**2, self.R
            M = (I + R * R) * np.eye(3) - R * R * np.outer(n, n)
            rhs = (-I * (Omd * K_HAT + Om * np.cross(K_HAT, w)) - R * R * np.cross(n, np.cross(w, nd))
                   + R * np.cross(n, ge))
            wd = np.linalg.solve(M, rhs) - self.drill * (n @ w) * n
            cdd = R * np.cross(wd, n) + R * np.cross(w, nd)
            N = n @ (cdd - ge)
            return np.concatenate([qd, wd]), float(N)
        qd = y[2:4]
        n, c, J, geo = self.frame(q)
        nd, Jdqd = self.rates(geo, qd)
        ge = self.g_eff(t, c, J @ qd)
        qdd = np.linalg.solve(J.T @ J, J.T @ (ge - Jdqd))
        N = n @ (J @ qdd + Jdqd - ge)
        return np.concatenate([qd, qdd]), float(N)

    def fun(self) -> Callable[[float, np.ndarray], np.ndarray]:
        """``f(t, y)`` for ``scipy.integrate.solve_ivp``."""
        def f(t: float, y: np.ndarray) -> np.ndarray:
            return self.derivatives(t, y)[0]
        return f

    def centre(self, Y: np.ndarray) -> np.ndarray:
        """Ball centre (n, 3) for states (n, d)."""
        return np.array([self.frame(row[:2])[1] for row in np.atleast_2d(Y)])
