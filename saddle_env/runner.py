"""The simulator below its public entry points: the one check of a run's inputs, validated
integrator settings, initial states, results, and the runs.

* Inputs: `check_run` (one ball) and `check_batch` (many) check everything but the
  integrator settings, once per call, out of the checks named for their job
  (`check_state`, `check_force`, `output_times`, `omega_rows`, `check_angles`);
  `Settings.build` checks the settings.
* Runs: `run_checked` and `run_batch_checked` run checked inputs with checked settings;
  `run` and `run_batch` check and run in one call, with explicit settings.

This is the layer automatic accuracy (`saddle_env.accuracy`) pilots: it never resolves
``tol=``. The public entry points `saddle_env.simulate.simulate` / `simulate_batch` sit above
both: they check with this module, resolve ``tol=`` (one place), run with this module and
report fixed steps that are too large.

Both runs call the same compiled loop (`saddle_env.integrators.integrate`); the batch path
runs it once per ball in parallel threads, so a ball gives bit-identical results either way.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from . import blockstep, integrators
from . import kernels as K
from .compilation.specialise import entry
from .compilation.threads import in_threads
from .integrators import (
    EVENT_DETACH,
    EVENT_ESCAPE,
    EVENT_KINDS,
    LOG_PHASE,
    LOG_T,
    METHODS,
    STATUS_FAILED,
    STATUS_MAX_STEPS,
    Method,
    StepControl,
    state_scale,
    step_control,
    transition_log,
    workspace,
)
from .omega import OmegaProfile, drive_row, omega_rows
from .scene import COULOMB, P_RESIST, Scene, finite_number

# Default accuracy: DOP853 at this tolerance (see docs/accuracy.md).
DEFAULT_METHOD = "dop853"
DEFAULT_RTOL = 1e-10
DEFAULT_FIXED_DT = 1e-3
EVENT_NAMES = {"detach": EVENT_DETACH, "escape": EVENT_ESCAPE}
DEFAULT_EVENTS = ("detach", "escape")
MAX_OUTPUTS = 10_000_000
TRANSITION_LOG_ROWS = 100_000  # stick-slip transitions kept per run (more are counted)
PHASE_NAMES = {K.STICK: "stick", K.SLIP: "slip"}
RTOL_MIN = 1e-15

Start = Literal["rotating-rest", "lab-rest"]


class SimulationError(RuntimeError):
    """The integration could not continue (non-finite state, step-size underflow, step limit)."""


# --------------------------------------------------------------------------------------
# Initial states
# --------------------------------------------------------------------------------------
def initial_state(scene: Scene, x: float, y: float, vx: float = 0.0, vy: float = 0.0, *,
                  start: Start | None = None, omega: float | OmegaProfile = 0.0,
                  spin_normal: float = 0.0,
                  spin: Sequence[float] | None = None) -> np.ndarray:
    """State vector of a ball whose contact point is at (x, y) [m] in the rotating frame.

    Parameters
    ----------
    scene : Scene
    x, y : float
        Contact point [m], rotating (saddle) coordinates.
    vx, vy : float
        Contact-point velocity relative to the saddle [m/s]. Ignored when
        ``start`` is given.
    start : {"rotating-rest", "lab-rest"}, optional
        ``"rotating-rest"``: at rest on the saddle (vx = vy = 0). ``"lab-rest"``: placed at
        rest in the laboratory — the centre's velocity relative to the saddle is the
        tangential part of -Ω k×c (the normal part cannot be given to a ball that stays on
        the surface); needs ``omega``.
    omega : float or OmegaProfile
        The saddle speed at t = 0 (used by ``"lab-rest"``).
    spin_normal : float
        Rolling and coulomb: spin about the normal relative to the saddle
        [rad/s]; 0 is the state friction drives the ball to (the paper's ω_z = 0).
    spin : (wx, wy, wz), optional
        Coulomb only: the ball's whole angular velocity relative
        to the saddle, in the saddle's axes [rad/s], instead of the rolling one (then it
        slips from the start unless the two agree). By default a coulomb ball starts rolling
        without slip.

    Returns
    -------
    ndarray, shape (scene.state_size,)
        rolling ``(x, y, wx, wy, wz)``: the spin w relative to the saddle is n × ċ / R +
        spin_normal · n; slipping/point ``(x, y, vx, vy)``; coulomb
        ``(x, y, wx, wy, wz, vx, vy)``, the spin as rolling's unless ``spin`` is given.
    """
    if not isinstance(scene, Scene):
        raise ValueError(f"scene must be a saddle_env.Scene, got {type(scene).__name__}")
    x = finite_number("x", x)
    y = finite_number("y", y)
    vx = finite_number("vx", vx)
    vy = finite_number("vy", vy)
    spin_normal = finite_number("spin_normal", spin_normal)
    profile = OmegaProfile.coerce(omega)
    if start is not None:
        if start not in ("rotating-rest", "lab-rest"):
            raise ValueError(f"start must be 'rotating-rest' or 'lab-rest', got {start!r}")
        if start == "rotating-rest":
            vx = vy = 0.0
        else:
            vx, vy = K.lab_rest_velocity(scene.params(), profile(0.0), x, y)
    if spin is not None and scene.contact != "coulomb":
        raise ValueError(f"spin applies to contact='coulomb' only (got contact={scene.contact!r}); "
                         "a rolling ball's spin follows from its velocity (use spin_normal)")
    out = np.empty(K.STATE_WIDTH)
    K.state_from_velocity(scene.model_code, scene.params(), x, y, vx, vy, spin_normal, out)
    if spin is not None:
        if not isinstance(spin, (tuple, list, np.ndarray)) or len(spin) != 3:
            raise ValueError(f"spin must be a triple (wx, wy, wz) in rad/s, got {spin!r}")
        out[2:5] = [finite_number(f"spin {c}", w) for c, w in zip(("wx", "wy", "wz"), spin)]
    if not np.all(np.isfinite(out)):
        raise ValueError(f"initial state is not finite for x = {x:g}, y = {y:g}, vx = {vx:g}, "
                         f"vy = {vy:g} m: the position or velocity is too large for the saddle")
    return out[: scene.state_size].copy()


def padded_width(models: np.ndarray) -> int:
    """Width of a batch's public states (`BatchResult`, `Prediction`): a rolling ball's 5,
    or a coulomb ball's 7 when the batch (model codes ``models``) has one."""
    return K.DYNAMICS_WIDTH if np.any(np.asarray(models) == COULOMB) else 5


