"""Automatic accuracy: ask for a position error, get the cheapest integrator that meets it.

``simulate(..., tol=1e-6)`` (and ``simulate_batch``) call `choose`, which picks a method and
a tolerance or step for *this* scene, speed profile and horizon. This module sits between the
runs it pilots (`saddle_env.runner`) and the public entry points (`saddle_env.simulate`),
which resolve ``tol=`` with it:

1. **Candidates.** Three families, each ordered from cheap to expensive: ``dop853`` and
   ``dopri5`` at rtol = 1e-4 … 1e-13, ``rk4`` at fixed steps ``h0/k``. ``h0`` is
   π/(8·max(|Ω|, ω₀)), ω₀ = sqrt(2g/a), and at most the simulator's default step cap. While the
   detachment event is on, every candidate respects that cap, so a brief dip of the normal
   force is not stepped over (the event is checked at step ends); without it, the adaptive
   families run uncapped. The work-precision benchmark (``saddle-bench``, docs/accuracy.md)
   shows which family wins where: rk4 at the cap for millimetres, dopri5 around 1e-5 m,
   dop853 below.
2. **Pilot.** Every candidate is run over a pilot window (the first 10 % of the run, at
   most 100 s, but at least one second and four saddle turns, and never beyond the run) and compared
   with a DOP853 solve at rtol = 1e-13, on the run's own output grid; the measured error is
   extrapolated to the full run as e ∝ t^p with p measured from the pilot's two halves
   (at least 1: the error of a trapped orbit is mostly phase error, which grows linearly;
   at most 3) and must come out below ``tol / SAFETY``. Within a family the first passing
   candidate is the cheapest; a family stops once it costs more right-hand-side
   evaluations than the best pick so far.
3. **Pick.** The passing candidate with the fewest right-hand-side evaluations in the pilot.

`Choice.describe()` says what was picked and why; the Trajectory's ``settings`` string
carries it. On a 10-s run the pilot costs a few times the run it calibrates (its measured
cost is on docs/accuracy.md; long runs amortise it, since the pilot is at most 100 s long),
so `tol` is for "how accurate is this and what does it cost", not for the inner loop of
training: pick once with `choose`, then pass the chosen method/rtol/dt explicitly.
"""

from __future__ import annotations

import contextvars
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, TypedDict

import numpy as np

from . import kernels as K
from .omega import OmegaProfile, drive_row
from .runner import RunInputs, Settings, check_run, output_times, run, run_checked
from .scene import Scene, finite_number

if TYPE_CHECKING:
    from typing_extensions import Unpack  # typing.Unpack from Python 3.11

SAFETY = 2.0                     # predicted error must be below tol / SAFETY
PILOT_FRACTION = 0.1
PILOT_MIN_S = 1.0
PILOT_MIN_TURNS = 4
PILOT_MAX_S = 100.0              # longer runs extrapolate further (and need more margin)
REFERENCE_RTOL = 1e-13
TOL_FLOOR = 1e-11                # [m] below this the reference itself cannot vouch for it
TOL_CEIL = 1.0                   # [m]
ADAPTIVE_RTOLS = tuple(10.0 ** -k for k in range(4, 14))
RK4_DIVISORS = (1, 2, 4, 8, 16, 32)
MAX_STEPS = 50_000_000           # the pilots' step limit (`simulate`'s default)


class IntegratorKwargs(TypedDict, total=False):
    """The integrator's keywords of `simulate` and `runner.run`: a candidate or a pick."""

    method: str
    rtol: float | None
    atol: float | None
    dt: float
    max_step: float


@dataclass(frozen=True)
class Choice:
    """An integrator setting picked by `choose` (pass ``kwargs()`` to `simulate`)."""

    method: str
    rtol: float | None
    dt: float | None
    max_step: float | None
    tol: float
    predicted_error: float
    pilot_t: float
    t_end: float
    candidates_tried: int
    pilot_rhs_evaluations: int

    def kwargs(self) -> IntegratorKwargs:
        """The pick as `simulate`'s keywords (method and rtol or dt, and max_step if set)."""
        out: IntegratorKwargs = {"method": self.method}
        if self.dt is not None:
            out["dt"] = self.dt
        else:
            out["rtol"] = self.rtol
        if self.max_step is not None:
            out["max_step"] = self.max_step
        return out

    def describe(self) -> str:
        """What was picked and why, in one line (a `Trajectory`'s ``settings``)."""
        what = (f"{self.method} fixed dt = {self.dt:.4g} s" if self.dt is not None
                else f"{self.method} rtol = {self.rtol:g}"
                + ("" if self.max_step is None else f", max_step = {self.max_step:g} s"))
        return (f"auto (tol = {self.tol:g} m): picked {what}; pilot over {self.pilot_t:.3g} s "
                f"of {self.t_end:.3g} s predicts {self.predicted_error:.2g} m "
                f"({self.candidates_tried} candidates tried)")


