"""Quadrupole ion traps beside the rotating saddle (the seed paper's last section).

Two traps for one charged particle, in the plane across the trap axis, per unit mass:

* `RRFTrap` — the rotating radio-frequency trap: the quadrupole φ ∝ (x'² − y'²) rotates at
  Ω (x', y' rotate with it), plus an axial magnetic field (cyclotron frequency ω_B) and an
  optional static term κ_t. In the frame rotating with the quadrupole the motion is the
  paper's Eq. (comp2), exactly (an ideal quadrupole is exactly quadratic):

      ẍ = A x + B ẏ,   ÿ = C y + D ẋ,   A = Ω² − Ωω_B − κ + κ_t,  B = 2Ω − ω_B,
                                        C = Ω² − Ωω_B + κ + κ_t,  D = −B.

* `PaulTrap` — the flapping quadrupole φ = φ0 + (U0 + V0 cos(Ωt + ψ))(x² − y²)/(2 r0²) in the
  laboratory; with τ = Ωt/2 each axis obeys Mathieu's equation x'' + (a + 2q cos 2τ) x = 0,
  a = 4κ_dc/Ω², q = 2κ/Ω² (y: −a, −q). `mathieu_first_region` gives its first stability
  region.

Here κ = eV0/(m r0²) and κ_dc = eU0/(m r0²) [1/s²] are the quadrupole's strengths per unit
mass, ω_B = eB/m [rad/s] (signed: positive when the free cyclotron orbit turns the same way
as the quadrupole, the paper's sign) and κ_t = k2·V_t [1/s²] (positive: pushes outward, as
the end-cap voltage of a trap that confines along the axis does). `RRFTrap.from_voltages`
and `PaulTrap.from_voltages` take SI voltages instead.

Both are integrated by the project's own stepping loop and Runge–Kutta registry
(`saddle_env.integrators`; the rates are `kernels.ion_rates`, model codes ION_RRF and
ION_PAUL), with the escape event at the electrode radius r0. `simulate_ion` is the entry.

`ball_to_ion` maps a ball on the rotating saddle to the RRF ion that obeys its linearised
equations; `paper_analogy_ion` is the paper's own term-by-term reading. docs/iontrap.md
explains which term becomes which field, where the map is exact and where it is not.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from . import kernels as K
from .integrators import EVENT_KINDS, STATUS_FAILED, STATUS_MAX_STEPS, workspace
from .linear import (
    ABCD,
    abcd,
    eigenfrequencies,
    eigenfrequencies_of,
    is_stable_abcd,
    linear_trajectory,
)
from .omega import OmegaProfile
from .runner import integrator_loop
from .scene import ION_PAUL, ION_RRF, N_PARAMS, P_RIM, Scene, finite_number
from .simulate import Settings, SimulationError, default_max_step, drive_row

# Most output samples one run may ask for (as saddle_env.simulate).
MAX_OUTPUTS = 10_000_000

# Largest rate accepted [rad/s] and field strength [1/s²] (beyond, the coefficients of the
# eigen-frequency quartic leave floating-point range; no trap comes near).
MAX_RATE = 1e9
MAX_STRENGTH = 1e18


def _rate(name: str, value: object, positive: bool = False) -> float:
    v = finite_number(name, value)
    if positive and not v > 0:
        raise ValueError(f"{name} must be > 0 rad/s, got {v:g}")
    if abs(v) > MAX_RATE:
        raise ValueError(f"{name} must lie within ±{MAX_RATE:g} rad/s, got {v:g}")
    return v


def _strength(name: str, value: object, nonnegative: bool = False) -> float:
    v = finite_number(name, value)
    if nonnegative and v < 0:
        raise ValueError(f"{name} must be >= 0 (1/s^2; a negative amplitude is the same drive "
                         f"half a period later: change phase by pi), got {v:g}")
    if abs(v) > MAX_STRENGTH:
        raise ValueError(f"{name} must lie within ±{MAX_STRENGTH:g} 1/s^2, got {v:g}")
    return v


def _radius(value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"r0 must be a real number (metres, or math.inf), got {value!r}")
    v = float(value)
    if not v > 0 or math.isnan(v):
        raise ValueError(f"r0 must be > 0 (electrode radius in metres, or math.inf), got {v}")
    return v


def _output_times(t_end: object, dt_out: object) -> np.ndarray:
    """0, dt_out, 2 dt_out, ... ≤ t_end (multiples, no drift); [0, t_end] when dt_out is None."""
    t_end = finite_number("t_end", t_end)
    if t_end <= 0:
        raise ValueError(f"t_end must be > 0 seconds, got {t_end}")
    if dt_out is None:
        return np.array([0.0, t_end])
    dt_out = finite_number("dt_out", dt_out)
    if dt_out <= 0:
        raise ValueError(f"dt_out must be > 0 seconds, got {dt_out}")
    ratio = t_end / dt_out * (1 + 1e-12)
    if not ratio < MAX_OUTPUTS:
        raise ValueError(f"dt_out = {dt_out:g} s gives {ratio:.3g} outputs over t_end = "
                         f"{t_end:g} s; at most {MAX_OUTPUTS} are allowed")
    return np.arange(int(math.floor(ratio)) + 1) * dt_out


def _voltage_factor(e_over_m: object, r0: object) -> tuple[float, float]:
    em = finite_number("e_over_m", e_over_m)
    if em == 0:
        raise ValueError("e_over_m must be non-zero (C/kg; negative for a negative charge)")
    r = finite_number("r0", r0)
    if not r > 0:
        raise ValueError(f"r0 must be > 0 (electrode radius in metres), got {r:g}")
    return em, r


# ------------------------------------------------------------------------------------------
# The traps
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RRFTrap:
    """Rotating radio-frequency trap: rotating quadrupole, axial field, static term.

    Parameters
    ----------
    omega : float
        Rotation rate Ω of the quadrupole [rad/s], > 0.
    kappa : float
        Quadrupole strength κ = eV0/(m r0²) [1/s²] (the paper's k1·V0). Its sign picks
        which rotating axis is the defocusing one (x' for κ > 0, as gravity's saddle along
        x); −κ is the same trap turned by 90°.
    omega_B : float
        Cyclotron frequency ω_B = eB/m [rad/s], signed as in the paper's Eq. (comp2):
        the Lorentz acceleration is ω_B k × v (k: the rotation axis). 0: no field.
    kappa_t : float
        Static term κ_t [1/s²] (the paper's k2·V_t): acceleration κ_t·(x, y). Positive pushes
        outward (end caps that confine along the axis); negative confines. Default 0.
    r0 : float
        Electrode radius [m]: reaching it is an escape. ``math.inf`` for none.
    """

    omega: float = 20.0
    kappa: float = 2 * 9.8 / 0.159
    omega_B: float = 0.0
    kappa_t: float = 0.0
    r0: float = math.inf

    def __post_init__(self) -> None:
        object.__setattr__(self, "omega", _rate("omega", self.omega, positive=True))
        object.__setattr__(self, "kappa", _strength("kappa", self.kappa))
        object.__setattr__(self, "omega_B", _rate("omega_B", self.omega_B))
        object.__setattr__(self, "kappa_t", _strength("kappa_t", self.kappa_t))
        object.__setattr__(self, "r0", _radius(self.r0))

    @classmethod
    def from_voltages(cls, omega: float, e_over_m: float, V0: float, r0: float,
                      B: float = 0.0, Vt: float = 0.0, d: float | None = None) -> RRFTrap:
        """From SI quantities: charge/mass e/m [C/kg], quadrupole amplitude V0 [V], electrode
        radius r0 [m], field B [T] (ω_B = (e/m)·B in the paper's sign), static end-cap
        voltage Vt [V] acting over the length d [m] (κ_t = (e/m)·Vt/d²: the potential
        Vt (2z² − x² − y²)/(2d²)). The escape radius is r0."""
        em, r = _voltage_factor(e_over_m, r0)
        V0 = finite_number("V0", V0)
        B = finite_number("B", B)
        Vt = finite_number("Vt", Vt)
        kt = 0.0
        if Vt != 0.0:
            if d is None:
                raise ValueError("d (end-cap distance in metres) is needed when Vt != 0")
            d = finite_number("d", d)
            if not d > 0:
                raise ValueError(f"d must be > 0 metres, got {d:g}")
            kt = em * Vt / d ** 2
        return cls(omega=omega, kappa=em * V0 / r ** 2, omega_B=em * B, kappa_t=kt, r0=r)

    @property
    def model_code(self) -> int:
        """The compiled kernels' code for this trap."""
        return ION_RRF

    def params(self) -> np.ndarray:
        """The packed row the compiled rates read (`kernels.ion_rates`)."""
        p = np.zeros(N_PARAMS)
        p[K.I_KQUAD], p[K.I_OMEGA_B], p[K.I_KSTATIC], p[P_RIM] = (
            self.kappa, self.omega_B, self.kappa_t, self.r0)
        return p

    def abcd(self) -> ABCD:
        """Coefficients of the paper's Eq. (comp2) (rotating frame, exact)."""
        W, wB, k, kt = self.omega, self.omega_B, self.kappa, self.kappa_t
        diag = W * W - W * wB + kt
        return ABCD(A=diag - k, B=2 * W - wB, C=diag + k, D=-(2 * W - wB))

    def eigenfrequencies(self) -> np.ndarray:
        """The four ϖ [rad/s] (x ∝ e^{iϖt} in the rotating frame), sorted by real part."""
        return eigenfrequencies_of(self.abcd())

    def is_stable(self) -> bool:
        """Both roots ϖ² real and positive (the paper's Eq. Inequalities)."""
        return is_stable_abcd(self.abcd())

    def critical_omega(self) -> float:
        """Lowest Ω above which the trap is stable at every higher Ω, for this κ, ω_B, κ_t.

        In the frame turning at Ω' = Ω − ω_B/2 (Larmor's theorem) the field becomes a
        confining term ω_B²/4; with s = ω_B²/4 − κ_t the conditions read u + s > 0,
        (u − s)² > κ² and 4us + κ² ≥ 0 for u = Ω'². For s >= 0 the top stable interval
        starts at Ω' = sqrt(s + |κ|); for s < 0 (net outward static push) the stable Ω are
        bounded above and ``nan`` is returned. Without field and static term: sqrt(κ).
        """
        s = 0.25 * self.omega_B ** 2 - self.kappa_t
        if s < 0:
            return math.nan
        return 0.5 * self.omega_B + math.sqrt(s + abs(self.kappa))


# First stability region of Mathieu's equation at a = 0: b_1(q) = 0.
def _q_max() -> float:
    from scipy.optimize import brentq
    from scipy.special import mathieu_b

    return float(brentq(lambda q: mathieu_b(1, q), 0.5, 1.2, xtol=1e-15))


Q_MAX = 0.9080463337345777  # checked against _q_max() in tests/test_iontrap.py


def mathieu_first_region(q: float) -> tuple[float, float]:
    """Bounds (a_low, a_high) of a in Mathieu's first stability region at this q.

    For x'' + (a + 2q cos 2τ) x = 0 (stable for ±q alike): a_0(|q|) < a < b_1(|q|), the
    characteristic values of ce_0 and se_1 (scipy.special.mathieu_a / mathieu_b).
    """
    from scipy.special import mathieu_a, mathieu_b

    q = abs(finite_number("q", q))
    if q > 1e3:
        raise ValueError(f"|q| must be <= 1000 (the first region has closed long before), got {q:g}")
    return float(mathieu_a(0, q)), float(mathieu_b(1, q))


@dataclass(frozen=True)
class PaulTrap:
    """Paul trap: the flapping quadrupole (U0 + V0 cos(Ωt + phase))(x² − y²)/(2 r0²).

    Parameters
    ----------
    omega : float
        Drive angular frequency Ω [rad/s], > 0.
    kappa : float
        AC strength κ = eV0/(m r0²) [1/s²], >= 0. Mathieu q = 2κ/Ω².
    kappa_dc : float
        DC strength κ_dc = eU0/(m r0²) [1/s²], signed. Mathieu a = 4κ_dc/Ω². Default 0 (the
        paper's Eq. EPotentialPaulTrap).
    phase : float
        Drive phase ψ at t = 0 [rad].
    r0 : float
        Electrode radius [m]: reaching it is an escape. ``math.inf`` for none.
    """

    omega: float = 20.0
    kappa: float = 2 * 9.8 / 0.159
    kappa_dc: float = 0.0
    phase: float = 0.0
    r0: float = math.inf

    def __post_init__(self) -> None:
        object.__setattr__(self, "omega", _rate("omega", self.omega, positive=True))
        object.__setattr__(self, "kappa", _strength("kappa", self.kappa, nonnegative=True))
        object.__setattr__(self, "kappa_dc", _strength("kappa_dc", self.kappa_dc))
        object.__setattr__(self, "phase", finite_number("phase", self.phase))
        object.__setattr__(self, "r0", _radius(self.r0))

    @classmethod
    def from_voltages(cls, omega: float, e_over_m: float, V0: float, r0: float,
                      U0: float = 0.0, phase: float = 0.0) -> PaulTrap:
        """From SI quantities: e/m [C/kg], AC amplitude V0 [V], DC voltage U0 [V], electrode
        radius r0 [m] (κ = (e/m)V0/r0², κ_dc = (e/m)U0/r0²; the escape radius is r0)."""
        em, r = _voltage_factor(e_over_m, r0)
        V0 = finite_number("V0", V0)
        U0 = finite_number("U0", U0)
        return cls(omega=omega, kappa=abs(em * V0) / r ** 2,
                   kappa_dc=em * U0 * (1.0 if em * V0 >= 0 else -1.0) / r ** 2,
                   phase=phase, r0=r)

    @property
    def model_code(self) -> int:
        """The compiled kernels' code for this trap."""
        return ION_PAUL

    def params(self) -> np.ndarray:
        """The packed parameter vector read by the compiled kernels."""
        p = np.zeros(N_PARAMS)
        p[K.I_KQUAD], p[K.I_KDC], p[P_RIM] = self.kappa, self.kappa_dc, self.r0
        return p

    def mathieu(self) -> tuple[float, float]:
        """Mathieu parameters (a, q) of the x motion (y has −a, −q), τ = (Ωt + phase)/2."""
        W2 = self.omega ** 2
        return 4.0 * self.kappa_dc / W2, 2.0 * self.kappa / W2

    def is_stable(self) -> bool:
        """Both axes inside Mathieu's first stability region (higher regions not counted)."""
        a, q = self.mathieu()
        lo, hi = mathieu_first_region(q)
        return lo < a < hi and lo < -a < hi

    def critical_omega(self) -> float:
        """Lowest drive frequency that keeps (a, q) in the first region with κ_dc = 0:
        q = 2κ/Ω² < Q_MAX, i.e. Ω > sqrt(2κ/Q_MAX) ≈ 1.484·sqrt(κ). (With κ_dc ≠ 0 use
        `is_stable`.)"""
        if self.kappa_dc != 0.0:
            raise ValueError("critical_omega is the a = 0 threshold; kappa_dc must be 0 "
                             "(use is_stable for a != 0)")
        return math.sqrt(2.0 * self.kappa / Q_MAX)

    def drive(self) -> tuple[OmegaProfile, float]:
        """The drive as the integrator takes it: the Ω profile and the phase."""
        return OmegaProfile(self.omega), self.phase


Trap = RRFTrap | PaulTrap


def _check_trap(trap: object) -> None:
    if not isinstance(trap, (RRFTrap, PaulTrap)):
        raise ValueError(f"trap must be an RRFTrap or a PaulTrap, got {type(trap).__name__}")


# ------------------------------------------------------------------------------------------
# Simulation through the project's integrator registry
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class IonTrajectory:
    """One ion's run, sampled at the output times reached before any escape.

    ``state`` rows are (x, y, vx, vy): for an RRF trap in the frame rotating with the
    quadrupole (axes along the laboratory's at t = 0), for a Paul trap in the laboratory.
    """

    trap: RRFTrap | PaulTrap
    t: np.ndarray
    state: np.ndarray
    event: str | None
    t_event: float | None
    settings: str
    steps: int

    @property
    def x(self) -> np.ndarray:
        """x of each output time."""
        return self.state[:, 0]

    @property
    def y(self) -> np.ndarray:
        """y of each output time."""
        return self.state[:, 1]

    @property
    def r(self) -> np.ndarray:
        """Distance from the trap's centre at each output time."""
        return np.hypot(self.x, self.y)

    def lab_xy(self) -> np.ndarray:
        """Position (n, 2) [m] in the laboratory."""
        if isinstance(self.trap, PaulTrap):
            return self.state[:, :2].copy()
        th = self.trap.omega * self.t
        c, s = np.cos(th), np.sin(th)
        return np.column_stack([c * self.x - s * self.y, s * self.x + c * self.y])


def lab_rest_state(trap: RRFTrap | PaulTrap, x: float, y: float) -> np.ndarray:
    """State of an ion at (x, y) at rest in the laboratory at t = 0 (for an RRF trap the
    rotating-frame velocity is −Ω k × r)."""
    _check_trap(trap)
    x, y = finite_number("x", x), finite_number("y", y)
    if isinstance(trap, PaulTrap):
        return np.array([x, y, 0.0, 0.0])
    return np.array([x, y, trap.omega * y, -trap.omega * x])


def simulate_ion(trap: RRFTrap | PaulTrap, state: Sequence[float] | np.ndarray, t_end: float, *,
                 dt_out: float | None = 0.01, method: str | None = None,
                 rtol: float | None = None, atol: float | None = None,
                 dt: float | None = None, max_step: float | None = None,
                 escape: bool = True, max_steps: int = 50_000_000) -> IonTrajectory:
    """Integrate one ion from t = 0 to ``t_end`` with the project's stepping loop.

    ``state`` = (x, y, vx, vy) [m, m/s] (see `IonTrajectory` for the frame). ``method``,
    ``rtol``, ``atol``, ``dt``, ``max_step``, ``max_steps`` as in `saddle_env.simulate`
    (DOP853, rtol = 1e-10 by default; ``atol`` is relative to the initial amplitude).
    ``escape``: stop when the ion reaches r0. The default largest step is π/(2Ω).
    """
    _check_trap(trap)
    try:
        y0 = np.asarray(state, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("state must be 4 real numbers (x, y, vx, vy)") from None
    if y0.shape != (4,) or not np.all(np.isfinite(y0)):
        raise ValueError(f"state must be 4 finite numbers (x, y, vx, vy), got {state!r}")
    t_out = _output_times(t_end, dt_out)
    events = ("escape",) if escape else ()
    settings = Settings.build(method, rtol, atol, dt, events, max_step, max_steps)
    if settings.max_step is not None:
        hmax = settings.max_step
    else:
        hmax = math.inf if settings.dt > 0 else default_max_step(trap.omega)
    if isinstance(trap, PaulTrap):
        prof, theta0 = trap.drive()
    else:
        prof, theta0 = OmegaProfile(trap.omega), 0.0
    # One tolerance for all components: lengths against the initial amplitude, velocities
    # against it times the fastest natural rate.
    rate = max(trap.omega, math.sqrt(abs(trap.kappa)), abs(getattr(trap, "omega_B", 0.0)), 1e-9)
    L = math.hypot(y0[0], y0[1]) + math.hypot(y0[2], y0[3]) / rate
    if L == 0.0:
        L = trap.r0 if math.isfinite(trap.r0) else 1.0
    scale = np.array([L, L, L * rate, L * rate, 1.0])
    y = np.zeros(K.STATE_WIDTH)
    y[:4] = y0
    m = settings.method
    Y_out = np.empty((len(t_out), K.STATE_WIDTH))
    stats = np.zeros(4, dtype=np.int64)
    args = (trap.model_code, trap.params(), drive_row(prof, theta0=theta0), y, 0.0, t_out,
            m.tableau, settings.control(hmax), scale, Y_out, stats, 0.0, workspace(m.tableau))
    # compiled for the ion trap alone, without the balls' contact models: a third of the
    # full loop's compile
    status, t_final = integrator_loop(trap.model_code, False, args)(*args)[:2]
    if status == STATUS_FAILED:
        raise SimulationError(f"ion integration failed at t = {t_final:.9g} s (non-finite "
                              "state or step-size underflow: an unstable trap with no r0?)")
    if status == STATUS_MAX_STEPS:
        raise SimulationError(f"ion integration stopped at t = {t_final:.9g} s after "
                              "max_steps steps")
    n = int(stats[3])
    event = EVENT_KINDS.get(int(status))
    return IonTrajectory(trap, t_out[:n].copy(), Y_out[:n, :4].copy(), event,
                         float(t_final) if event else None, settings.describe(),
                         int(stats[0]))


def floquet_multipliers(trap: PaulTrap) -> np.ndarray:
    """|μ| of the Paul trap's x and y motion over one drive period, from simulation.

    The monodromy matrix of each axis is built from two runs of `simulate_ion` over
    T = 2π/Ω (DOP853, rtol 1e-12); returns the largest |μ| of x and of y. Stable (first or a
    higher region) iff both are 1 (to integration accuracy); > 1 grows as |μ|^(t/T).
    """
    if not isinstance(trap, PaulTrap):
        raise ValueError(f"trap must be a PaulTrap, got {type(trap).__name__}")
    free = PaulTrap(trap.omega, trap.kappa, trap.kappa_dc, trap.phase)
    T = 2 * math.pi / trap.omega
    M = np.empty((2, 2, 2))
    for col, s in enumerate(((1.0, 1.0, 0.0, 0.0), (0.0, 0.0, trap.omega, trap.omega))):
        end = simulate_ion(free, s, T, dt_out=None, rtol=1e-12, escape=False).state[-1]
        M[0, :, col] = end[0], end[2] / trap.omega
        M[1, :, col] = end[1], end[3] / trap.omega
    return np.array([np.abs(np.linalg.eigvals(M[k])).max() for k in range(2)])


# ------------------------------------------------------------------------------------------
# The ball → ion map
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BallIonMap:
    """The RRF ion that obeys a ball's linearised equations (`ball_to_ion`).

    Attributes
    ----------
    trap : RRFTrap
        Same Ω as the saddle.
    stretch : float
        λ = sqrt(−D/B): the ball's centre (x_c, y_c) is the ion at
        (x_c, y_c/λ) exactly (linear order). 1 when the map needs no stretch.
    ball, ion : ABCD
        The ball's Table I coefficients and the ion's Eq. (comp2) ones.
    exact_unstretched : bool
        λ = 1: the ball's centre and the ion coincide (linear order).
    """

    trap: RRFTrap
    stretch: float
    ball: ABCD
    ion: ABCD
    exact_unstretched: bool

    def ion_state(self, centre_state: Sequence[float] | np.ndarray) -> np.ndarray:
        """Ion state for a ball-centre state (x_c, y_c, ẋ_c, ẏ_c) in the rotating frame."""
        z = np.asarray(centre_state, dtype=float)
        if z.shape != (4,) or not np.all(np.isfinite(z)):
            raise ValueError(f"centre_state must be 4 finite numbers, got {centre_state!r}")
        return np.array([z[0], z[1] / self.stretch, z[2], z[3] / self.stretch])

    def ball_centre(self, ion_xy: np.ndarray) -> np.ndarray:
        """Ball-centre positions (n, 2) from ion positions (n, 2) (undo the stretch)."""
        xy = np.array(ion_xy, dtype=float)
        xy[..., 1] *= self.stretch
        return xy


def _ion_from_abcd(c: ABCD, omega: float, r0: float) -> tuple[RRFTrap, float]:
    if not (c.B * c.D < 0):
        raise ValueError(f"no RRF ion matches these coefficients: B·D = {c.B * c.D:g} >= 0 "
                         "(the spin about the vertical is too large for the map)")
    lam = math.sqrt(-c.D / c.B)
    Bi = math.copysign(math.sqrt(-c.B * c.D), c.B)
    wB = 2.0 * omega - Bi
    kappa = 0.5 * (c.C - c.A)
    kt = 0.5 * (c.A + c.C) - omega * omega + omega * wB
    return RRFTrap(omega=omega, kappa=kappa, omega_B=wB, kappa_t=kt, r0=r0), lam


def ball_to_ion(scene: Scene, omega: float, spin_z: float = 0.0) -> BallIonMap:
    """The RRF ion whose linear equations are the ball's (Table I), at the saddle's Ω.

    Matches A and C exactly through the quadrupole κ = (C − A)/2 and the static term κ_t, and
    B, D through the field: ion B = −D = 2Ω − ω_B. A ball has B = −D exactly when its spin
    about the vertical relative to the saddle ω_z is 0 (any contact model, any a, b) or when
    R = 0; then λ = 1 and

        mass point / slipping:  ω_B = 0,                   κ = g(1/(a−2R) + 1/(b+2R)),
        rolling (ω_z = 0):      ω_B = αΩ/(1+α),            κ = g(1/(a−2R) + 1/(b+2R))/(1+α),

    with κ_t = g(1/(b+2R) − 1/(a−2R)) (÷(1+α) rolling): a rolling ball's (2+α)/(1+α)·Ω
    Coriolis factor is exactly a magnetic field, the one its spin Ω in the laboratory
    produces. With ω_z ≠ 0 the unequal geometric factors (p = αΛ̃₁₁ < 0 < q = αΛ̃₂₂) make
    B ≠ −D; the ion then takes ω_B = 2Ω − sqrt(−BD) (same eigen-frequencies) and the map is
    exact in stretched coordinates y_ion = y_c/λ, λ = sqrt(−D/B).

    Exact for the linearised equations only: the ion has no z motion, no detachment, and
    its quadrupole stays exactly quadratic where the saddle does not.
    """
    c = abcd(scene, omega, spin_z)
    trap, lam = _ion_from_abcd(c, float(omega), math.inf)
    return BallIonMap(trap, lam, c, trap.abcd(), abs(lam - 1.0) <= 1e-12)


def paper_analogy_ion(scene: Scene, omega: float, spin_z: float = 0.0) -> RRFTrap:
    """The paper's own reading of its Eqs. (comp2)/(comp3): same Ω, the scaled Coriolis
    term 2Ω kept (not (2+α)Ω/(1+α)), gravity's saddle as the quadrupole and static term
    (κ = g(1/(a−2R) + 1/(b+2R)), κ_t = g(1/(b+2R) − 1/(a−2R))), and the spin as the field:
    ω_B = q·ω_z with q = αΛ̃₂₂ = 2αR/(b+2R) (from B; the x equation would want p·ω_z, of
    the opposite sign). Exact for the mass point and the slipping ball (ω_z = 0); for a
    rolling ball it is the analogy whose mismatch `eigenfrequency_mismatch` measures."""
    if not isinstance(scene, Scene):
        raise ValueError(f"scene must be a saddle_env.Scene, got {type(scene).__name__}")
    W = _rate("omega", omega, positive=True)
    wz = _rate("spin_z", spin_z)
    assert scene.b is not None  # Scene.__post_init__ sets b (None means b = a)
    a, b, R, g, al = scene.a, scene.b, scene.radius, scene.g, scene.alpha
    q = 2 * al * R / (b + 2 * R) if scene.rolling else 0.0
    return RRFTrap(omega=W, kappa=g * (1 / (a - 2 * R) + 1 / (b + 2 * R)), omega_B=q * wz,
                   kappa_t=g * (1 / (b + 2 * R) - 1 / (a - 2 * R)))


def eigenfrequency_mismatch(scene: Scene, omega: float, trap: RRFTrap,
                            spin_z: float = 0.0) -> float:
    """max_k |ϖ_ball,k − ϖ_ion,k| / max_k |ϖ_ball,k| over the four roots (sorted by real
    part, both in the rotating frame)."""
    _check_trap(trap)
    wb = eigenfrequencies(scene, omega, spin_z)
    wi = trap.eigenfrequencies()
    return float(np.abs(wb - wi).max() / np.abs(wb).max())


def max_rel_diff(a: np.ndarray, b: np.ndarray) -> float:
    """max over samples of |a − b| (Euclidean per row) over max |a|: the figure of merit of
    every trajectory comparison here."""
    a, b = np.atleast_2d(a), np.atleast_2d(b)
    return float(np.linalg.norm(a - b, axis=-1).max() / np.linalg.norm(a, axis=-1).max())


def linear_ball_vs_ion(scene: Scene, omega: float, centre_state: Sequence[float],
                       t_end: float = 10.0, dt_out: float = 0.01, spin_z: float = 0.0,
                       rtol: float = 1e-10) -> tuple[float, IonTrajectory, np.ndarray]:
    """Largest relative difference between the ball's linearised centre trajectory (exact,
    `linear.linear_trajectory`) and the mapped ion's simulated one (stretched back), over
    ``t_end``; also returns the ion run and the ball's (n, 4) linear trajectory."""
    mp = ball_to_ion(scene, omega, spin_z)
    ion = simulate_ion(mp.trap, mp.ion_state(centre_state), t_end, dt_out=dt_out, rtol=rtol,
                       escape=False)
    lin = linear_trajectory(scene, omega, np.asarray(centre_state, float), ion.t, spin_z)
    return max_rel_diff(lin[:, :2], mp.ball_centre(ion.state[:, :2])), ion, lin