def check_force(force: object) -> tuple[float, float]:
    """A constant lab-fixed force per unit mass ``(fx, fy)`` [m/s²], checked: returned as a
    pair of floats; ValueError unless it is a pair of finite numbers."""
    if not isinstance(force, (tuple, list, np.ndarray)) or len(force) != 2:
        raise ValueError(f"force must be a pair (fx, fy) of lab-frame accelerations [m/s^2], "
                         f"got {force!r}")
    return finite_number("force fx", force[0]), finite_number("force fy", force[1])


def integrator_loop(model: int, resist: bool, args: tuple):
    """`integrators.integrate_h` compiled for the contact model (or ion trap) ``model`` alone,
    with rolling resistance if ``resist``, for the arguments ``args``
    (`compilation.specialise.entry`): its callers (`run_checked`, `iontrap.simulate_ion`)
    build every argument themselves, so their types do not change from call to call."""
    return entry((model,), resist, integrators, "integrate_h", args)


def check_state(scene: Scene, state: object, name: str = "state") -> np.ndarray:
    """A ball's state for ``scene``, checked and padded as the compiled loop takes it.

    Parameters
    ----------
    scene : Scene
        The ball's scene (its ``state_size`` and contact model).
    state : array_like, shape (scene.state_size,)
        Finite real numbers (from `initial_state`).
    name : str
        What the error messages call it (``"states[3]"`` for a batch's row).

    Returns
    -------
    ndarray, shape (STATE_WIDTH,)
        The state, zero-padded; a coulomb ball's phase slot set to ONSET.

    Raises
    ------
    ValueError
        Wrong length, not real, or not finite.
    """
    try:
        arr = np.asarray(state, dtype=float)
    except (TypeError, ValueError):
        arr = np.asarray(state, dtype=object)
    if arr.dtype.kind not in "fiu" or arr.shape != (scene.state_size,):
        raise ValueError(f"{name} must be a real vector of length {scene.state_size} for "
                         f"contact={scene.contact!r} (see initial_state), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr}")
    padded = np.zeros(K.STATE_WIDTH)
    padded[: scene.state_size] = arr
    padded[K.PHASE_SLOT] = starting_phase(scene)
    return padded


def starting_phase(scene: Scene) -> float:
    """A state's phase slot at the start: ONSET for a coulomb ball, whose state does not say
    its phase (the loop decides it), 0 for the other models."""
    return K.ONSET if scene.contact == "coulomb" else 0.0


