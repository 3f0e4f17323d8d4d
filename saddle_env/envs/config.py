"""Every option of the SaddleTrap environment, in one frozen, validated dataclass."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, Literal

import numpy as np

from ..integrators import METHODS
from ..lifetimes.model import MAX_SPEED_SPREAD
from ..runner import check_rtol
from ..scene import CONTACT_MODELS, Scene, finite_number

# The paper's three polyfoam balls [m].
PAPER_BALL_RADII = (0.0223, 0.0265, 0.0330)
# Still air at room temperature [kg/m³] and a smooth sphere's drag coefficient at the
# Reynolds numbers of a ball on the saddle (|u| ~ 0.1-1 m/s, d ~ 5 cm: Re ~ 300-3000), for
# ``ball_density``'s quadratic drag.
AIR_DENSITY = 1.2
SPHERE_DRAG_COEFFICIENT = 0.47
BALL_DENSITY_RANGE = (1.0, 25_000.0)  # kg/m³ a ball may have (ball_density)


def quadratic_drag(R: float, density: float) -> float:
    """Quadratic air drag per unit mass [1/m] of a ball of radius ``R`` [m] and ``density``
    [kg/m³]: ½ ρ_a C_d π R² |u| u / (ρ_b 4/3 π R³) = 3 C_d ρ_a / (8 ρ_b R) (`Scene`'s
    ``drag_quadratic``)."""
    return 3.0 * SPHERE_DRAG_COEFFICIENT * AIR_DENSITY / (8.0 * density * R)
# Every physical parameter is a field of `Scene` and an option of the environment by the
# same name; the scene validates them (tests/test_levels.py checks the two agree).
SCENE_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(Scene))

ActionMode = Literal["acceleration", "target", "voltage"]
ACTION_MODES = ("acceleration", "target", "voltage")
ObsFrame = Literal["rotating", "lab"]


def _positive(name: str, value: object, allow_zero: bool = False) -> float:
    v = finite_number(name, value)
    if v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {v}")
    return v


def _range(name: str, value: object, lo: float = -math.inf) -> tuple[float, float]:
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise ValueError(f"{name} must be a (low, high) pair, got {value!r}")
    low, high = (finite_number(f"{name}[{i}]", v) for i, v in enumerate(value))
    if not lo <= low <= high:
        raise ValueError(f"{name} must satisfy {lo:g} <= low <= high, got ({low:g}, {high:g})")
    return low, high


# Integrator steps in one control step before it counts as failed (the engine's limit); a
# fixed substep must fit a control period within it.
MAX_STEPS_PER_CONTROL_STEP = 100_000
# Upper ends of options that only have a lower one in physics: beyond them the integration
# overflows instead of answering.
MAX_OMEGA = 1000.0  # [rad/s] about 160 revolutions per second
MAX_AIR_FORCE = 1000.0  # [m/s^2] about 100 g
# The drive's speed error (a fraction): the lifetimes model's own bound.
MAX_SPEED_ERROR = MAX_SPEED_SPREAD


@dataclass(frozen=True)
class EnvConfig:
    """Options of `SaddleTrapEnv` (all are constructor keywords of the environment).

    Scene (see `saddle_env.Scene`): ``a, b, R, alpha, g, contact, rim_radius,
    drilling_friction, drag_linear, drag_quadratic, rolling_resistance, mu, mu_static,
    rim_shape, tilt, surface_drag`` (the friction coefficients apply to ``"coulomb"`` balls
    and are passed to no other). ``tilt`` [rad] leans the saddle's axis toward the
    laboratory's x axis; ``rim_shape`` ``"square"`` makes the saddle a square of half-width
    ``rim_radius``; ``surface_drag`` [1/s] drags the ball along with the saddle's surface.

    Control: ``control_period`` [s] (20 ms); ``max_accel`` [rad/s²], the motor's limit on
    |Ω̇| (20: 0 → 45 s⁻¹ in 2.25 s); ``omega_max`` [rad/s], the motor's top speed (45, about
    what the paper's apparatus reached); ``action_mode``: ``"acceleration"`` (action × max_accel
    is Ω̇), ``"target"`` (the action picks a target speed in [0, omega_max], approached at
    up to max_accel) or ``"voltage"`` (a DC motor: the action picks a voltage
    V = (action + 1)/2 · ``voltage_max`` and Ω follows τ Ω̇ = K V − Ω, τ = ``motor_tau`` [s],
    K = ``motor_gain`` [rad/s/V]; K · voltage_max must not exceed omega_max).

    The motor's defaults are estimates for the paper's rig (a 24 V DC motor turning a
    3D-printed saddle; the paper gives neither its inertia nor the motor's data):
    ``voltage_max`` = 24 V (the paper's 0-24 V); ``motor_gain`` = 45 / 24 = 1.875 rad/s/V:
    about the top speed the apparatus reached (43.6 s⁻¹ in the paper's detachment snapshots;
    ``omega_max`` = 45) at 24 V, taking Ω proportional to V (no dead band);
    ``motor_tau`` = 0.25 s, the mechanical time constant τ = J ω_nl / T_stall of a small
    24 V gearmotor (no-load 45 rad/s, stall torque about 1 N·m at the output) driving
    J ≈ 5.5e-3 kg·m² (a 0.4 kg PLA saddle of radius 0.15 m as a disc, ½ m r² = 4.5e-3, plus
    about 1e-3 of rotor inertia reflected through the gearbox): an estimate good to a factor
    of two, not a measurement.

    Delays (0 by default; any non-negative value, exact, not rounded to a control period):
    ``obs_delay`` [s], the camera's latency: the observation after a step is the state at
    t − obs_delay (before the episode's start, the starting state); ``action_delay`` [s]: a
    command takes effect that long after it is given (until the first does, the motor holds
    its starting speed). The integration of a control period is split where a sample is
    taken or a command takes effect (`engine.DelayPlan`).

    Observation: ``obs_frame`` ``"rotating"`` or ``"lab"``; sensor noise standard deviations
    ``position_noise`` [m], ``velocity_noise`` [m/s], ``omega_noise`` [rad/s];
    ``observe_command`` adds the commanded speed (exact: the motor controller's own
    set-point) and ``observe_angle`` the saddle's angle as cos θ, sin θ (the lab frame always
    has it); ``obs_history`` k (1-64) makes the observation the last k frames, newest first.
    A camera: ``observe_velocity`` (True) set False leaves the velocities out (positions
    only; the ball's spin is never observed) and ``position_quantum`` [m] rounds the positions to a
    pixel's size (0: not rounded).
    Layout: `saddle_env.envs.observation`.

    Episode start (the ball placed by hand near the centre): offset uniform in a disc of
    radius ``init_offset`` [m]; ``init_start`` ``"lab-rest"`` (placed at rest in the lab) or
    ``"rotating-rest"``, plus a random velocity of up to ``init_speed`` [m/s]; Ω₀ uniform in
    ``omega0_range`` [rad/s]. The lab's launcher (`saddle_env.lifetimes`): ``init_spread`` [m]
    > 0 draws each coordinate of the release point from a normal of that standard deviation
    in place of ``init_offset``'s disc, and ``init_spin`` ``"lab"`` releases the ball not
    spinning in the laboratory (``"saddle"``, the default: spinning with the saddle). A real
    rig's imperfections: ``speed_error`` σ (a fraction, at most 0.2) draws the drive's error
    once per episode, as ``saddle-lifetimes`` does: the saddle turns at (1 + σz) times the
    speed the action asks for (and the starting speed), z standard normal (in
    ``"target"`` and ``"voltage"`` modes; the tachometer shows the true speed);
    ``tilt_direction`` ``"random"`` draws the direction the axis leans in (``tilt``) each
    episode, uniform around the vertical (``"x"``: toward the laboratory's x axis; random
    needs ``air_force`` 0, whose lab-fixed force slot it uses). Domain randomisation:
    ``ball_radii`` (a tuple to draw R from,
    e.g. `PAPER_BALL_RADII`), ``a_range`` ((low, high) for the saddle length, b = a
    unless ``b`` is given), ``contact_models`` (a tuple to draw from) and ``mu_range``
    ((low, high): a coulomb ball's kinetic friction coefficient, uniform; its static one is
    ``mu_static`` if given, else equal). ``ball_density`` [kg/m³] (None: off) gives every
    ball, drawn or not, the quadratic air drag of its size (`quadratic_drag`: still air of
    1.2 kg/m³, C_d 0.47) in place of ``drag_quadratic``.

    Reward per step: the fraction of the step the ball stayed trapped, minus
    ``distance_cost``·(r/rim)², minus ``effort_cost``·action², minus ``loss_penalty`` when the
    ball detaches or escapes.

    Disturbances (off by default): ``air_force`` [m/s²], the standard deviation of a random
    horizontal force per unit mass fixed in the lab, an Ornstein–Uhlenbeck process with
    correlation time ``air_force_tau`` [s] (constant within a step); ``ripple_amp`` [rad/s]
    and ``ripple_freq`` [rad/s], a sinusoidal ripple of the motor's speed with random phase.

    Integration: ``method`` (a name in ``saddle_env.METHODS``), ``rtol`` for adaptive
    methods or ``substep`` [s] for fixed steps (at least ``control_period`` / 100,000: the
    integrator's step limit in one control step).
    """

    # The scene's fields (`SCENE_FIELDS`), with the Scene's own defaults and checks (the
    # checks run by building the nominal scene); only the ball differs: the environment's
    # nominal ball is the paper's 2.65 cm one.
    a: float = Scene.a
    b: float | None = Scene.b
    R: float = PAPER_BALL_RADII[1]
    alpha: float = Scene.alpha
    g: float = Scene.g
    contact: str = Scene.contact
    rim_radius: float = Scene.rim_radius
    drilling_friction: float = Scene.drilling_friction
    drag_linear: float = Scene.drag_linear
    drag_quadratic: float = Scene.drag_quadratic
    rolling_resistance: float = Scene.rolling_resistance
    mu: float | None = Scene.mu
    mu_static: float | None = Scene.mu_static
    rim_shape: str = Scene.rim_shape
    tilt: float = Scene.tilt
    surface_drag: float = Scene.surface_drag
    control_period: float = 0.02
    max_accel: float = 20.0
    omega_max: float = 45.0
    action_mode: str = "acceleration"
    voltage_max: float = 24.0
    motor_gain: float = 1.875
    motor_tau: float = 0.25
    obs_delay: float = 0.0
    action_delay: float = 0.0
    obs_frame: str = "rotating"
    position_noise: float = 0.0
    velocity_noise: float = 0.0
    omega_noise: float = 0.0
    observe_command: bool = False
    observe_angle: bool = False
    observe_velocity: bool = True
    position_quantum: float = 0.0
    obs_history: int = 1
    init_offset: float = 0.01
    init_start: str = "lab-rest"
    init_speed: float = 0.0
    omega0_range: tuple[float, float] = (15.0, 25.0)
    init_spread: float = 0.0
    init_spin: str = "saddle"
    speed_error: float = 0.0
    tilt_direction: str = "x"
    ball_radii: tuple[float, ...] | None = None
    a_range: tuple[float, float] | None = None
    contact_models: tuple[str, ...] | None = None
    mu_range: tuple[float, float] | None = None
    ball_density: float | None = None
    loss_penalty: float = 10.0
    distance_cost: float = 0.0
    effort_cost: float = 0.0
    air_force: float = 0.0
    air_force_tau: float = 1.0
    ripple_amp: float = 0.0
    ripple_freq: float = 0.0
    method: str = "dop853"
    rtol: float | None = 1e-8
    substep: float | None = None

    def __post_init__(self) -> None:
        # In this order: the first invalid option found is the one reported.
        self._check_drag_and_friction()
        self._check_motor()
        self._check_observation()
        self._check_episode()
        self._check_randomisation()
        self._check_integration()

    def _set(self, name: str, value: object) -> None:
        """Store a checked (normalised) value in the frozen dataclass."""
        object.__setattr__(self, name, value)

    def _check_drag_and_friction(self) -> None:
        """The drag, the nominal scene and the friction coefficients."""
        if self.ball_density is not None:
            density = _positive("ball_density", self.ball_density)
            # From aerogel to tungsten: outside it the drag formula over- or underflows.
            if not BALL_DENSITY_RANGE[0] <= density <= BALL_DENSITY_RANGE[1]:
                raise ValueError(f"ball_density must be in [{BALL_DENSITY_RANGE[0]:g}, "
                                 f"{BALL_DENSITY_RANGE[1]:g}] kg/m^3, got {density}")
            self._set("ball_density", density)
            if self.drag_quadratic != 0.0:
                raise ValueError("give drag_quadratic or ball_density (which sets each ball's "
                                 "quadratic drag from its size), not both")
        if self.mu_range is not None:  # before the nominal scene, which takes its low end
            self._set("mu_range", _range("mu_range", self.mu_range, lo=0.0))
        # Scene parameters are validated by building the nominal scene.
        self.scene()
        if self.g == 0:  # the simulator takes g = 0; a trap needs gravity to work against
            raise ValueError("g must be > 0 m/s^2 in the environment, got 0: gravity holds "
                             "the ball on the saddle (the trap's threshold sqrt(2g/(a - 2R)) "
                             "is 0 without it, and no start keeps the ball on the surface)")
        # The friction coefficients reach only coulomb balls' scenes: check them here too.
        for name in ("mu", "mu_static"):
            if getattr(self, name) is not None:
                self._set(name, _positive(name, getattr(self, name), allow_zero=True))
        if self.mu is not None and self.mu_static is not None and self.mu_static < self.mu:
            raise ValueError(f"mu_static must be >= mu = {self.mu:g}, got {self.mu_static:g}")

    def _check_motor(self) -> None:
        """The control period, the motor and the delays."""
        self._set("control_period", _positive("control_period", self.control_period))
        if self.control_period > 1.0:
            raise ValueError(f"control_period must be <= 1 s, got {self.control_period}")
        self._set("max_accel", _positive("max_accel", self.max_accel))
        self._set("omega_max", _positive("omega_max", self.omega_max))
        if self.omega_max > MAX_OMEGA:
            raise ValueError(f"omega_max must be <= {MAX_OMEGA:g} rad/s (a saddle far past any "
                             f"detachment speed), got {self.omega_max:g}")
        if self.action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode must be one of {ACTION_MODES}, got {self.action_mode!r}")
        for name in ("voltage_max", "motor_gain", "motor_tau"):
            self._set(name, _positive(name, getattr(self, name)))
        if self.action_mode == "voltage" and \
                self.motor_gain * self.voltage_max > self.omega_max * (1 + 1e-12):
            raise ValueError(f"motor_gain * voltage_max (the motor's top speed, "
                             f"{self.motor_gain * self.voltage_max:g} rad/s) must be <= "
                             f"omega_max = {self.omega_max:g} in voltage mode")
        for name in ("obs_delay", "action_delay"):
            self._set(name, _positive(name, getattr(self, name), allow_zero=True))
            if getattr(self, name) > 10.0:
                raise ValueError(f"{name} must be <= 10 s, got {getattr(self, name)}")

    def _check_observation(self) -> None:
        """The observation's frame, columns and history."""
        if self.obs_frame not in ("rotating", "lab"):
            raise ValueError(f"obs_frame must be 'rotating' or 'lab', got {self.obs_frame!r}")
        for name in ("observe_command", "observe_angle", "observe_velocity"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
            self._set(name, bool(getattr(self, name)))
        if self.observe_command and self.action_mode == "voltage":
            # the column would hold the motor's true speed: no set-point exists to observe
            raise ValueError("observe_command needs a speed servo (action_mode 'acceleration' "
                             "or 'target'); a voltage-driven motor has no commanded speed (the "
                             "controller knows the voltage it gave)")
        k = self.obs_history
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= 64:
            raise ValueError(f"obs_history must be an integer in [1, 64], got {k!r}")
        self._set("obs_history", int(k))

    def _check_episode(self) -> None:
        """Noise, rewards, disturbances and the episode's start."""
        for name in ("position_noise", "velocity_noise", "omega_noise", "init_offset",
                     "init_speed", "loss_penalty", "distance_cost", "effort_cost",
                     "air_force", "ripple_amp", "ripple_freq", "position_quantum"):
            self._set(name, _positive(name, getattr(self, name), allow_zero=True))
        self._set("air_force_tau", _positive("air_force_tau", self.air_force_tau))
        if self.air_force > MAX_AIR_FORCE:
            raise ValueError(f"air_force must be <= {MAX_AIR_FORCE:g} m/s^2 (a draught, not a "
                             f"blast), got {self.air_force:g}")
        if self.ripple_amp > self.omega_max:
            raise ValueError(f"ripple_amp must be <= omega_max = {self.omega_max:g} rad/s, "
                             f"got {self.ripple_amp:g}")
        if self.init_speed > self.max_start_speed:
            raise ValueError(f"init_speed must be <= omega_max * rim_radius = "
                             f"{self.max_start_speed:g} m/s, got {self.init_speed}")
        if self.init_offset >= self.rim_radius:
            raise ValueError(f"init_offset must be < rim_radius = {self.rim_radius}, got {self.init_offset}")
        if self.init_start not in ("lab-rest", "rotating-rest"):
            raise ValueError(f"init_start must be 'lab-rest' or 'rotating-rest', got {self.init_start!r}")
        low, high = _range("omega0_range", self.omega0_range, lo=0.0)
        if high > self.omega_max:
            raise ValueError(f"omega0_range must lie within [0, omega_max = {self.omega_max}], "
                             f"got ({low}, {high})")
        top = self.motor_gain * self.voltage_max   # the voltage-driven motor's top speed
        if self.action_mode == "voltage" and high > top * (1 + 1e-12):
            raise ValueError(f"omega0_range must lie within [0, motor_gain * voltage_max = "
                             f"{self.motor_gain * self.voltage_max:g}] in voltage mode (the "
                             f"motor holds its start speed), got ({low}, {high})")
        self._set("omega0_range", (low, high))
        self._check_lab_release()

    def _check_lab_release(self) -> None:
        """The lab's launcher and the rig's per-episode imperfections (issue 57)."""
        self._set("init_spread", _positive("init_spread", self.init_spread, allow_zero=True))
        # Ten standard deviations inside the rim: a release off the saddle is never drawn.
        if self.init_spread > self.rim_radius / 10:
            raise ValueError(f"init_spread must be <= rim_radius / 10 = "
                             f"{self.rim_radius / 10:g} m, got {self.init_spread:g}")
        if self.init_spin not in ("saddle", "lab"):
            raise ValueError(f"init_spin must be 'saddle' or 'lab', got {self.init_spin!r}")
        self._set("speed_error", _positive("speed_error", self.speed_error, allow_zero=True))
        if self.speed_error > MAX_SPEED_ERROR:
            raise ValueError(f"speed_error must be <= {MAX_SPEED_ERROR:g} (a fraction of the "
                             f"speed), got {self.speed_error:g}")
        if self.speed_error > 0 and self.action_mode == "acceleration":
            raise ValueError("speed_error scales the speed an action asks for: it needs "
                             "action_mode 'target' or 'voltage', not 'acceleration'")
        if self.tilt_direction not in ("x", "random"):
            raise ValueError(f"tilt_direction must be 'x' or 'random', got "
                             f"{self.tilt_direction!r}")
        if self.tilt_direction == "random" and self.air_force > 0:
            # the drawn direction's share of the tilt rides in the lab-fixed force's slot,
            # which the air current's process would decay
            raise ValueError("tilt_direction 'random' needs air_force 0 (it carries the "
                             "tilt's drawn direction in the lab-fixed force)")

    def _check_randomisation(self) -> None:
        """Domain randomisation; every randomised scene must be valid."""
        if self.ball_radii is not None:
            if not isinstance(self.ball_radii, (tuple, list)):
                raise ValueError(f"ball_radii must be None or a tuple of radii [m], "
                                 f"got {self.ball_radii!r}")
            radii = tuple(_positive(f"ball_radii[{i}]", r) for i, r in enumerate(self.ball_radii))
            if not radii:
                raise ValueError("ball_radii must be None or a non-empty tuple of radii")
            self._set("ball_radii", radii)
        if self.a_range is not None:
            self._set("a_range", _range("a_range", self.a_range, lo=1e-12))
        if self.contact_models is not None:
            if not isinstance(self.contact_models, (tuple, list)):
                raise ValueError(f"contact_models must be None or a tuple from {CONTACT_MODELS}, "
                                 f"got {self.contact_models!r}")
            models = tuple(self.contact_models)
            if not models or any(m not in CONTACT_MODELS for m in models):
                raise ValueError(f"contact_models must be a non-empty tuple from {CONTACT_MODELS}, "
                                 f"got {self.contact_models!r}")
            self._set("contact_models", models)
        if self.mu_range is not None:
            if "coulomb" not in (self.contact_models or (self.contact,)):
                raise ValueError("mu_range randomises a coulomb ball's friction: it needs "
                                 "contact='coulomb' or 'coulomb' in contact_models")
        # Every randomised scene must be valid: check the extremes now, not mid-training.
        for scene in self.extreme_scenes():
            scene.with_()  # re-validates

    def _check_integration(self) -> None:
        """The integration method and its tolerance or step."""
        if not isinstance(self.method, str) or self.method not in METHODS:
            raise ValueError(f"method must be one of {sorted(METHODS)}, got {self.method!r}")
        if self.substep is not None:
            self._set("substep", _positive("substep", self.substep))
            shortest = self.control_period / MAX_STEPS_PER_CONTROL_STEP
            if self.substep < shortest:  # every control step would hit the step limit
                raise ValueError(f"substep must be >= control_period / "
                                 f"{MAX_STEPS_PER_CONTROL_STEP:,} = {shortest:.3g} s, "
                                 f"got {self.substep!r}")
            if self.rtol is not None and METHODS[self.method].adaptive:
                self._set("rtol", None)
        elif not METHODS[self.method].adaptive:
            raise ValueError(f"method {self.method!r} is fixed-step: give substep [s]")
        if self.rtol is not None:
            self._set("rtol", check_rtol(self.rtol))  # the simulator's own check

    @classmethod
    def from_kwargs(cls, **kwargs: object) -> EnvConfig:
        """The configuration from keyword options (``gym.make``'s), each checked.

        Raises
        ------
        ValueError
            On an unknown option or a value outside its range.
        """
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(kwargs) - known)
        if unknown:
            raise ValueError(f"unknown SaddleTrap option(s) {unknown}; known options: {sorted(known)}")
        return cls(**kwargs)  # type: ignore[arg-type]

    @property
    def max_start_speed(self) -> float:
        """The largest start speed [m/s] a reset accepts (options ``vx, vy``, ``init_speed``,
        a spin's surface speed): the rim's own speed at the motor's top speed,
        ``omega_max * rim_radius``. A ball faster than the saddle's rim is not a trapping
        problem."""
        return self.omega_max * self.rim_radius

    def as_dict(self) -> dict[str, Any]:
        """Every option and its value."""
        return asdict(self)

    def voltage_of_action(self, action: Any) -> Any:
        """The motor voltage [V] of an action in voltage mode: V = (a + 1)/2 · ``voltage_max``
        with the action clipped to [-1, 1], as the environment's step applies it (its steady
        speed is ``motor_gain`` · V). A rig's loop writes this to the motor driver; a float
        for a number, an array for an array (the controllers' batches)."""
        a = np.asarray(action, dtype=float)
        if not np.isfinite(a).all():
            raise ValueError(f"action must be finite (in [-1, 1]), got {action!r}")
        v = 0.5 * (np.clip(a, -1.0, 1.0) + 1.0) * self.voltage_max
        return float(v) if v.ndim == 0 else v

    def action_of_voltage(self, voltage: float) -> float:
        """The action whose voltage is ``voltage`` [V] (the inverse of `voltage_of_action`);
        ValueError outside [0, ``voltage_max``]."""
        v = float(voltage)
        if not 0.0 <= v <= self.voltage_max:
            raise ValueError(f"voltage must be in [0, voltage_max = {self.voltage_max:g}] V, "
                             f"got {voltage!r}")
        return 2.0 * v / self.voltage_max - 1.0

    def scene(self, **changes: object) -> Scene:
        """The nominal scene (or one with randomised parameters changed)."""
        kw = {name: getattr(self, name) for name in SCENE_FIELDS}
        kw.update(changes)
        if self.ball_density is not None and isinstance(kw["R"], (int, float)) and kw["R"] > 0:
            kw["drag_quadratic"] = quadratic_drag(float(kw["R"]), self.ball_density)
        if kw["contact"] != "coulomb":  # friction coefficients belong to coulomb balls only
            kw["mu"] = kw["mu_static"] = None
        elif kw["mu"] is None and self.mu_range is not None:
            kw["mu"] = self.mu_range[0]
        return Scene(**kw)

    def extreme_scenes(self) -> list[Scene]:
        """The scenes at the corners of the randomised ranges (radii, saddle shapes, contact models)."""
        radii = self.ball_radii or (self.R,)
        a_values = self.a_range or (self.a,)
        models = self.contact_models or (self.contact,)
        mus = self.mu_range or (self.mu,)
        out = []
        for R in (min(radii), max(radii)):
            for a in (min(a_values), max(a_values)):
                for m, mu in ((model, mu) for model in models
                              for mu in (mus if model == "coulomb" else (None,))):
                    friction = {"mu": mu} if mu is not None else {}
                    try:
                        out.append(self.scene(R=R, a=a, contact=m, **friction))
                    except ValueError as exc:
                        raise ValueError(f"randomised scene R={R}, a={a}, contact={m!r} is "
                                         f"invalid: {exc}") from None
        return out
