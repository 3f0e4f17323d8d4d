"""The paper's approximate equation of motion (its Eq. EOM), as a comparison tool only.

This module is **not** the product dynamics (those are `saddle_env.kernels`, the exact
Newton–Euler model). It exists so that `saddle-reproduce` can say how much the seed paper's
own nonlinear equation differs from the exact one.

The paper writes the torque balance about the moving contact point O,

    M_o = dL_o/dt + ṙ_o × m ṙ_c,            L_o = m R n × ṙ_c + I ω,

and then drops ṙ_o × m ṙ_c, arguing that O and C always move in parallel. On a saddle they
do not: ṙ_c = ṙ_o + R ṅ and ṅ is not parallel to ṙ_o because the two principal curvatures
differ. With the term dropped (per unit mass, rotating frame, constant Ω):

    d/dt (R n × ċ + α R² w) = R n × g_eff + α R² w × Ω k                     (paper Eq. EOM)

with g_eff = −g k − 2Ω k×ċ − Ω² k×(k×c), w the spin relative to the saddle and the
rolling constraint ċ = R w × n. Expanding c̈ = R ẇ×n + R w×ṅ gives a 3×3 system

    R² [(1+α) 1 − n nᵀ] ẇ = R n×g_eff + α R² w×Ωk − R² n×(w×ṅ) − R ṅ×ċ − keep·(ṙ_o×ċ).

With ``keep_transport=True`` the dropped term is restored and the system is the exact
model (the tests check this against the compiled kernels, which are derived differently,
from Newton's law for the centre and Euler's equation about it). Since ṙ_o × ċ =
−R ṅ × ċ = R² (ṅ·w) n, the paper's form adds exactly ẇ_extra = (ṅ·w) n / α: a spurious
torque about the contact normal, second order in the amplitude, which spins the ball about
n and feeds back into the orbit through the −(n·w) ṅ coupling of rolling.

For a frictionless slipping ball the paper's equation has no such content: its tangential
part is Newton's law for the centre and its normal part would require ṅ × ċ = 0, which is
false; the variant is therefore implemented for rolling balls only.

Everything here is plain numpy, vectorised over a leading batch axis, and integrated with
`scipy.integrate.solve_ivp` (DOP853). A right-hand side costs about the same whether for one
ball or a few hundred stacked ones, so this serves single comparison runs (`simulate_paper`)
and small stacked sweeps (`feasible_paper`), not the product's sweeps.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..scene import Scene


# Vectors are triples of arrays (components), so that a batch of balls is vectorised and a
# single ball does not pay numpy's per-call overhead of stacking and np.cross.
def _cross(u, v):
    return (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])


def _dot(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _axpy(k, u, v):
    """k·u + v."""
    return (k * u[0] + v[0], k * u[1] + v[1], k * u[2] + v[2])


def _scale(k, u):
    return (k * u[0], k * u[1], k * u[2])


def _kinematics(scene: Scene, y: np.ndarray) -> dict:
    """Geometry and velocities of rolling states ``y`` (..., 5) = (x, y, wx, wy, wz).

    Derived here from the surface z = x²/a − y²/b independently of the compiled kernels.
    """
    assert scene.b is not None  # Scene.__post_init__ sets b (None means b = a)
    a, b, R = scene.a, scene.b, scene.radius
    x, yy = y[..., 0], y[..., 1]
    w = (y[..., 2], y[..., 3], y[..., 4])
    zero = np.zeros_like(x)
    m = (-2 * x / a, 2 * yy / b, zero + 1.0)                      # un-normalised normal
    s = np.sqrt(_dot(m, m))
    n = _scale(1 / s, m)
    o = (x, yy, x * x / a - yy * yy / b)
    c = _axpy(R, n, o)
    # Columns of J = dc/dq: do/dq_i + R P (dm/dq_i) / s, with P = 1 − n nᵀ and
    # dm/dx = (−2/a, 0, 0), dm/dy = (0, 2/b, 0).
    J1 = (1 + R * (-2 / a) * (1 - n[0] * n[0]) / s, R * (2 / a) * n[1] * n[0] / s,
          2 * x / a + R * (2 / a) * n[2] * n[0] / s)
    J2 = (-R * (2 / b) * n[0] * n[1] / s, 1 + R * (2 / b) * (1 - n[1] * n[1]) / s,
          -2 * yy / b - R * (2 / b) * n[2] * n[1] / s)
    cdot = _scale(R, _cross(w, n))                                # rolling constraint
    # Contact velocity: J q̇ = ċ (ċ is tangent, so the least-squares solve is exact).
    g11, g12, g22 = _dot(J1, J1), _dot(J1, J2), _dot(J2, J2)
    b1, b2 = _dot(J1, cdot), _dot(J2, cdot)
    det = g11 * g22 - g12 * g12
    vx, vy = (g22 * b1 - g12 * b2) / det, (g11 * b2 - g12 * b1) / det
    odot = (vx, vy, 2 * x * vx / a - 2 * yy * vy / b)
    mdot = (-2 * vx / a, 2 * vy / b, zero)
    nm = _dot(n, mdot)
    ndot = ((mdot[0] - n[0] * nm) / s, (mdot[1] - n[1] * nm) / s, (mdot[2] - n[2] * nm) / s)
    return {"n": n, "c": c, "w": w, "cdot": cdot, "qd": (vx, vy), "odot": odot,
            "ndot": ndot}


def _g_eff(scene: Scene, omega: float, c, cdot):
    """−g k − 2Ω k×ċ − Ω² k×(k×c) (constant Ω)."""
    w2 = omega * omega
    return (2 * omega * cdot[1] + w2 * c[0], -2 * omega * cdot[0] + w2 * c[1],
            -scene.g + 0 * c[2])


def spin_rate(scene: Scene, omega: float, y: np.ndarray, keep_transport: bool = False):
    """ẇ from the torque balance about the contact point (a triple of arrays of shape ...).

    Parameters
    ----------
    scene : Scene
        A rolling ball.
    omega : float
        Constant saddle speed Ω [rad/s] (the paper's equation assumes it).
    y : (..., 5)
        States (x, y, wx, wy, wz) as in `saddle_env.initial_state`.
    keep_transport : bool
        Restore the term ṙ_o × ṙ_c the paper drops (→ exact model).

    Returns
    -------
    wdot : triple of arrays; kin : dict of the kinematic quantities (triples).
    """
    R, al = scene.radius, scene.alpha
    kin = _kinematics(scene, y)
    n, w, cdot, ndot = kin["n"], kin["w"], kin["cdot"], kin["ndot"]
    geff = _g_eff(scene, omega, kin["c"], cdot)
    ngx = _cross(n, geff)
    wxk = (w[1], -w[0], 0 * w[2])                                 # w × k
    nwn = _cross(n, _cross(w, ndot))
    ndc = _cross(ndot, cdot)
    r = tuple(ngx[i] / R + al * omega * wxk[i] - nwn[i] - ndc[i] / R for i in range(3))
    if keep_transport:
        oc = _cross(kin["odot"], cdot)
        r = tuple(r[i] - oc[i] / (R * R) for i in range(3))
    # [(1+α) 1 − n nᵀ]⁻¹ = (1 + n nᵀ/α)/(1+α) (Sherman–Morrison).
    nr = _dot(n, r) / al
    wdot = tuple((r[i] + nr * n[i]) / (1 + al) for i in range(3))
    kin["geff"] = geff
    return wdot, kin


def rhs(scene: Scene, omega: float, y: np.ndarray, keep_transport: bool = False) -> np.ndarray:
    """dy/dt of rolling states ``y`` (..., 5) under the paper's Eq. EOM (or the exact
    model with ``keep_transport=True``)."""
    _check(scene, omega)
    wdot, kin = spin_rate(scene, omega, np.asarray(y, dtype=float), keep_transport)
    return np.stack([kin["qd"][0], kin["qd"][1], wdot[0], wdot[1], wdot[2]], axis=-1)


def normal_force(scene: Scene, omega: float, y: np.ndarray, keep_transport: bool = False
                 ) -> np.ndarray:
    """N/(m g) for states ``y`` (..., 5): N/m = n·(c̈ − g_eff), c̈ = R ẇ×n + R w×ṅ."""
    _check(scene, omega)
    wdot, kin = spin_rate(scene, omega, np.asarray(y, dtype=float), keep_transport)
    R, n = scene.radius, kin["n"]
    a1, a2 = _cross(wdot, n), _cross(kin["w"], kin["ndot"])
    cdd_minus_g = tuple(R * (a1[i] + a2[i]) - kin["geff"][i] for i in range(3))
    return _dot(n, cdd_minus_g) / scene.g


def jacobi(scene: Scene, omega: float, y: np.ndarray) -> np.ndarray:
    """Jacobi integral per unit mass [J/kg], conserved by the exact model (not by the paper's)."""
    kin = _kinematics(scene, np.asarray(y, dtype=float))
    c, cd, w = kin["c"], kin["cdot"], kin["w"]
    return (0.5 * _dot(cd, cd) + 0.5 * scene.alpha * scene.radius ** 2 * _dot(w, w)
            - 0.5 * omega ** 2 * (c[0] ** 2 + c[1] ** 2) + scene.g * c[2])


def _check(scene: Scene, omega: float) -> None:
    if not isinstance(scene, Scene) or not scene.rolling:
        raise ValueError("the paper's Eq. EOM variant is implemented for rolling balls only "
                         "(for slipping balls its tangential part is Newton's law)")
    if not np.isfinite(omega):
        raise ValueError(f"omega must be finite, got {omega}")


@dataclass
class PaperRun:
    """A run of the paper's equation: output times, states, N/(mg), Jacobi integral and the
    first time N < 0 (None if it stayed positive)."""

    t: np.ndarray
    state: np.ndarray
    N_over_mg: np.ndarray
    h: np.ndarray
    t_detach: float | None


def simulate_paper(scene: Scene, state: np.ndarray, t_end: float, omega: float,
                   dt_out: float = 0.001, keep_transport: bool = False, rtol: float = 1e-10,
                   stop_at_detach: bool = False) -> PaperRun:
    """Integrate the paper's Eq. EOM (DOP853, solve_ivp) and locate the first N < 0.

    Parameters
    ----------
    scene : Scene
        Rolling ball; the run stops when the contact point leaves its rim.
    state : (5,)
        From `saddle_env.initial_state`.
    t_end : float
        Duration [s].
    omega : float
        Constant Ω [rad/s].
    dt_out : float
        Output spacing [s].
    keep_transport : bool
        Restore the dropped term (the exact model, for checking).
    rtol : float
        Relative tolerance; absolute tolerances scale with the state's size as in
        `saddle_env.integrators.state_scale`.
    stop_at_detach : bool
        Stop at the first N = 0 crossing (else run on, as the paper's
        figure does, showing the forbidden negative force).
    """
    from scipy.integrate import solve_ivp

    _check(scene, omega)
    y0 = np.asarray(state, dtype=float)
    if y0.shape != (5,):
        raise ValueError(f"state must have 5 components (rolling), got shape {y0.shape}")
    t_eval = np.arange(int(np.floor(t_end / dt_out + 1e-9)) + 1) * dt_out

    def f(_t: float, y: np.ndarray) -> np.ndarray:
        return rhs(scene, omega, y, keep_transport)

    def detach(_t: float, y: np.ndarray) -> float:
        return float(normal_force(scene, omega, y, keep_transport))

    def escape(_t: float, y: np.ndarray) -> float:
        return scene.rim_radius ** 2 - (y[0] ** 2 + y[1] ** 2)

    detach.direction = -1  # type: ignore[attr-defined]
    detach.terminal = stop_at_detach  # type: ignore[attr-defined]
    escape.terminal = True  # type: ignore[attr-defined]
    sol = solve_ivp(f, (0.0, t_eval[-1]), y0, method="DOP853", t_eval=t_eval, rtol=rtol,
                    atol=rtol * _state_scale(scene), events=(detach, escape),
                    max_step=np.pi / (8 * abs(omega)))
    Y = sol.y.T
    t_det = float(sol.t_events[0][0]) if len(sol.t_events[0]) else None
    if detach(0.0, y0) < 0:
        t_det = 0.0
    return PaperRun(sol.t, Y, normal_force(scene, omega, Y, keep_transport),
                    jacobi(scene, omega, Y), t_det)


def _state_scale(scene: Scene) -> np.ndarray:
    """Characteristic size of (x, y, wx, wy, wz): a, b and a·sqrt(2g/a)/R."""
    v = scene.a * np.sqrt(2 * scene.g / scene.a) / scene.radius
    return np.array([scene.a, scene.b, v, v, v])


def feasible_paper(scene: Scene, states: np.ndarray, omega: float, t_end: float,
                   keep_transport: bool = False, segment: float = 0.02, sample: float = 5e-4,
                   rtol: float = 1e-10, progress: Callable[[float], object] | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Which starting states never lose contact (N > 0) nor leave the rim within ``t_end``.

    All balls are stacked into one ODE system and integrated in segments of ``segment``
    seconds; after each segment N and r are checked on the dense output every ``sample``
    seconds and the balls that detached or escaped are dropped, so a ball flying off after
    detaching no longer dictates the step size of the others.

    Returns
    -------
    ok : (n,) bool
        Stayed in contact and on the saddle.
    t_lost : (n,) float
        First sampled time of N < 0 or r > rim (inf if ok).
    """
    from scipy.integrate import solve_ivp

    _check(scene, omega)
    y = np.array(states, dtype=float)
    n = len(y)
    alive = np.ones(n, dtype=bool)
    t_lost = np.full(n, np.inf)
    scale = _state_scale(scene)
    t0 = 0.0
    while t0 < t_end - 1e-12 and alive.any():
        t1 = min(t0 + segment, t_end)
        idx = np.flatnonzero(alive)
        m = len(idx)

        def f(_t: float, z: np.ndarray, m: int = m) -> np.ndarray:
            return rhs(scene, omega, z.reshape(m, 5), keep_transport).ravel()

        sol = solve_ivp(f, (t0, t1), y[idx].ravel(), method="DOP853", rtol=rtol,
                        atol=rtol * np.tile(scale, m), dense_output=True,
                        max_step=np.pi / (8 * abs(omega)))
        tt = np.linspace(t0, t1, max(2, int(np.rint((t1 - t0) / sample)) + 1))
        Z = sol.sol(tt).T.reshape(len(tt), m, 5)
        bad = (normal_force(scene, omega, Z, keep_transport) < 0) | \
              (np.hypot(Z[..., 0], Z[..., 1]) > scene.rim_radius)
        gone = bad.any(axis=0)
        t_lost[idx[gone]] = tt[np.argmax(bad, axis=0)[gone]]
        alive[idx[gone]] = False
        y[idx] = Z[-1]
        t0 = t1
        if progress is not None:
            progress(t1 / t_end)
    return alive, t_lost