# --------------------------------------------------------------------------------------
# Integration settings
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Settings:
    """Validated integration settings (method, step or tolerance, events)."""

    method: Method
    dt: float           # 0 → adaptive
    rtol: float
    atol: float
    events: int
    max_step: float | None
    max_steps: int

    @classmethod
    def build(cls, method: str | None, rtol: float | None, atol: float | None,
              dt: float | None, events: Sequence[str], max_step: float | None,
              max_steps: int) -> Settings:
        """Check the integrator settings; the parameters are `saddle_env.simulate.simulate`'s.

        Returns
        -------
        Settings

        Raises
        ------
        ValueError
            A setting out of range (named), or dt given with rtol/atol.
        """
        name = DEFAULT_METHOD if method is None else method
        if not isinstance(name, str) or name not in METHODS:
            raise ValueError(f"method must be one of {sorted(METHODS)}, got {method!r}")
        m = METHODS[name]
        if dt is not None:
            dt = finite_number("dt", dt)
            if dt <= 0:
                raise ValueError(f"dt must be > 0 seconds, got {dt}")
            if rtol is not None or atol is not None:
                raise ValueError("give either dt (fixed step) or rtol/atol (adaptive), not both")
        elif not m.adaptive:
            if rtol is not None:
                raise ValueError(f"method {name!r} has no error estimate: give dt, not rtol")
            dt = DEFAULT_FIXED_DT
        rtol_v = DEFAULT_RTOL if rtol is None else check_rtol(rtol)
        atol_v = rtol_v if atol is None else finite_number("atol", atol)
        if not 0 < atol_v < 1:
            raise ValueError(f"atol must satisfy 0 < atol < 1 (relative to the saddle size), "
                             f"got {atol_v}")
        if isinstance(events, str):
            events = (events,)
        if not isinstance(events, (tuple, list, set, frozenset)):
            raise ValueError(f"events must be a sequence drawn from {sorted(EVENT_NAMES)}, "
                             f"got {events!r}")
        mask = 0
        for e in events:
            if e not in EVENT_NAMES:
                raise ValueError(f"events must be a subset of {sorted(EVENT_NAMES)}, got {e!r}")
            mask |= EVENT_NAMES[e]
        if max_step is not None:
            max_step = finite_number("max_step", max_step)
            if max_step <= 0:
                raise ValueError(f"max_step must be > 0 seconds, got {max_step}")
        if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) \
                or max_steps < 1:
            raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")
        return cls(m, 0.0 if dt is None else float(dt), rtol_v, atol_v, mask, max_step,
                   int(max_steps))

    def max_step_for(self, profile: OmegaProfile, t_end: float) -> float:
        """Largest step: the user's; else, for adaptive steps, half the half-turn period
        π/|Ω| (N oscillates at 2Ω; the stage points sample it about ten times per step, so a
        dip is not stepped over). A fixed step ``dt`` is taken as given."""
        if self.max_step is not None:
            return self.max_step
        if self.dt > 0:
            return math.inf
        return default_max_step(profile.bound(t_end))

    def control(self, max_step: float) -> StepControl:
        """The compiled loop's record of these settings.

        Parameters
        ----------
        max_step : float
            Largest step [s] (from `max_step_for`).

        Returns
        -------
        StepControl
        """
        return step_control(self.dt, self.rtol, self.atol, max_step, self.events,
                            self.max_steps)

    def describe(self) -> str:
        """The settings in one line (a `Trajectory`'s ``settings``)."""
        if self.dt > 0:
            return f"{self.method.name} (order {self.method.order}), fixed dt = {self.dt:g} s"
        return (f"{self.method.name} (order {self.method.order}), adaptive, "
                f"rtol = {self.rtol:g}, atol = {self.atol:g}")


def default_max_step(omega_bound: float) -> float:
    """Default largest adaptive step [s] for saddle speeds up to ``omega_bound`` [rad/s]:
    π/(2Ω), or inf when the saddle does not turn."""
    return math.pi / (2.0 * omega_bound) if omega_bound > 0 else math.inf


def output_times(t_end: float, dt_out: float | None) -> np.ndarray:
    """A run's output times, its end and spacing checked.

    Parameters
    ----------
    t_end : float
        Final time [s], > 0.
    dt_out : float or None
        Output spacing [s], > 0, at most MAX_OUTPUTS outputs; None: only 0 and ``t_end``.

    Returns
    -------
    ndarray
        The multiples of ``dt_out`` up to ``t_end``, and ``t_end`` when it is not one.

    Raises
    ------
    ValueError
        A time that is not a finite positive number, or too many outputs.
    """
    t_end = finite_number("t_end", t_end)
    if t_end <= 0:
        raise ValueError(f"t_end must be > 0 seconds, got {t_end}")
    if dt_out is None:
        return np.array([0.0, t_end])
    dt_out = finite_number("dt_out", dt_out)
    if dt_out <= 0:
        raise ValueError(f"dt_out must be > 0 seconds, got {dt_out}")
    ratio = t_end / dt_out * (1 + 1e-12)
    if not ratio < MAX_OUTPUTS:  # also catches inf from a huge t_end or a denormal dt_out
        raise ValueError(f"dt_out = {dt_out:g} s gives {ratio:.3g} outputs over t_end = "
                         f"{t_end:g} s; at most {MAX_OUTPUTS} are allowed")
    n = int(math.floor(ratio)) + 1
    # Multiples of dt_out (not a cumulative sum) so the grid carries no rounding drift.
    grid = np.arange(n) * dt_out
    if t_end - grid[-1] > 1e-12 * t_end:  # t_end off the grid: its state is an output too
        grid = np.append(grid, t_end)
    return grid