def check_tol(tol: object) -> float:
    """The position error asked for, checked.

    Parameters
    ----------
    tol : float
        Largest position error [m] over the run, in [TOL_FLOOR, TOL_CEIL].

    Returns
    -------
    float

    Raises
    ------
    ValueError
        Not a finite number in that range.
    """
    tol = finite_number("tol", tol)
    if not TOL_FLOOR <= tol <= TOL_CEIL:
        raise ValueError(f"tol must satisfy {TOL_FLOOR:g} <= tol <= {TOL_CEIL:g} metres (the "
                         f"largest position error allowed over the run), got {tol:g}")
    return tol


def _base_step(scene: Scene, profile: OmegaProfile, t_end: float) -> float:
    """Largest fixed step tried: π/(8·max(|Ω|, ω₀)), and never above the simulator's
    default adaptive step cap (which keeps the detachment event from being stepped over)."""
    omega0 = math.sqrt(2.0 * scene.g / scene.a) if scene.g > 0 else 0.0
    rate = max(profile.bound(t_end), omega0)
    h0 = math.pi / (8.0 * rate) if rate > 0 else t_end / 64.0
    cap = Settings.build(None, None, None, None, (), None, 1).max_step_for(profile, t_end)
    return min(h0, cap, t_end)


def _families(h0: float, t_end: float, detach: bool) -> list[list[IntegratorKwargs]]:
    """Candidate families, each cheap to dear; dop853 first (it wins most often on the
    benchmark's diagram, so its pick prunes the other families early)."""
    cap = None if detach else max(t_end, h0)
    out = []
    for m in ("dop853", "dopri5"):
        fam = []
        for r in ADAPTIVE_RTOLS:
            if m == "dopri5" and r < 1e-10:
                continue
            kw: IntegratorKwargs = {"method": m, "rtol": r}
            if cap is not None:
                kw["max_step"] = cap
            fam.append(kw)
        out.append(fam)
    out.append([{"method": "rk4", "dt": h0 / k} for k in RK4_DIVISORS])
    return out


def _pilot_window(profile: OmegaProfile, t_end: float) -> float:
    turns = 2.0 * math.pi * PILOT_MIN_TURNS / profile.bound(t_end) if profile.bound(t_end) > 0 \
        else 0.0
    return min(t_end, max(min(PILOT_FRACTION * t_end, PILOT_MAX_S), PILOT_MIN_S, turns))


def _extrapolate(e_half: float, e_full: float, ratio: float) -> float:
    """Error over the run from the pilot's first half and whole: e ∝ t^p, with p measured
    from the two and kept in [1, 3] (1: phase error of a trapped orbit)."""
    if ratio <= 1.0 or not math.isfinite(e_full):
        return e_full
    if e_full <= 0.0:
        return 0.0
    p = 3.0 if e_half <= 0.0 else min(3.0, max(1.0, math.log2(e_full / e_half)))
    try:
        return e_full * ratio ** p
    except OverflowError:
        return math.inf


def _positions(tr) -> tuple[np.ndarray, object]:
    xy = np.column_stack([tr.x, tr.y])
    if tr.event is not None:
        xy = np.vstack([xy, tr.event.state[:2]])
    return xy, None if tr.event is None else tr.event.kind


