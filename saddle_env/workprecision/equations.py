"""The ball's equations of motion as plain arithmetic on scalars: one source for the
benchmark's compiled peers and for a JAX path.

`saddle_env.kernels` holds the simulator's own equations, written for numba alone
(``math.sqrt``, in-place writes, every force the scenes have). The peers of ``saddle-bench``
(`saddle_env.workprecision.peers`) need the same equations in forms numba *and* JAX can
compile: a function that touches no module but the square root it is handed does that.
`rolling_rates` and `slipping_rates` build such a function around a ``sqrt``: called with
``math.sqrt`` it is a lean Python right-hand side (and ``numba.njit`` / ``numba.cfunc``
compile it as it stands); with ``jax.numpy.sqrt`` it traces under ``jax.jit`` and
``jax.vmap``. `jax_rhs` is that JAX right-hand side; tests/test_peers.py checks both
against `saddle_env.kernels.rhs`.

The model is the benchmark's: the rolling ball or the frictionless slipping ball (the
point mass is slipping with R = 0) on the saddle z = x²/a − y²/b turning at Ω(t), in the
saddle's rotating frame, per unit mass (docs/physics.md). No drag, drilling friction,
rolling resistance or external force: those scenes are the simulator's alone.

State: rolling ``(x, y, wx, wy, wz)`` — the contact point [m] and the spin relative to the
saddle [rad/s]; slipping ``(x, y, vx, vy)`` — the contact point and its velocity [m/s].
Notation as in `saddle_env.kernels`: m = (−2x/a, 2y/b, 1), s = |m|, n = m/s, the centre
c = o + R n and the columns J1, J2 of J = dc/dq.
"""

from __future__ import annotations

import math
from collections.abc import Callable

Sqrt = Callable[[float], float]


def rolling_rates(sqrt: Sqrt = math.sqrt) -> Callable[..., tuple]:
    """``rates(a, b, R, alpha, g, Om, Omd, x, y, wx, wy, wz) -> (ẋ, ẏ, ẇx, ẇy, ẇz)`` for a
    ball rolling without slipping; Ω = ``Om`` [rad/s] and Ω̇ = ``Omd`` [rad/s²] at the time."""

    def rates(a, b, R, alpha, g, Om, Omd, x, y, wx, wy, wz):
        ia, ib = 1.0 / a, 1.0 / b
        fx, fy = 2.0 * x * ia, -2.0 * y * ib          # the surface's slopes
        nz = 1.0 / sqrt(1.0 + fx * fx + fy * fy)
        nx, ny = -fx * nz, -fy * nz
        cx, cy = x + R * nx, y + R * ny
        # J = dc/dq: dn/dq_i = (1 − n nᵀ)(dm/dq_i)/s, with dm/dx = (−2/a, 0, 0), dm/dy = (0, 2/b, 0).
        k1, k2 = -2.0 * R * ia * nz, 2.0 * R * ib * nz
        J1x, J1y, J1z = 1.0 + k1 * (1.0 - nx * nx), -k1 * nx * ny, fx - k1 * nx * nz
        J2x, J2y, J2z = -k2 * nx * ny, 1.0 + k2 * (1.0 - ny * ny), fy - k2 * ny * nz
        # Rolling: ċ = R w × n, and the contact point's velocity is J's least-squares inverse of it.
        cdx, cdy, cdz = R * (wy * nz - wz * ny), R * (wz * nx - wx * nz), R * (wx * ny - wy * nx)
        g11 = J1x * J1x + J1y * J1y + J1z * J1z
        g12 = J1x * J2x + J1y * J2y + J1z * J2z
        g22 = J2x * J2x + J2y * J2y + J2z * J2z
        b1 = J1x * cdx + J1y * cdy + J1z * cdz
        b2 = J2x * cdx + J2y * cdy + J2z * cdz
        idet = 1.0 / (g11 * g22 - g12 * g12)
        vx, vy = (g22 * b1 - g12 * b2) * idet, (g11 * b2 - g12 * b1) * idet
        # ṅ = (1 − n nᵀ) ṁ / s, ṁ = (−2vx/a, 2vy/b, 0).
        mdx, mdy = -2.0 * vx * ia, 2.0 * vy * ib
        nm = nx * mdx + ny * mdy
        ndx, ndy, ndz = (mdx - nx * nm) * nz, (mdy - ny * nm) * nz, -nz * nm * nz
        # Gravity, Euler, Coriolis and centrifugal accelerations in the rotating frame.
        Om2 = Om * Om
        gx = Omd * cy + 2.0 * Om * cdy + Om2 * cx
        gy = -Omd * cx - 2.0 * Om * cdx + Om2 * cy
        gz = -g
        # Euler's equation with the contact force eliminated,
        # [(1+α) 1 − n nᵀ] ẇ = −α(Ω̇ k + Ω k×w) + (n·w) ṅ + n×g_eff/R,
        # whose matrix has the inverse (1 + n nᵀ/α)/(1+α); n·(right side)/α keeps only the
        # frame terms.
        iR = 1.0 / R
        nw = nx * wx + ny * wy + nz * wz
        rx = alpha * Om * wy + nw * ndx + (ny * gz - nz * gy) * iR
        ry = -alpha * Om * wx + nw * ndy + (nz * gx - nx * gz) * iR
        rz = -alpha * Omd + nw * ndz + (nx * gy - ny * gx) * iR
        nr = -(Omd * nz + Om * (ny * wx - nx * wy))
        inv = 1.0 / (1.0 + alpha)
        return vx, vy, (rx + nr * nx) * inv, (ry + nr * ny) * inv, (rz + nr * nz) * inv

    return rates