def check_rtol(rtol: object) -> float:
    """A relative tolerance of the adaptive integrators, checked.

    The one check of ``rtol`` for the simulator and the environment's config.

    Parameters
    ----------
    rtol : float
        A finite number in [1e-15, 1) (below 1e-15 the error estimate is rounding noise).

    Returns
    -------
    float

    Raises
    ------
    ValueError
        Out of range or not a finite number.
    """
    r = finite_number("rtol", rtol)
    if not RTOL_MIN <= r < 1:
        raise ValueError(f"rtol must satisfy {RTOL_MIN:g} <= rtol < 1, got {r}")
    return r


def check_fixed_step_fits(dt: float, dt_out: float | None) -> None:
    """Check that a fixed step fits the output spacing.

    A step larger than the spacing would be cut to it (the loop lands on every output): say
    so rather than run with a step other than the one asked for.

    Parameters
    ----------
    dt : float
        The fixed step [s].
    dt_out : float or None
        The output spacing [s] (None: outputs at 0 and the end only).

    Raises
    ------
    ValueError
        ``dt`` > ``dt_out``.
    """
    if dt_out is not None and dt > dt_out * (1 + 1e-9):
        raise ValueError(f"dt = {dt:g} s is larger than dt_out = {dt_out:g} s: the integrator "
                         "lands on every output, so the step would be cut to dt_out; give "
                         "dt <= dt_out or a larger dt_out")


# --------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Event:
    """Why a run stopped early: ``kind`` is "detach" (N fell below 0) or "escape" (left the rim)."""

    kind: str
    t: float
    state: np.ndarray

    def as_dict(self) -> dict[str, object]:
        """The fields as JSON-ready values."""
        return {"kind": self.kind, "t": self.t}


@dataclass(frozen=True)
class Transition:
    """A coulomb ball's change of phase at time ``t`` [s] to ``phase`` ("stick" or "slip")."""

    t: float
    phase: str

    def as_dict(self) -> dict[str, object]:
        """The fields as JSON-ready values."""
        return {"t": self.t, "phase": self.phase}


@dataclass(frozen=True)
class Stats:
    """The integrator's work on one run: accepted steps, rejected steps and right-hand-side
    evaluations."""

    steps: int
    rejected: int
    rhs_evaluations: int