def choose(scenes: Scene | Sequence[Scene], states: Sequence[np.ndarray], t_end: float,
           tol: float, *, omegas: Sequence[OmegaProfile], dt_out: float | None = None,
           events: Sequence[str] = ("detach", "escape"),
           force: tuple[float, float] = (0.0, 0.0)) -> Choice:
    """Cheapest setting that keeps every given ball within ``tol`` metres of the exact
    trajectory (contact-point position, maximum over the run). See the module docstring.

    Parameters
    ----------
    scenes : Scene or sequence of Scene
        One scene for all balls or one per ball.
    states : sequence of ndarray
        The balls' starting states (each of its scene's ``state_size``); a batch passes a
        few representatives, and the pick must pass for all of them.
    t_end : float
        The run's length [s] (the pilot covers its start and extrapolates).
    tol : float
        Largest position error [m] allowed over the run (`check_tol`).
    omegas : sequence of OmegaProfile
        Each ball's Ω profile.
    dt_out : float or None
        The run's output spacing [s] (the pilot lands on it, as the run will).
    events : subset of ("detach", "escape")
        The run's events.
    force : (fx, fy)
        The run's lab-fixed force per unit mass [m/s²].

    Returns
    -------
    Choice
        The pick; ``kwargs()`` gives `simulate`'s keywords for it.

    Raises
    ------
    ValueError
        ``tol`` or ``t_end`` out of range, or no candidate reaches ``tol``.
    """
    t_end = finite_number("t_end", t_end)
    if t_end <= 0:
        raise ValueError(f"t_end must be > 0 seconds, got {t_end}")
    scene_list = [scenes] * len(states) if isinstance(scenes, Scene) else list(scenes)
    balls = [check_run(sc, s0, t_end, om, None, force)
             for sc, s0, om in zip(scene_list, states, omegas)]
    return choose_for(balls, tol, dt_out, events)


def choose_for(balls: Sequence[RunInputs], tol: float, dt_out: float | None,
               events: Sequence[str]) -> Choice:
    """`choose` for balls whose inputs are checked (`runner.check_run`), as
    `saddle_env.simulate` has them: nothing is checked again.

    Parameters
    ----------
    balls : sequence of RunInputs
        The balls; their last output time is the run's end.
    tol : float
        Largest position error [m] allowed over the run (checked: `check_tol`).
    dt_out : float or None
        The run's output spacing [s].
    events : subset of ("detach", "escape")
        The run's events.

    Returns
    -------
    Choice
    """
    token = _INTERNAL.set(True)  # candidates that are too coarse are expected here
    try:
        return _choose(balls, check_tol(tol), dt_out, events)
    finally:
        _INTERNAL.reset(token)


def _choose(balls: Sequence[RunInputs], tol: float, dt_out: float | None,
            events: Sequence[str]) -> Choice:
    t_end = float(balls[0].t_out[-1])
    detach = "detach" in (events if not isinstance(events, str) else (events,))
    t_p = min(_pilot_window(b.omega, t_end) for b in balls)
    # The pilot lands on the run's own output grid (landing changes the steps), or on t_p/2.
    out_dt = dt_out if dt_out is not None and t_p / 2000 <= dt_out <= t_p / 2 else t_p / 2
    pilots = [replace(b, t_out=output_times(t_p, out_dt)) for b in balls]
    reference = Settings.build("dop853", REFERENCE_RTOL, None, None, events, None, MAX_STEPS)
    refs = [_positions(run_checked(b, reference)) for b in pilots]
    h0 = min(_base_step(b.scene, b.omega, t_end) for b in balls)
    fams = _families(h0, t_end, detach)
    best: tuple[int, IntegratorKwargs, float] | None = None
    tried = 0
    total_evals = 0
    for fam in fams:
        for kw in fam:
            if best is not None and "dt" in kw and 4 * len(balls) * t_p / kw["dt"] >= best[0]:
                break  # a fixed-step candidate's cost is known in advance: dearer than the pick
            evals = 0
            worst = 0.0
            worst_half = 0.0
            for b, pilot in enumerate(pilots):
                try:
                    tr = run_checked(pilot, Settings.build(
                        kw.get("method"), kw.get("rtol"), kw.get("atol"), kw.get("dt"), events,
                        kw.get("max_step"), MAX_STEPS))
                except Exception:  # noqa: BLE001 — a failed candidate simply does not pass
                    worst = math.inf
                    break
                evals += tr.stats.rhs_evaluations
                xy, kind = _positions(tr)
                ref_xy, ref_kind = refs[b]
                if kind != ref_kind or xy.shape != ref_xy.shape:
                    worst = math.inf
                    break
                dist = np.hypot(*(xy - ref_xy).T)
                worst = max(worst, float(np.max(dist)))
                half = len(dist) // 2 + 1
                worst_half = max(worst_half, float(np.max(dist[:half])))
            tried += 1
            total_evals += evals
            predicted = _extrapolate(worst_half, worst, t_end / t_p)
            if best is not None and evals >= best[0]:
                break  # this family is already dearer than the best pick
            if predicted <= tol / SAFETY:
                best = (evals, kw, predicted)
                break
    if best is None:
        raise ValueError(f"no integrator setting reaches tol = {tol:g} m for this scene "
                         f"(the pilot's reference is DOP853 at rtol {REFERENCE_RTOL:g}); "
                         "ask for a larger tol")
    kw = best[1]
    dt = kw.get("dt")
    if dt is not None and dt_out is not None:
        # The run lands on every output, so a larger step would run at dt_out anyway (as in
        # the pilot); saying so keeps choice.kwargs() valid for simulate(..., dt_out=dt_out).
        dt = min(float(dt), float(dt_out))
    return Choice(method=str(kw["method"]), rtol=kw.get("rtol"), dt=dt,
                  max_step=kw.get("max_step"), tol=tol, predicted_error=best[2],
                  pilot_t=t_p, t_end=t_end, candidates_tried=tried,
                  pilot_rhs_evaluations=total_evals)


