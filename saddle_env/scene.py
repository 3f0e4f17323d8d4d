"""Scene parameters: the saddle, the ball, gravity and the contact model.

One frozen, validated dataclass holds every physical parameter. Derived quantities
(the effective radius, the packed parameter vector the compiled kernels read) are
computed from it, never stored twice.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Literal

import numpy as np

ContactModel = Literal["rolling", "slipping", "point", "coulomb"]
CONTACT_MODELS: tuple[ContactModel, ...] = ("rolling", "slipping", "point", "coulomb")

# Integer codes the compiled kernels switch on (kept in one place). The ion codes select a
# charged particle in a quadrupole trap (saddle_env.iontrap), integrated by the same loop.
ROLLING, SLIPPING = 0, 1
ION_RRF, ION_PAUL = 2, 3
COULOMB = 4

# Layout of the packed parameter vector read by the kernels (saddle_env.kernels).
(P_A, P_B, P_R, P_ALPHA, P_G, P_DRILL, P_RIM, P_DRAG_LINEAR, P_DRAG_QUADRATIC, P_MU,
 P_MU_STATIC, P_RESIST, P_SPIN_BAND, P_TILT_FORCE, P_RIM_SQUARE, P_SURFACE_DRAG) = range(16)
N_PARAMS = 16
RimShape = Literal["circle", "square"]
RIM_SHAPES: tuple[RimShape, ...] = ("circle", "square")
# The largest tilt of the saddle's axis a scene accepts [rad] (about 11°): far beyond any
# levelled rig (a few mrad), and small enough that the saddle stays a saddle under the ball.
MAX_TILT = 0.2


def finite_number(name: str, value: object) -> float:
    """Return ``value`` as a float, or raise a ValueError that names ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a real number, got {value!r} ({type(value).__name__})")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return value


def _non_negative(name: str, value: object, unit: str, most: float = math.inf) -> float:
    """A finite number in [0, most] as a float, or a ValueError that names ``name``, its
    unit and its range."""
    v = finite_number(name, value)
    if v < 0:
        raise ValueError(f"{name} must be >= 0 ({unit}), got {v}")
    if v > most:
        raise ValueError(f"{name} must satisfy 0 <= {name} <= {most:g} ({unit}), got {v:g}")
    return v


# The largest dissipation rate a scene takes [1/s; 1/m for the quadratic drag, a rate at
# 1 m/s]: a relaxation within a microsecond is a constraint, not a friction, and much faster
# ones leave no step the integrator can take (overflow, or the step limit every step).
MAX_RATE = 1e6
MAX_G = 1000.0  # [m/s^2] about 100 Earth gravities