@dataclass
class Trajectory:
    """One ball's run, sampled at the output times reached before any event.

    Derived quantities (velocity, normal force, Jacobi integral, centre, laboratory
    coordinates) are computed on first access from the shared kernels.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Output times [s].
    state : ndarray, shape (n, state_size)
        States (see `initial_state`).
    event : Event or None
        The event that stopped the run, if one did.
    settings : str
        The integrator used.
    stats : Stats
        The integrator's counts.
    work : ndarray, shape (n,)
        Work per unit mass [J/kg] done by the dissipative forces (air drag, drilling
        friction) since t = 0, integrated with the state; zeros when the scene has none.
        At constant Ω and with no lab-fixed force, ``h - h[0] == work``.
    phase : ndarray, shape (n,), or None
        Coulomb: 0 where the ball sticks (rolls), 1 where it slips; None otherwise.
    transitions : list of Transition
        Coulomb: every change of phase after t = 0, at its located time (``phase[0]`` is
        the starting phase); ``transitions_total`` counts them all when more than
        TRANSITION_LOG_ROWS happened.
    """

    scene: Scene
    omega: OmegaProfile
    t: np.ndarray
    state: np.ndarray
    event: Event | None
    settings: str
    stats: Stats
    force: tuple[float, float] = (0.0, 0.0)
    work: np.ndarray | None = None
    phase: np.ndarray | None = None
    transitions: list[Transition] = field(default_factory=list)
    transitions_total: int = 0
    _obs: np.ndarray | None = field(default=None, repr=False)
    _obs_has_normal: bool = field(default=False, repr=False)

    def __post_init__(self) -> None:
        if self.work is None:
            self.work = np.zeros(len(self.t))

    def _observables(self, want_normal: bool) -> np.ndarray:
        if self._obs is None or (want_normal and not self._obs_has_normal):
            padded = np.zeros((len(self.t), K.STATE_WIDTH))
            padded[:, : self.scene.state_size] = self.state
            if self.phase is not None:
                padded[:, K.PHASE_SLOT] = self.phase
            out = np.empty((len(self.t), K.OBS_WIDTH))
            K.observables(self.scene.model_code, self.scene.params(),
                          drive_row(self.omega, self.force), self.t, padded, want_normal, out)
            self._obs, self._obs_has_normal = out, want_normal
        return self._obs

    @property
    def x(self) -> np.ndarray:
        """Contact point's x [m] at each output, rotating frame."""
        return self.state[:, 0]

    @property
    def y(self) -> np.ndarray:
        """Contact point's y [m] at each output, rotating frame."""
        return self.state[:, 1]

    @property
    def vx(self) -> np.ndarray:
        """Contact point's velocity along x [m/s] relative to the saddle."""
        return self._observables(False)[:, K.OBS_VX]

    @property
    def vy(self) -> np.ndarray:
        """Contact point's velocity along y [m/s] relative to the saddle."""
        return self._observables(False)[:, K.OBS_VY]

    @property
    def r(self) -> np.ndarray:
        """Distance of the contact point from the axis [m]."""
        return np.hypot(self.x, self.y)

    @property
    def N_over_mg(self) -> np.ndarray:
        """Normal force in units of the ball's weight (computed on first access)."""
        g = self.scene.g
        n = self._observables(True)[:, K.OBS_N]
        return n / g if g > 0 else n

    @property
    def h(self) -> np.ndarray:
        """Jacobi integral per unit mass [J/kg]; conserved when Ω is constant."""
        return self._observables(False)[:, K.OBS_H]

    @property
    def centre(self) -> np.ndarray:
        """Ball centre (n, 3) [m], rotating frame."""
        return self._observables(False)[:, K.OBS_CX:K.OBS_CZ + 1]

    @property
    def theta(self) -> np.ndarray:
        """Saddle angle θ(t) [rad]."""
        return np.asarray(self.omega.angle(self.t))

    def lab_xy(self, of: Literal["contact", "centre"] = "contact") -> np.ndarray:
        """Horizontal position (n, 2) [m] in the laboratory frame (saddle axes at t = 0)."""
        if of == "contact":
            px, py = self.x, self.y
        elif of == "centre":
            px, py = self.centre[:, 0], self.centre[:, 1]
        else:
            raise ValueError(f"of must be 'contact' or 'centre', got {of!r}")
        c, s = np.cos(self.theta), np.sin(self.theta)
        return np.column_stack([c * px - s * py, s * px + c * py])

    def as_dict(self) -> dict[str, object]:
        """The columns of `saddle-sim --format json`."""
        out = {"t": self.t.tolist(), "x": self.x.tolist(), "y": self.y.tolist(),
               "vx": self.vx.tolist(), "vy": self.vy.tolist(),
               "N_over_mg": self.N_over_mg.tolist(), "h": self.h.tolist(),
               "event": None if self.event is None else self.event.as_dict()}
        if self.phase is not None:
            assert self.work is not None  # __post_init__ fills work (zeros when there is none)
            out["phase"] = [PHASE_NAMES[float(p)] for p in self.phase]
            out["transitions"] = [tr.as_dict() for tr in self.transitions]
            out["work"] = self.work.tolist()
        return out


# --------------------------------------------------------------------------------------
# A run's inputs, checked once
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunInputs:
    """One ball's run with its inputs checked (`check_run`): the scene, the padded state
    (`check_state`), the Ω profile, the lab-fixed force and the output times."""

    scene: Scene
    state: np.ndarray
    omega: OmegaProfile
    force: tuple[float, float]
    t_out: np.ndarray


def check_run(scene: Scene, state: object, t_end: float, omega: object = 20.0,
              dt_out: float | None = 0.01,
              force: object = (0.0, 0.0)) -> RunInputs:
    """Check one ball's run inputs, once for a call of `simulate` or `run`.

    Parameters
    ----------
    scene, state, t_end, omega, dt_out, force
        As in `saddle_env.simulate.simulate`.

    Returns
    -------
    RunInputs

    Raises
    ------
    ValueError
        The first input out of range, named (the scene, the state, Ω, the force, then the
        times).
    """
    if not isinstance(scene, Scene):
        raise ValueError(f"scene must be a saddle_env.Scene, got {type(scene).__name__}")
    y = check_state(scene, state)
    profile = OmegaProfile.coerce(omega)
    return RunInputs(scene, y, profile, check_force(force), output_times(t_end, dt_out))