# ----------------------------------------------------------------------------------------
# Fixed steps that are too large: detect and report
# ----------------------------------------------------------------------------------------
class AccuracyWarning(UserWarning):
    """A run's own checks say its result is inaccurate (a fixed step too large)."""


# Set while this module runs the simulator itself (pilots, step doubling): no nested checks.
_INTERNAL: contextvars.ContextVar[bool] = contextvars.ContextVar("saddle_accuracy_internal",
                                                                 default=False)

FIXED_STEP_DRIFT = 1e-5      # relative Jacobi drift above which a fixed-step run is flagged
FIXED_STEP_PHASE = 1.0       # dt·max(|Ω|, ω₀) above which a fixed step is flagged outright
FIXED_STEP_ERROR = 1e-4      # step-doubling error estimate, as a fraction of min(a, b)


def _jacobi_rows(traj) -> np.ndarray:
    """h at every output and, if the run ended in an event, at the event state."""
    h = traj.h
    if traj.event is None:
        return h
    y = np.zeros(K.STATE_WIDTH)
    y[: traj.scene.state_size] = traj.event.state
    he = K.jacobi(traj.scene.model_code, traj.scene.params(), drive_row(traj.omega, traj.force),
                  traj.event.t, y)
    return np.append(h, he)


def jacobi_drift(traj) -> float:
    """How far a run's Jacobi integral drifted, net of the dissipated work.

    Parameters
    ----------
    traj : Trajectory
        A finished run.

    Returns
    -------
    float
        Largest |h(t) − h(0) − W(t)| over the outputs (and, without dissipation, the event
        state), relative to |h(0)| + g·a/100, where W is the work of the dissipative forces
        (`Trajectory.work`); NaN when the Jacobi integral is not conserved (Ω varies or a
        lab-frame force acts).
    """
    if not traj.omega.constant or traj.force != (0.0, 0.0) or len(traj.t) < 1:
        return math.nan
    # The event state carries no work, so a dissipative run is measured at its outputs.
    h = traj.h - traj.work if np.any(traj.work) else _jacobi_rows(traj)
    if len(h) < 2:
        return math.nan
    scale = abs(h[0]) + traj.scene.g * traj.scene.a / 100.0
    if scale == 0.0:
        return math.nan
    return float(np.max(np.abs(h - h[0])) / scale)


def _doubling_estimate(traj, dt: float, method: str) -> float:
    """Error over the run estimated by step doubling on a window at its start (16 steps or
    5 % of the run): |y(dt) − y(dt/2)| at the window's end, scaled to the run linearly."""
    t_run = float(traj.event.t) if traj.event is not None else float(traj.t[-1])
    window = min(t_run, max(16.0 * dt, 0.05 * t_run))
    if window <= 0.0:
        return 0.0
    kw = {"omega": traj.omega, "dt_out": None, "method": method, "events": (),
          "force": traj.force}
    token = _INTERNAL.set(True)
    try:
        coarse = run(traj.scene, traj.state[0], window, dt=dt, **kw)
        fine = run(traj.scene, traj.state[0], window, dt=dt / 2.0, **kw)
    except Exception:  # noqa: BLE001 — a step that cannot even do the window is too large
        return math.inf
    finally:
        _INTERNAL.reset(token)
    diff = float(np.hypot(*(coarse.state[-1, :2] - fine.state[-1, :2])))
    return diff * t_run / window


