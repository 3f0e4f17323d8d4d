"""Linear theory about the saddle point (the paper's §III–IV, Table I).

Near the centre the ball's centre obeys (paper Eq. LinearizedEOM)

    ẍ_c = A x_c + B ẏ_c,      ÿ_c = C y_c + D ẋ_c,

with A, B, C, D from Table I. For the asymmetric saddle z = x²/a − y²/b the same
derivation gives Table I with (a − 2R) in A and D (the x direction) and (b + 2R) in B and C
(the y direction); the tests check every coefficient, for a ≠ b and ω_z ≠ 0, against a
finite-difference linearisation of the exact model. Eigen-frequencies ϖ (x ∝ e^{iϖt})
solve ϖ⁴ + (A + C + BD) ϖ² + AC = 0; the motion is (marginally) stable iff both roots
ϖ² are real and positive.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .scene import Scene, finite_number

# Beyond this the coefficients (∝ Ω²) leave floating point range in the quartic.
MAX_RATE = 1e12


def _check_scene(scene: object) -> None:
    if not isinstance(scene, Scene):
        raise ValueError(f"scene must be a saddle_env.Scene, got {type(scene).__name__}")


@dataclass(frozen=True)
class ABCD:
    """The coefficients of the linearised equations of motion (the paper's Table I; `abcd`)."""

    A: float
    B: float
    C: float
    D: float

    def matrix(self) -> np.ndarray:
        """First-order system matrix for the state (x_c, y_c, ẋ_c, ẏ_c)."""
        return np.array([[0.0, 0.0, 1.0, 0.0],
                         [0.0, 0.0, 0.0, 1.0],
                         [self.A, 0.0, 0.0, self.B],
                         [0.0, self.C, self.D, 0.0]])


def abcd(scene: Scene, omega: float, spin_z: float = 0.0) -> ABCD:
    """Table I coefficients at saddle speed ``omega`` [rad/s].

    Slipping and point use Table I's right column with R = scene.radius (0 for the point).

    Parameters
    ----------
    scene : Scene
        The saddle and the ball.
    omega : float
        The saddle's speed [rad/s].
    spin_z : float
        The ball's spin about the vertical relative to the saddle [rad/s] (the paper's
        ω_z); it enters only for a rolling ball.

    Returns
    -------
    ABCD
        The coefficients.
    """
    _check_scene(scene)
    W = finite_number("omega", omega)
    wz = finite_number("spin_z", spin_z)
    if abs(W) > MAX_RATE or abs(wz) > MAX_RATE:
        raise ValueError(f"omega and spin_z must lie within ±{MAX_RATE:g} rad/s, got {W:g}, {wz:g}")
    assert scene.b is not None  # Scene.__post_init__ sets b (None means b = a)
    a, b, R, g, al = scene.a, scene.b, scene.radius, scene.g, scene.alpha
    am, bp = a - 2.0 * R, b + 2.0 * R
    if scene.rolling:
        k = 1.0 + al
        return ABCD(A=(am * W * W + 2 * al * R * wz * W - 2 * g) / (k * am),
                    B=((2 + al) * bp * W - 2 * al * R * wz) / (k * bp),
                    C=(bp * W * W - 2 * al * R * wz * W + 2 * g) / (k * bp),
                    D=(-(2 + al) * am * W - 2 * al * R * wz) / (k * am))
    return ABCD(A=W * W - 2 * g / am, B=2 * W, C=W * W + 2 * g / bp, D=-2 * W)


def system_matrix(scene: Scene, omega: float, spin_z: float = 0.0) -> np.ndarray:
    """First-order matrix of the linearised motion for (x_c, y_c, ẋ_c, ẏ_c), with the scene's
    linear air drag (quadratic drag has no linear part).

    The drag per unit mass, -k (ċ + Ω k×c) with the air still in the laboratory, adds
    -μk (ẋ_c - Ω y_c) to ẍ_c and -μk (ẏ_c + Ω x_c) to ÿ_c, where μ = 1 for a slipping ball
    and 1/(1 + α) for a rolling one (the contact force makes the ball's spin take its share).
    Without drag this is ``abcd(...).matrix()``.

    Parameters
    ----------
    scene : Scene
        The saddle and the ball.
    omega : float
        The saddle's speed [rad/s].
    spin_z : float
        The ball's spin about the vertical relative to the saddle [rad/s] (`abcd`).

    Returns
    -------
    numpy.ndarray
        The 4 × 4 matrix.
    """
    M = abcd(scene, omega, spin_z).matrix()
    k = scene.drag_linear / (1.0 + scene.alpha) if scene.rolling else scene.drag_linear
    W = float(omega)
    M[2, 1] += k * W
    M[2, 2] -= k
    M[3, 0] -= k * W
    M[3, 3] -= k
    return M


def growth_rate(scene: Scene, omega: float, spin_z: float = 0.0) -> float:
    """Largest real part [1/s] of the eigenvalues of `system_matrix`.

    Zero (to round-off) where the drag-free motion is marginally stable; with drag, its
    sign tells whether the air damps the orbit or, dissipation-induced instability, drives
    it out.

    Parameters
    ----------
    scene : Scene
        The saddle and the ball.
    omega : float
        The saddle's speed [rad/s].
    spin_z : float
        The ball's spin about the vertical relative to the saddle [rad/s] (`abcd`).

    Returns
    -------
    float
        The rate [1/s]; > 0 means the orbit grows as e^{rate·t}.
    """
    return float(np.max(np.linalg.eigvals(system_matrix(scene, omega, spin_z)).real))


def _biquadratic(c: ABCD) -> tuple[float, float]:
    """(P, Q) of ϖ⁴ + P ϖ² + Q = 0."""
    return c.A + c.C + c.B * c.D, c.A * c.C


def eigenfrequencies(scene: Scene, omega: float, spin_z: float = 0.0) -> np.ndarray:
    """The four complex eigen-frequencies ϖ [rad/s] (x ∝ e^{iϖt}), sorted by real part.

    A negative imaginary part means growth, e^{|Im ϖ| t}: the paper's instability.

    Parameters
    ----------
    scene : Scene
        The saddle and the ball.
    omega : float
        The saddle's speed [rad/s].
    spin_z : float
        The ball's spin about the vertical relative to the saddle [rad/s] (`abcd`).

    Returns
    -------
    numpy.ndarray
        Four complex frequencies [rad/s].
    """
    return eigenfrequencies_of(abcd(scene, omega, spin_z))


def eigenfrequencies_of(c: ABCD) -> np.ndarray:
    """The four ϖ of ẍ = A x + B ẏ, ÿ = C y + D ẋ (any source of A, B, C, D, e.g. an ion
    trap in saddle_env.iontrap), sorted by real part."""
    P, Q = _biquadratic(c)
    disc = np.sqrt(complex(P * P - 4 * Q))
    roots = []
    for w2 in ((-P + disc) / 2, (-P - disc) / 2):
        r = np.sqrt(complex(w2))
        roots += [r, -r]
    return np.array(sorted(roots, key=lambda z: (z.real, z.imag)))


def is_stable(scene: Scene, omega: float, spin_z: float = 0.0) -> bool:
    """Linear (marginal) stability: both roots ϖ² real and positive (paper Eq. Inequalities).

    Parameters
    ----------
    scene : Scene
        The saddle and the ball.
    omega : float
        The saddle's speed [rad/s].
    spin_z : float
        The ball's spin about the vertical relative to the saddle [rad/s] (`abcd`).

    Returns
    -------
    bool
        Whether the linearised motion is (marginally) stable.
    """
    return is_stable_abcd(abcd(scene, omega, spin_z))


def is_stable_abcd(c: ABCD) -> bool:
    """`is_stable` for any coefficients A, B, C, D."""
    P, Q = _biquadratic(c)
    return Q > 0 and P < 0 and P * P - 4 * Q >= 0


def critical_omega(scene: Scene) -> float:
    """Lowest stabilising speed Ω_crt [rad/s] (ω_z = 0).

    Symmetric saddle: sqrt(2g/(a − 2R)) for a rigid ball (rolling or slipping), sqrt(2g/a)
    for the mass point (paper Eqs. RigidBodyThreshold, MassPointThreshold). Asymmetric
    saddle: the lower edge of `stable_band`.

    Parameters
    ----------
    scene : Scene
        The saddle and the ball.

    Returns
    -------
    float
        Ω_crt [rad/s]; ``nan`` if no speed stabilises the ball.
    """
    _check_scene(scene)
    if scene.a == scene.b:
        return math.sqrt(2 * scene.g / (scene.a - 2 * scene.radius))
    band = stable_band(scene)
    return band[0][0] if band else math.nan


def mass_point_band(a: float, b: float, g: float = 9.8) -> tuple[float, float] | None:
    """Closed-form stable band (Ω_low, Ω_high) of the mass point, or None if there is none.

    Stable iff Q = AC > 0 (Ω² > 2g/a), the discriminant P² − 4Q ≥ 0 (when b < a:
    Ω² ≤ g(a + b)²/(4ab(a − b))) and P = A + C + BD < 0 (Ω² > g(a − b)/(ab)). The last
    condition holds across the band iff a < 3b; for a ≥ 3b both roots ϖ² are negative there
    and no speed stabilises the point.

    Parameters
    ----------
    a, b : float
        The saddle's lengths [m] (z = x²/a − y²/b).
    g : float
        Gravitational acceleration [m/s²].

    Returns
    -------
    (float, float) or None
        The band [rad/s]; Ω_high = inf when b ≥ a.
    """
    a, b, g = (finite_number(k, v) for k, v in (("a", a), ("b", b), ("g", g)))
    if a <= 0 or b <= 0 or g < 0:
        raise ValueError(f"mass_point_band needs a > 0, b > 0, g >= 0; got a={a}, b={b}, g={g}")
    low = math.sqrt(2 * g / a)
    if b >= a:
        return low, math.inf
    if a >= 3 * b:
        return None
    return low, math.sqrt(g * (a + b) ** 2 / (4 * a * b * (a - b)))


def stable_band(scene: Scene, spin_z: float = 0.0, omega_max: float | None = None,
                n_grid: int = 4000) -> list[tuple[float, float]]:
    """Intervals of Ω in (0, omega_max] where the drag-free linearised motion is stable.

    Stability is `is_stable`'s; the scene's drag is ignored (see `damped_band`). Scans a
    grid (geometric above Ω_ref = sqrt(2g/min(a, b))) and refines every edge by bisection
    to ~1e-12 relative.

    Parameters
    ----------
    scene : Scene
        The saddle and the ball.
    spin_z : float
        The ball's spin about the vertical relative to the saddle [rad/s] (`abcd`).
    omega_max : float, optional
        The highest speed scanned [rad/s]; default 100·Ω_ref.
    n_grid : int
        Grid points of the scan.

    Returns
    -------
    list of (float, float)
        The stable intervals [rad/s]. One reaching ``omega_max`` has an upper end of ``inf``
        (no upper bound was found below omega_max; for the symmetric saddle there is none).
    """
    _check_scene(scene)
    return _bands_where(lambda w: is_stable(scene, w, spin_z), scene, omega_max, n_grid)


def damped_band(scene: Scene, spin_z: float = 0.0, omega_max: float | None = None,
                n_grid: int = 4000) -> list[tuple[float, float]]:
    """Intervals of Ω in (0, omega_max] where the linearised motion with the scene's linear
    drag does not grow (`growth_rate` ≤ 0).

    Uses the grid and edge refinement of `stable_band`. Without drag this is
    `stable_band`: there the stable modes neither grow nor decay, and a rate of zero
    computed by an eigensolver is only zero to round-off, so the exact criterion is used
    instead. With drag the rate changes sign at an edge, and the band may lose part of the
    drag-free one (dissipation-induced instability) — e.g. on an asymmetric saddle a rolling
    ball's band can become finite.

    Parameters
    ----------
    scene : Scene
        The saddle and the ball, with its linear drag.
    spin_z : float
        The ball's spin about the vertical relative to the saddle [rad/s] (`abcd`).
    omega_max : float, optional
        The highest speed scanned [rad/s], as in `stable_band`.
    n_grid : int
        Grid points of the scan.

    Returns
    -------
    list of (float, float)
        The intervals [rad/s], as in `stable_band`.
    """
    _check_scene(scene)
    if scene.drag_linear == 0.0:
        return stable_band(scene, spin_z, omega_max, n_grid)
    return _bands_where(lambda w: growth_rate(scene, w, spin_z) <= 0.0, scene, omega_max,
                        n_grid)


def _bands_where(holds: Callable[[float], bool], scene: Scene, omega_max: float | None,
                 n_grid: int) -> list[tuple[float, float]]:
    """Intervals of Ω in (0, omega_max] where ``holds(Ω)``: a grid scan, edges bisected."""
    if isinstance(n_grid, bool) or not isinstance(n_grid, (int, np.integer)) or not 10 <= n_grid <= 10**7:
        raise ValueError(f"n_grid must be an integer in [10, 1e7], got {n_grid!r}")
    assert scene.b is not None  # Scene.__post_init__ sets b (None means b = a)
    ref = math.sqrt(2 * max(scene.g, 1e-12) / min(scene.a, scene.b))
    top = 100.0 * ref if omega_max is None else finite_number("omega_max", omega_max)
    if top <= 0:
        raise ValueError(f"omega_max must be > 0, got {top}")
    grid = np.unique(np.concatenate([np.linspace(top * 1e-4, ref * 4, n_grid // 2),
                                     np.geomspace(ref * 4, top, n_grid // 2)]))
    grid = grid[grid <= top]
    stable = [holds(w) for w in grid]

    def edge(lo: float, hi: float, stable_lo: bool) -> float:
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if (hi - lo) <= 1e-13 * hi:
                break
            if holds(mid) == stable_lo:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

    bands: list[tuple[float, float]] = []
    start = grid[0] if stable[0] else None
    for i in range(1, len(grid)):
        if stable[i] != stable[i - 1]:
            e = edge(grid[i - 1], grid[i], stable[i - 1])
            if stable[i]:
                start = e
            else:
                bands.append((start, e))  # type: ignore[arg-type]
                start = None
    if start is not None:
        bands.append((start, math.inf))
    return bands


def centre_from_contact(scene: Scene, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linearised map from contact point to ball centre: x_c = (1 − 2R/a) x, y_c = (1 + 2R/b) y."""
    R = scene.radius
    assert scene.b is not None  # Scene.__post_init__ sets b (None means b = a)
    return (1 - 2 * R / scene.a) * np.asarray(x), (1 + 2 * R / scene.b) * np.asarray(y)


def linear_trajectory(scene: Scene, omega: float, centre_state: np.ndarray, t: np.ndarray,
                      spin_z: float = 0.0) -> np.ndarray:
    """Exact solution of the linearised equations, with the scene's linear air drag
    (`system_matrix`).

    The solution is advanced by the matrix exponential of one spacing of ``t``, so it
    carries no discretisation error.

    Parameters
    ----------
    scene : Scene
        The saddle and the ball.
    omega : float
        The saddle's speed [rad/s].
    centre_state : numpy.ndarray
        The start (x_c, y_c, ẋ_c, ẏ_c) of the ball's centre [m, m/s].
    t : numpy.ndarray
        Times [s], evenly spaced from 0.
    spin_z : float
        The ball's spin about the vertical relative to the saddle [rad/s] (`abcd`).

    Returns
    -------
    numpy.ndarray
        (len(t), 4) rows (x_c, y_c, ẋ_c, ẏ_c).

    Raises
    ------
    ValueError
        If ``centre_state`` is not 4 finite numbers, or ``t`` is not a finite 1-D array
        starting at 0.
    """
    from scipy.linalg import expm

    try:
        t = np.asarray(t, dtype=float)
        z0 = np.asarray(centre_state, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("centre_state and t must be real arrays") from None
    if not np.all(np.isfinite(t)):
        raise ValueError("t must be finite")
    if z0.shape != (4,) or not np.all(np.isfinite(z0)):
        raise ValueError(f"centre_state must be 4 finite numbers (x_c, y_c, vx_c, vy_c), got {z0}")
    if t.ndim != 1 or len(t) < 1 or t[0] != 0:
        raise ValueError("t must be a 1-D array starting at 0")
    out = np.empty((len(t), 4))
    out[0] = z0
    if len(t) > 1:
        step = np.diff(t)
        if not np.allclose(step, step[0], rtol=1e-9, atol=0):
            raise ValueError("t must be evenly spaced")
        E = expm(system_matrix(scene, omega, spin_z) * step[0])
        for i in range(1, len(t)):
            out[i] = E @ out[i - 1]
    return out