def slipping_rates(sqrt: Sqrt = math.sqrt) -> Callable[..., tuple]:
    """``rates(a, b, R, g, Om, Omd, x, y, vx, vy) -> (ẋ, ẏ, v̇x, v̇y)`` for a ball sliding
    without friction (its centre a particle on the offset surface; R = 0: the point)."""

    def rates(a, b, R, g, Om, Omd, x, y, vx, vy):
        ia, ib = 1.0 / a, 1.0 / b
        fx, fy = 2.0 * x * ia, -2.0 * y * ib
        nz = 1.0 / sqrt(1.0 + fx * fx + fy * fy)
        nx, ny = -fx * nz, -fy * nz
        cx, cy = x + R * nx, y + R * ny
        k1, k2 = -2.0 * R * ia * nz, 2.0 * R * ib * nz
        J1x, J1y, J1z = 1.0 + k1 * (1.0 - nx * nx), -k1 * nx * ny, fx - k1 * nx * nz
        J2x, J2y, J2z = -k2 * nx * ny, 1.0 + k2 * (1.0 - ny * ny), fy - k2 * ny * nz
        cdx, cdy = J1x * vx + J2x * vy, J1y * vx + J2y * vy
        mdx, mdy = -2.0 * vx * ia, 2.0 * vy * ib
        nm = nx * mdx + ny * mdy
        ndx, ndy, ndz = (mdx - nx * nm) * nz, (mdy - ny * nm) * nz, -nz * nm * nz
        # κ = J̇ q̇, the centre's acceleration when q̈ = 0 (m is affine in q, so m̈ = 0 there).
        ndm = ndx * mdx + ndy * mdy
        kR = R * nz
        kx = -kR * (2.0 * nm * ndx + ndm * nx)
        ky = -kR * (2.0 * nm * ndy + ndm * ny)
        kz = 2.0 * (vx * vx * ia - vy * vy * ib) - kR * (2.0 * nm * ndz + ndm * nz)
        Om2 = Om * Om
        rx = Omd * cy + 2.0 * Om * cdy + Om2 * cx - kx
        ry = -Omd * cx - 2.0 * Om * cdx + Om2 * cy - ky
        rz = -g - kz
        # q̈ = (JᵀJ)⁻¹ Jᵀ (g_eff − κ): the normal force takes the rest.
        g11 = J1x * J1x + J1y * J1y + J1z * J1z
        g12 = J1x * J2x + J1y * J2y + J1z * J2z
        g22 = J2x * J2x + J2y * J2y + J2z * J2z
        b1 = J1x * rx + J1y * ry + J1z * rz
        b2 = J2x * rx + J2y * ry + J2z * rz
        idet = 1.0 / (g11 * g22 - g12 * g12)
        return vx, vy, (g22 * b1 - g12 * b2) * idet, (g11 * b2 - g12 * b1) * idet

    return rates


def jax_rhs(rolling: bool):
    """The JAX right-hand side ``f(t, y, args)`` (diffrax's signature) of the rolling or
    slipping ball, with ``args = (a, b, R, alpha, g, w0)`` (Ω = w0 constant; alpha is unused
    when slipping). Traceable: ``jax.jit`` and ``jax.vmap`` take it as it is. Call
    ``jax.config.update("jax_enable_x64", True)`` first for float64."""
    import jax.numpy as jnp

    if rolling:
        rates = rolling_rates(jnp.sqrt)

        def f(t, y, args):
            a, b, R, alpha, g, w0 = args
            return jnp.stack(rates(a, b, R, alpha, g, w0, 0.0, y[0], y[1], y[2], y[3], y[4]))
    else:
        srates = slipping_rates(jnp.sqrt)

        def f(t, y, args):
            a, b, R, alpha, g, w0 = args
            return jnp.stack(srates(a, b, R, g, w0, 0.0, y[0], y[1], y[2], y[3]))
    return f