@dataclass(frozen=True)
class BatchInputs:
    """Many balls' run with its inputs checked (`check_batch`): a scene per ball, the
    padded states (n, STATE_WIDTH), the Ω profile rows (n, 5), the lab-fixed force, the
    saddle's angles at t = 0 (n,) and the common output times."""

    scenes: list[Scene]
    states: np.ndarray
    omegas: np.ndarray
    force: tuple[float, float]
    angles: np.ndarray
    t_out: np.ndarray


def check_batch(scenes: object, states: object, t_end: float, omega: object = 20.0,
                dt_out: float | None = 0.01, force: object = (0.0, 0.0),
                angle: object = 0.0) -> BatchInputs:
    """Check a batch's run inputs, once for a call of `simulate_batch` or `run_batch`.

    Parameters
    ----------
    scenes, states, t_end, omega, dt_out, force
        As in `saddle_env.simulate.simulate_batch`.
    angle : float or ndarray
        As in `run_batch`.

    Returns
    -------
    BatchInputs

    Raises
    ------
    ValueError
        The first input out of range, named.
    """
    try:
        rows = np.asarray(states, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("states must be a real array of shape (n, state_size)") from None
    if rows.ndim != 2 or rows.shape[0] < 1:
        raise ValueError(f"states must have shape (n, state_size), got {rows.shape}")
    n = rows.shape[0]
    if isinstance(scenes, Scene):
        scene_list = [scenes] * n
    elif isinstance(scenes, (list, tuple)):
        scene_list = list(scenes)
    else:
        raise ValueError(f"scenes must be a Scene or a sequence of {n} Scenes, "
                         f"got {type(scenes).__name__}")
    if len(scene_list) != n or not all(isinstance(s, Scene) for s in scene_list):
        raise ValueError(f"scenes must be a Scene or a sequence of {n} Scenes (one per ball)")
    Y = np.zeros((n, K.STATE_WIDTH))
    sc, d = scene_list[0], scene_list[0].state_size
    if isinstance(scenes, Scene) and d <= rows.shape[1] <= K.DYNAMICS_WIDTH:
        # one scene: the rows checked at once (a Python loop per row cost thousands of calls)
        if not (ok := np.isfinite(rows[:, :d]).all(axis=1)).all():
            check_state(sc, rows[int(np.argmin(ok)), :d], f"states[{int(np.argmin(ok))}]")
        Y[:, :d], Y[:, K.PHASE_SLOT] = rows[:, :d], starting_phase(sc)
    else:
        for i, (sc, row) in enumerate(zip(scene_list, rows)):
            if sc.state_size < rows.shape[1] <= K.DYNAMICS_WIDTH:  # a padded row
                row = row[: sc.state_size]
            Y[i] = check_state(sc, row, f"states[{i}]")
    profiles = omega_rows(omega, n)
    force = check_force(force)
    angles = check_angles(angle, n)
    return BatchInputs(scene_list, Y, profiles, force, angles, output_times(t_end, dt_out))


# --------------------------------------------------------------------------------------
# Runs
# --------------------------------------------------------------------------------------
def run(scene: Scene, state: np.ndarray, t_end: float, *,
             omega: float | OmegaProfile | Sequence[float] = 20.0, dt_out: float | None = 0.01,
             method: str | None = None, rtol: float | None = None, atol: float | None = None,
             dt: float | None = None, events: Sequence[str] = DEFAULT_EVENTS,
             max_step: float | None = None, max_steps: int = 50_000_000,
             force: tuple[float, float] = (0.0, 0.0)) -> Trajectory:
    """Integrate one ball from t = 0 to ``t_end`` with the given integrator settings.

    `check_run`, `Settings.build`, then `run_checked`: `saddle_env.simulate.simulate`
    without ``tol=`` and without its checks of a fixed step, with its parameters, result
    (`Trajectory`) and errors (ValueError, SimulationError).
    """
    return run_checked(check_run(scene, state, t_end, omega, dt_out, force),
                       Settings.build(method, rtol, atol, dt, events, max_step, max_steps))


def run_checked(inputs: RunInputs, settings: Settings) -> Trajectory:
    """Run one ball whose inputs (`check_run`) and settings (`Settings.build`) are checked;
    returns its `Trajectory`, or raises SimulationError when the integration failed
    (non-finite state, step-size underflow, step limit)."""
    scene, profile, force, t_out = inputs.scene, inputs.omega, inputs.force, inputs.t_out
    y = inputs.state.copy()
    p = scene.params()
    tab = settings.method.tableau
    Y_out = np.empty((len(t_out), K.STATE_WIDTH))
    stats = np.zeros(4, dtype=np.int64)
    coulomb = scene.contact == "coulomb"
    work = workspace(tab, TRANSITION_LOG_ROWS if coulomb else 0)
    # compiled for this scene's contact model alone (`compilation.specialise`)
    args = (scene.model_code, p, drive_row(profile, force), y, 0.0, t_out, tab,
            settings.control(settings.max_step_for(profile, float(t_out[-1]))),
            state_scale(p, scene.model_code), Y_out, stats, 0.0, work)
    status, t_final = integrator_loop(scene.model_code, p[P_RESIST] != 0.0, args)(*args)[:2]
    _raise_on_failure(status, t_final, math.hypot(y[0], y[1]), scene)
    total, rows = transition_log(tab, work) if coulomb else (0, work[:0])
    n = int(stats[3])
    event = None
    if status in EVENT_KINDS:
        event = Event(EVENT_KINDS[status], float(t_final), y[: scene.state_size].copy())
    return Trajectory(scene, profile, t_out[:n].copy(), Y_out[:n, : scene.state_size].copy(),
                      event, settings.describe(),
                      Stats(int(stats[0]), int(stats[1]), int(stats[2])), force,
                      Y_out[:n, scene.state_size].copy(),
                      # users see slip starting (ONSET) as slip
                      np.minimum(Y_out[:n, K.PHASE_SLOT], K.SLIP) if coulomb else None,
                      [Transition(float(r[LOG_T]), PHASE_NAMES[float(r[LOG_PHASE])])
                       for r in rows[:min(total, len(rows))]], total)


def _raise_on_failure(status: int, t_final: float, r: float, scene: Scene) -> None:
    assert scene.b is not None  # Scene.__post_init__ sets b (None means b = a)
    if status in (STATUS_FAILED, STATUS_MAX_STEPS) and not r < 10 * max(scene.a, scene.b):
        raise SimulationError(
            f"integration stopped at t = {t_final:.9g} s with the ball {r:.3g} m from the axis: "
            "it has left the saddle and runs away; give the scene a finite rim_radius and "
            "keep the 'escape' event on")
    if status == STATUS_FAILED:
        raise SimulationError(
            f"integration failed at t = {t_final:.9g} s: the state became non-finite or the "
            "step size underflowed (a fixed step too large for this scene, or the ball left "
            "the saddle with no rim to stop it)")
    if status == STATUS_MAX_STEPS:
        raise SimulationError(f"integration stopped at t = {t_final:.9g} s after max_steps "
                              "steps; raise max_steps or loosen rtol")


@dataclass
class BatchResult:
    """Many balls' runs on a common output grid.

    Attributes
    ----------
    t : ndarray, shape (m,)
        Output times [s].
    state : ndarray, shape (n, m, k)
        States padded to k = 5 (7 when the batch has a coulomb ball); rows after a ball's
        last output, and a ball's slots past its own state (a rolling ball's in a batch
        padded to 7), are NaN.
    n_out : ndarray, shape (n,)
        Outputs reached per ball.
    status : ndarray, shape (n,)
        STATUS_* codes.
    t_final : ndarray, shape (n,)
        Time of each final state [s] (the event's time where one fired).
    final_state : ndarray, shape (n, k)
        State at ``t_final``, padded as ``state``.
    stats : ndarray, shape (n, 4)
        The integrator's counts per ball.
    settings : str
        The integrator used.
    work : ndarray, shape (n, m)
        Work of the dissipative forces per unit mass [J/kg] since t = 0
        (`Trajectory.work`), NaN after a ball's last output.
    """

    t: np.ndarray
    state: np.ndarray
    n_out: np.ndarray
    status: np.ndarray
    t_final: np.ndarray
    final_state: np.ndarray
    stats: np.ndarray
    settings: str = ""
    work: np.ndarray | None = None

    def event(self, i: int) -> str | None:
        """Ball ``i``'s event ("detach" or "escape"), or None if none stopped it."""
        return EVENT_KINDS.get(int(self.status[i]))


def run_batch(scenes: Scene | Sequence[Scene], states: np.ndarray, t_end: float, *,
                   omega: float | OmegaProfile | Sequence[float | OmegaProfile] | np.ndarray = 20.0,
                   dt_out: float | None = 0.01, method: str | None = None,
                   rtol: float | None = None, atol: float | None = None,
                   dt: float | None = None, events: Sequence[str] = DEFAULT_EVENTS,
                   max_step: float | None = None, max_steps: int = 50_000_000,
                   force: tuple[float, float] = (0.0, 0.0),
                   angle: float | np.ndarray = 0.0) -> BatchResult:
    """Integrate many balls at once (threads over balls; same kernel as `run`), with the
    given integrator settings (``tol=`` is `saddle_env.simulate.simulate_batch`'s).

    Parameters
    ----------
    scenes, states, t_end, omega, dt_out, method, rtol, atol, dt, events, max_step, max_steps, force
        As in `saddle_env.simulate.simulate_batch`.
    angle : float or ndarray, shape (n,)
        The saddle's angle [rad] at t = 0 from the laboratory's x axis, one for all balls or
        one each: where the saddle points when each ball is released, which matters only
        when something is fixed in the laboratory (``force``, a scene's ``tilt``).

    Returns
    -------
    BatchResult
        Failures do not raise; they are reported per ball in ``status`` (bad input raises
        ValueError).
    """
    return run_batch_checked(check_batch(scenes, states, t_end, omega, dt_out, force, angle),
                             Settings.build(method, rtol, atol, dt, events, max_step, max_steps))


def run_batch_checked(inputs: BatchInputs, settings: Settings,
                      shared_steps: bool = False) -> BatchResult:
    """Run a batch whose inputs (`check_batch`) and settings (`Settings.build`) are checked;
    failures do not raise, they are reported per ball in the `BatchResult`'s ``status``.
    ``shared_steps``: blocks of balls share their steps (`saddle_env.blockstep`), else each
    ball steps alone (`integrators.integrate_batch`)."""
    scene_list, profiles, t_out = inputs.scenes, inputs.omegas, inputs.t_out
    n = len(scene_list)
    Y = inputs.states.copy()
    # each distinct scene and Ω profile packed once (per ball, this cost more than
    # integrating 1024 balls for 2 s at rtol 1e-7)
    rows = [(*row, theta0) for row, theta0 in zip(profiles.tolist(), inputs.angles.tolist())]
    drives = np.array(_per_distinct(rows, lambda r: drive_row(OmegaProfile(*r[:5]),
                                                              inputs.force, r[5])))
    P = np.array(_per_distinct(scene_list, Scene.params))
    models = np.array([sc.model_code for sc in scene_list], dtype=np.int64)
    scales = np.array(_per_distinct(scene_list, lambda s: state_scale(s.params(), s.model_code)))
    max_step_arr = np.array(_per_distinct(rows, lambda r: settings.max_step_for(
        OmegaProfile(*r[:5]), float(t_out[-1]))))
    m = settings.method
    Y_out = np.full((n, len(t_out), K.STATE_WIDTH), np.nan)
    status = np.zeros(n, dtype=np.int64)
    t_final = np.zeros(n)
    stats = np.zeros((n, 4), dtype=np.int64)
    # Each ball's own largest step replaces the record's (integrate_batch).
    args = (models, P, drives, Y, 0.0, t_out, m.tableau, settings.control(math.inf), scales,
            max_step_arr, np.ones(n, dtype=bool), Y_out, status, t_final, stats)
    # compiled for these balls' contact models alone, as `simulate` is for its one
    module, name = ((blockstep, "integrate_batch_shared") if shared_steps
                    else (integrators, "integrate_batch"))
    batch = entry(np.unique(models), bool((P[:, P_RESIST] != 0.0).any()), module, name,
                  (0, n, *args))
    in_threads(batch, n, *args, simulated_s=n * float(t_out[-1]))
    work = np.array([Y_out[i, :, sc.state_size] for i, sc in enumerate(scene_list)])
    width = padded_width(models)
    state, final = Y_out[..., :width], Y[:, :width].copy()
    # a narrower ball's slots past its own state hold the kernel's work and scratch
    padding = np.arange(width) >= np.array([sc.state_size for sc in scene_list])[:, None]
    state[np.broadcast_to(padding[:, None, :], state.shape)] = np.nan
    final[padding] = np.nan
    return BatchResult(t_out, state, stats[:, 3].copy(), status, t_final, final, stats,
                       settings.describe(), work)


def _per_distinct(keys: Sequence, make) -> list:
    """``[make(k) for k in keys]``, ``make`` called once per distinct key (tuples by value,
    anything else, such as a Scene, by identity)."""
    made: dict = {}
    return [made[t] if (t := k if isinstance(k, tuple) else id(k)) in made
            else made.setdefault(t, make(k)) for k in keys]


def check_angles(angle: object, n: int) -> np.ndarray:
    """The saddle's angle at t = 0 [rad] for each of n balls, checked: a finite number for
    all, or an (n,) array of finite angles. Returns an (n,) float array."""
    if isinstance(angle, np.ndarray) and angle.ndim >= 1:
        if angle.shape != (n,) or not np.issubdtype(angle.dtype, np.number) \
                or not np.all(np.isfinite(angle)):
            raise ValueError(f"angle must be a finite number or an array of shape ({n},) of "
                             f"finite angles [rad], got an array of shape {angle.shape}")
        return angle.astype(float)
    return np.full(n, finite_number("angle", angle))