def check_fixed_step(traj, dt: float, method: str = "rk4") -> str | None:
    """Warn (`AccuracyWarning`) if a fixed-step run is evidently inaccurate.

    Checks, in turn: the step is more than a radian of the fastest rotation
    (dt·max(|Ω|, ω₀) > 1); at constant Ω, the Jacobi integral (outputs and event state)
    drifted by more than `FIXED_STEP_DRIFT`; otherwise a step-doubling estimate on a short
    window at the start exceeds `FIXED_STEP_ERROR`·min(a, b).

    Parameters
    ----------
    traj : Trajectory
        The fixed-step run.
    dt : float
        Its step [s].
    method : str
        Its method (the step doubling reruns with it).

    Returns
    -------
    str or None
        The warning's message, or None when no check flagged the run.
    """
    import warnings

    if _INTERNAL.get():
        return None
    sc = traj.scene
    omega0 = math.sqrt(2.0 * sc.g / sc.a) if sc.g > 0 else 0.0
    t_end = float(traj.t[-1]) if len(traj.t) else 0.0
    if len(traj.t) > 2:  # the loop lands on every output: the step taken is at most the spacing
        dt = min(dt, float(traj.t[1] - traj.t[0]))
    phase = dt * max(traj.omega.bound(max(t_end, dt)), omega0)
    msg = None
    if phase > FIXED_STEP_PHASE:
        msg = (f"fixed step dt = {dt:g} s is far too large for this scene: dt·max(|Ω|, ω₀) = "
               f"{phase:.3g} rad per step")
    else:
        drift = jacobi_drift(traj)
        if math.isfinite(drift):
            if drift > FIXED_STEP_DRIFT:
                msg = (f"fixed step dt = {dt:g} s is too large for this scene: the Jacobi "
                       f"integral (conserved by the exact dynamics) drifted by {drift:.2g} "
                       "relative")
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", AccuracyWarning)
                est = _doubling_estimate(traj, dt, method)
            if not est <= FIXED_STEP_ERROR * min(sc.a, sc.b):
                msg = (f"fixed step dt = {dt:g} s is too large for this scene: step doubling "
                       f"estimates a position error of {est:.2g} m over the run")
    if msg is not None:
        msg += "; use a smaller dt, an adaptive method, or tol= (see saddle_env.accuracy)"
        warnings.warn(msg, AccuracyWarning, stacklevel=3)
    return msg


def assess(traj, **settings: Unpack[IntegratorKwargs]) -> dict[str, float]:
    """A posteriori error estimate of a finished run.

    Re-runs it with half the fixed step (or rtol/100 for an adaptive run) and compares.

    Parameters
    ----------
    traj : Trajectory
        The finished run.
    **settings
        The run's ``method`` and ``dt`` or ``rtol`` (`IntegratorKwargs`).

    Returns
    -------
    dict
        ``"error_estimate_m"``: the largest contact-point distance [m] between the two
        runs; ``"jacobi_drift"``: `jacobi_drift` of the run (NaN where not conserved).
    """
    kw: IntegratorKwargs = {**settings}
    dt_out = float(traj.t[1] - traj.t[0]) if len(traj.t) > 2 else None
    if kw.get("dt") is not None:
        # the loop lands on every output, so the step taken is at most the output spacing
        kw["dt"] = min(float(kw["dt"]), dt_out or math.inf) / 2.0
    else:
        kw["rtol"] = max(float(kw.get("rtol") or 1e-10) / 100.0, 1e-14)
    token = _INTERNAL.set(True)
    try:
        finer = run(traj.scene, traj.state[0], float(traj.t[-1]), omega=traj.omega,
                         dt_out=dt_out, force=traj.force, **kw)
    finally:
        _INTERNAL.reset(token)
    n = min(len(finer.t), len(traj.t))
    err = float(np.max(np.hypot(finer.x[:n] - traj.x[:n], finer.y[:n] - traj.y[:n])))
    return {"error_estimate_m": err, "jacobi_drift": jacobi_drift(traj)}