@dataclass(frozen=True)
class Scene:
    """A ball on a rotating saddle ``z = x**2/a - y**2/b``.

    Parameters
    ----------
    a : float
        Saddle length along x [m]; the surface is ``z = x²/a − y²/b`` (the paper's saddle:
        0.159 m).
    b : float or None
        Saddle length along y [m]. None (the default) means ``b = a``, the symmetric saddle
        of the paper: the built scene's ``b`` holds the value used.
    R : float
        Ball radius [m], ``0 < R < min(a, b)/2``. Ignored (taken as 0) by ``contact="point"``.
    alpha : float
        Moment-of-inertia factor, ``I = alpha·m·R²`` (2/5 solid ball, 2/3 thin shell),
        ``0 < alpha <= 1``.
    g : float
        Gravitational acceleration [m/s²], ``>= 0``.
    contact : {"rolling", "slipping", "point", "coulomb"}
        ``"rolling"``: rolls without slipping (spin integrated). ``"slipping"``: frictionless,
        spin decoupled and not integrated. ``"point"``: the mass-point (Brouwer) model, i.e.
        slipping with R = 0. ``"coulomb"``: Coulomb friction between the two: the ball
        sticks (rolls) while the friction it needs stays below ``mu_static``·N and slips
        with friction ``mu``·N against the slip otherwise (docs/physics.md, "Coulomb
        friction"); position, contact-point velocity and full spin are integrated.
    rim_radius : float
        Size [m] of the saddle's edge: its horizontal radius (``rim_shape="circle"``) or the
        half-width of a square saddle (``"square"``); the ball escapes when its contact
        point leaves it. ``math.inf`` for an unbounded saddle.
    rim_shape : {"circle", "square"}
        The saddle's outline seen from above. ``"square"``: |x| and |y| at most
        ``rim_radius`` in the saddle's own axes (which turn with it), as a 3D-printed saddle
        measured to ±80 mm is.
    tilt : float
        Angle [rad] between the saddle's rotation axis and the vertical, ``0 <= tilt <= 0.2``,
        fixed in the laboratory: the axis leans toward the laboratory's x axis (the saddle's
        x axis at t = 0). Exact, not linearised: gravity has g·cos(tilt) along the axis and
        g·sin(tilt) across it, a force fixed in the laboratory that the rotating frame sees
        turn at -Ω. A levelled rig has a few mrad.
    drilling_friction : float
        Rate [1/s] at which friction about the contact normal relaxes the spin about the
        normal toward the saddle's own rate (the paper's ω_z → 0). Acts on rolling balls only
        (a slipping ball has no friction by definition). ``0`` disables it. At most
        ``MAX_RATE`` (1e6), as ``drag_linear``, ``drag_quadratic`` and ``surface_drag`` are.
    drag_linear : float
        Linear air drag [1/s]: a force per unit mass ``-drag_linear · u`` on the ball's
        centre, where ``u`` is the centre's velocity relative to still air in the laboratory.
        Acts on every contact model. ``0`` disables it.
    drag_quadratic : float
        Quadratic air drag [1/m]: a force per unit mass ``-drag_quadratic · |u| · u`` (for a
        ball of density ρ_b in air of density ρ_a with drag coefficient C_d, this is
        3 C_d ρ_a / (8 ρ_b R)). Acts on every contact model. ``0`` disables it.
    surface_drag : float
        Linear drag [1/s] against the centre's velocity relative to the saddle's surface: a
        force per unit mass ``-surface_drag · ċ`` (ċ in the rotating frame), as the vapour
        film under a Leidenfrost droplet or a viscous contact gives. Unlike air drag it pulls
        the ball along with the turning saddle, which undoes the trap's gyroscopic
        stabilisation slowly. Acts on every contact model. ``0`` disables it.
    rolling_resistance : float
        Rolling-resistance coefficient c_rr (dimensionless, ``>= 0``): a torque c_rr·R·N
        about the centre against the rolling part of the spin (its component along the
        surface, relative to the saddle), as a ball deforming at its contact feels. Acts on
        rolling and coulomb balls (a frictionless ball does not roll). ``0`` disables it.
    mu : float
        ``contact="coulomb"`` only: the kinetic friction coefficient, ``>= 0``. ``0`` is the
        frictionless (slipping) ball; a large value keeps it rolling.
    mu_static : float or None
        ``contact="coulomb"`` only: the static friction coefficient, ``>= mu``; defaults to
        ``mu``.
    """

    a: float = 0.159
    b: float | None = None
    R: float = 0.02
    alpha: float = 0.4
    g: float = 9.8
    contact: ContactModel = "rolling"
    rim_radius: float = 0.1
    drilling_friction: float = 0.0
    drag_linear: float = 0.0
    drag_quadratic: float = 0.0
    rolling_resistance: float = 0.0
    mu: float | None = None
    mu_static: float | None = None
    rim_shape: RimShape = "circle"
    tilt: float = 0.0
    surface_drag: float = 0.0

    def __post_init__(self) -> None:
        a = finite_number("a", self.a)
        if a <= 0:
            raise ValueError(f"a must be > 0 (saddle length in metres), got {a}")
        b = a if self.b is None else finite_number("b", self.b)
        if b <= 0:
            raise ValueError(f"b must be > 0 (saddle length in metres), got {b}")
        if not isinstance(self.contact, str) or self.contact not in CONTACT_MODELS:
            raise ValueError(f"contact must be one of {CONTACT_MODELS}, got {self.contact!r}")
        R = finite_number("R", self.R)
        if self.contact != "point":
            limit = min(a, b) / 2
            if not 0 < R < limit:
                raise ValueError(
                    f"R must satisfy 0 < R < min(a, b)/2 = {limit:g} m for contact={self.contact!r} "
                    f"(the ball must fit the saddle's curvature), got R = {R:g}"
                )
        elif R < 0:
            raise ValueError(f"R must be >= 0, got {R}")
        alpha = finite_number("alpha", self.alpha)
        if not 0 < alpha <= 1:
            raise ValueError(f"alpha must satisfy 0 < alpha <= 1 (I = alpha m R^2), got {alpha}")
        g = _non_negative("g", self.g, "m/s^2", MAX_G)
        rim = self.rim_radius
        if isinstance(rim, bool) or not isinstance(rim, (int, float, np.integer, np.floating)):
            raise ValueError(f"rim_radius must be a real number, got {rim!r}")
        rim = float(rim)
        if not (rim > 0) or math.isnan(rim):
            raise ValueError(f"rim_radius must be > 0 (metres, or math.inf), got {rim}")
        drill = _non_negative("drilling_friction", self.drilling_friction, "1/s", MAX_RATE)
        drag_linear = _non_negative("drag_linear", self.drag_linear, "1/s", MAX_RATE)
        drag_quadratic = _non_negative("drag_quadratic", self.drag_quadratic, "1/m", MAX_RATE)
        resist = _non_negative("rolling_resistance", self.rolling_resistance, "dimensionless",
                               1.0)  # a torque beyond R N: no ball rolls against that
        surface_drag = _non_negative("surface_drag", self.surface_drag, "1/s", MAX_RATE)
        if not isinstance(self.rim_shape, str) or self.rim_shape not in RIM_SHAPES:
            raise ValueError(f"rim_shape must be one of {RIM_SHAPES}, got {self.rim_shape!r}")
        tilt = finite_number("tilt", self.tilt)
        if not 0 <= tilt <= MAX_TILT:
            raise ValueError(f"tilt must satisfy 0 <= tilt <= {MAX_TILT} (rad, the axis's angle "
                             f"from the vertical), got {tilt:g}")
        mu, mu_static = self._friction_coefficients()
        # Normalise to plain floats so equality, hashing and pickling behave.
        for name, value in (("a", a), ("b", b), ("R", R), ("alpha", alpha), ("g", g),
                            ("rim_radius", rim), ("drilling_friction", drill),
                            ("drag_linear", drag_linear), ("drag_quadratic", drag_quadratic),
                            ("rolling_resistance", resist), ("mu", mu),
                            ("mu_static", mu_static), ("tilt", tilt),
                            ("surface_drag", surface_drag)):
            object.__setattr__(self, name, value)

    def _friction_coefficients(self) -> tuple[float | None, float | None]:
        """Validated (mu, mu_static): both numbers for "coulomb", both None otherwise."""
        if self.contact != "coulomb":
            for name in ("mu", "mu_static"):
                if getattr(self, name) is not None:
                    raise ValueError(f"{name} applies to contact='coulomb' only (got "
                                     f"contact={self.contact!r}); leave it None")
            return None, None
        if self.mu is None:
            raise ValueError("contact='coulomb' needs mu, the kinetic friction coefficient "
                             "(>= 0; e.g. Scene(contact='coulomb', mu=0.3))")
        mu = _non_negative("mu", self.mu, "kinetic friction coefficient")
        mu_static = mu if self.mu_static is None else finite_number("mu_static", self.mu_static)
        if mu_static < mu:
            raise ValueError(f"mu_static must be >= mu = {mu:g} (static friction is at least "
                             f"the kinetic), got {mu_static:g}")
        return mu, mu_static

    # -- derived quantities -------------------------------------------------------------
    @property
    def radius(self) -> float:
        """The radius the dynamics use [m]: 0 for the mass point, ``R`` otherwise."""
        return 0.0 if self.contact == "point" else self.R

    @property
    def rolling(self) -> bool:
        """True for the pure-rolling model (the constraint always holds)."""
        return self.contact == "rolling"

    @property
    def state_size(self) -> int:
        """Length of the state vector: (x, y, wx, wy, wz) rolling, (x, y, vx, vy) slipping
        and point, (x, y, wx, wy, wz, vx, vy) coulomb."""
        return {"rolling": 5, "coulomb": 7}.get(self.contact, 4)

    @property
    def model_code(self) -> int:
        """The compiled kernels' code for the contact model."""
        return {"rolling": ROLLING, "coulomb": COULOMB}.get(self.contact, SLIPPING)

    def params(self) -> np.ndarray:
        """The packed float64 parameter vector read by the compiled kernels."""
        p = np.empty(N_PARAMS)
        p[P_A], p[P_B], p[P_R], p[P_ALPHA] = self.a, self.b, self.radius, self.alpha
        # A tilted axis: gravity's part along it, and its part across it as a force fixed in
        # the laboratory (exact for any tilt; cos 0 = 1 keeps a level scene's g bit for bit).
        p[P_G] = self.g * math.cos(self.tilt)
        p[P_TILT_FORCE] = self.g * math.sin(self.tilt)
        p[P_DRILL], p[P_RIM] = self.drilling_friction, self.rim_radius
        p[P_RIM_SQUARE] = 1.0 if self.rim_shape == "square" else 0.0
        p[P_SURFACE_DRAG] = self.surface_drag
        p[P_DRAG_LINEAR], p[P_DRAG_QUADRATIC] = self.drag_linear, self.drag_quadratic
        p[P_MU] = 0.0 if self.mu is None else self.mu
        p[P_MU_STATIC] = 0.0 if self.mu_static is None else self.mu_static
        # only a ball with friction at its contact rolls against resistance
        p[P_RESIST] = self.rolling_resistance if self.contact in ("rolling", "coulomb") else 0.0
        # Not the scene's: the integrator's loop writes the rolling spin its tolerance cannot
        # tell from 0 (`integrators`, roll stop); rolling resistance treats a ball spinning
        # less as not rolling. 0 until a run sets it.
        p[P_SPIN_BAND] = 0.0
        return p

    @classmethod
    def from_curvatures(cls, c_plus: float, c_minus: float, **kwargs: object) -> Scene:
        """A scene on the saddle z = c₊x² − c₋y², as experimenters measure it: ``a = 1/c₊``,
        ``b = 1/c₋`` [m] (``c_plus``, ``c_minus`` in 1/m, both > 0). Other parameters as
        keywords."""
        cp = finite_number("c_plus", c_plus)
        cm = finite_number("c_minus", c_minus)
        for name, c in (("c_plus", cp), ("c_minus", cm)):
            if c <= 0:
                raise ValueError(f"{name} must be > 0 (saddle curvature in 1/m), got {c:g}")
        if "a" in kwargs or "b" in kwargs:
            raise ValueError("give the saddle either as c_plus, c_minus or as a, b, not both")
        return cls(a=1.0 / cp, b=1.0 / cm, **kwargs)  # type: ignore[arg-type]

    @property
    def c_plus(self) -> float:
        """Curvature c₊ = 1/a [1/m] of the rising direction."""
        return 1.0 / self.a

    @property
    def c_minus(self) -> float:
        """Curvature c₋ = 1/b [1/m] of the falling direction."""
        assert self.b is not None  # __post_init__ sets b (None means b = a)
        return 1.0 / self.b

    def with_(self, **changes: object) -> Scene:
        """A copy with some parameters changed (validated again)."""
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise ValueError(f"unknown Scene parameter(s) {sorted(unknown)}; "
                             f"known: {[f.name for f in fields(self)]}")
        return replace(self, **changes)  # type: ignore[arg-type]
