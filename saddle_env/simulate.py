"""Python API: initial states, `simulate` (one ball) and `simulate_batch` (many balls).

Both call the same compiled loop (`saddle_env.integrators.integrate`, through
`saddle_env.runner`); the batch path runs it once per ball in parallel threads, so a ball
gives bit-identical results either way.

This module is the one place ``tol=`` is resolved: it asks `saddle_env.accuracy.choose`
(which pilots `saddle_env.runner`, below both) for the cheapest setting, then runs it. It
also reports fixed steps that are too large. Everything else (`initial_state`, `Settings`,
`Trajectory`, ...) lives in `saddle_env.runner` and is re-exported here.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from . import runner
from .accuracy import Choice, IntegratorKwargs, check_fixed_step, check_tol, choose
from .omega import OmegaProfile
from .runner import (
    DEFAULT_EVENTS,
    DEFAULT_METHOD,
    DEFAULT_RTOL,
    BatchResult,
    Event,
    Settings,
    SimulationError,
    Stats,
    Trajectory,
    check_fixed_step_fits,
    check_rtol,
    default_max_step,
    drive_row,
    initial_state,
)
from .scene import Scene


# --------------------------------------------------------------------------------------
# Entry points
# --------------------------------------------------------------------------------------
def simulate(scene: Scene, state: np.ndarray, t_end: float, *,
             omega: float | OmegaProfile | Sequence[float] = 20.0, dt_out: float | None = 0.01,
             method: str | None = None, rtol: float | None = None, atol: float | None = None,
             dt: float | None = None, events: Sequence[str] = DEFAULT_EVENTS,
             max_step: float | None = None, max_steps: int = 50_000_000,
             force: tuple[float, float] = (0.0, 0.0), tol: float | None = None) -> Trajectory:
    """Integrate one ball from t = 0 to ``t_end`` in the frame rotating with the saddle.

    Parameters
    ----------
    scene : Scene
    state : array (scene.state_size,) — from `initial_state`.
    t_end : float — final time [s].
    omega : float, OmegaProfile or tuple — Ω(t) [rad/s] (a number means constant speed).
    dt_out : float or None — output spacing [s]; None outputs only t = 0 and t_end. The
        outputs are the multiples of ``dt_out`` up to ``t_end``, and ``t_end`` itself when
        it is not one of them.
    method : str — a name in ``METHODS`` (default ``"dop853"``).
    rtol, atol : float — adaptive tolerances (default 1e-10); ``atol`` is relative to the
        saddle's size (see `state_scale`).
    dt : float — fixed step [s]; selects fixed-step integration. It must not exceed
        ``dt_out`` (ValueError: the loop lands on every output, so a larger step would be
        cut to the output spacing). A step too large for the scene's dynamics runs, with an
        `AccuracyWarning` (`saddle_env.accuracy.check_fixed_step`).
    events : subset of ("detach", "escape") — stop when the normal force falls below 0 or
        the contact point leaves ``scene.rim_radius``; the normal force is computed during
        integration only if "detach" is asked for.
    max_step : float — largest step [s] (default: an eighth of π/max|Ω|).
    max_steps : int — give up after this many steps.
    force : (fx, fy) — constant horizontal force per unit mass [m/s²] fixed in the
        laboratory (whose axes coincide with the saddle's at t = 0), e.g. an air current.
    tol : float — instead of method/rtol/atol/dt/max_step: the largest position error [m]
        allowed over the run; the cheapest integrator setting that meets it for this scene
        is picked by a short pilot run (`saddle_env.accuracy`) and named in ``settings``.

    Returns
    -------
    Trajectory

    Raises
    ------
    ValueError — invalid input (the message names the parameter and the allowed range).
    SimulationError — the integration failed (non-finite state or step-size underflow).
    """
    if tol is not None:  # automatic accuracy (saddle_env.accuracy)
        if not isinstance(scene, Scene):
            raise ValueError(f"scene must be a saddle_env.Scene, got {type(scene).__name__}")
        y = runner._check_state(scene, state)[: scene.state_size]
        profile = OmegaProfile.coerce(omega)
        force = runner._check_force(force)
        t_out = runner._output_times(t_end, dt_out)
        auto = _auto([scene], [y], [profile], t_out, dt_out, tol,
                     (method, rtol, atol, dt, max_step), events, force)
        traj = runner.run(scene, state, t_end, omega=profile, dt_out=dt_out, events=events,
                          max_steps=max_steps, force=force, **_run_kwargs(auto, dt_out))
        traj.settings = auto.describe()
        return traj
    if dt is not None:
        check_fixed_step_fits(runner._finite_number("dt", dt), _spacing(dt_out))
    traj = runner.run(scene, state, t_end, omega=omega, dt_out=dt_out, method=method, rtol=rtol,
                      atol=atol, dt=dt, events=events, max_step=max_step, max_steps=max_steps,
                      force=force)
    settings = Settings.build(method, rtol, atol, dt, events, max_step, max_steps)
    if settings.dt > 0:  # a fixed step too large is reported, not hidden
        check_fixed_step(traj, settings.dt, settings.method.name)
    return traj


def _spacing(dt_out: float | None) -> float | None:
    return None if dt_out is None else runner._finite_number("dt_out", dt_out)


def _auto(scenes, states, profiles, t_out, dt_out, tol, explicit, events, force) -> Choice:
    """Pick the integrator for ``tol`` (see saddle_env.accuracy); ``explicit`` must be unset."""
    if any(v is not None for v in explicit):
        raise ValueError("give either tol (automatic accuracy) or method/rtol/atol/dt/"
                         "max_step, not both")
    check_tol(tol)
    return choose(scenes, states, float(t_out[-1]), tol, omegas=profiles, dt_out=dt_out,
                  events=events, force=force)


def _run_kwargs(choice: Choice, dt_out: float | None) -> IntegratorKwargs:
    """The run's settings from a pick. A fixed step above the output spacing runs at the
    spacing (the loop lands on every output), which is what the pilot measured."""
    kw = choice.kwargs()
    if "dt" in kw and dt_out is not None:
        kw["dt"] = min(float(kw["dt"]), float(dt_out))
    return kw


def simulate_batch(scenes: Scene | Sequence[Scene], states: np.ndarray, t_end: float, *,
                   omega: float | OmegaProfile | Sequence[float | OmegaProfile] | np.ndarray = 20.0,
                   dt_out: float | None = 0.01, method: str | None = None,
                   rtol: float | None = None, atol: float | None = None,
                   dt: float | None = None, events: Sequence[str] = DEFAULT_EVENTS,
                   max_step: float | None = None, max_steps: int = 50_000_000,
                   force: tuple[float, float] = (0.0, 0.0),
                   tol: float | None = None) -> BatchResult:
    """Integrate many balls at once (threads over balls; same kernel as `simulate`).

    ``scenes`` is one Scene for all balls or one per ball (contact models may differ).
    ``states`` is (n, k): each row a ball's state, padded with zeros to a common k ≤ 7.
    ``omega`` is one value/profile for all, or one per ball (a sequence, or an (n,) array of
    constant speeds, or an (n, 5) array of profile rows). Failures do not raise; they are
    reported per ball in ``status``. ``tol`` [m] picks the integrator automatically as in
    `simulate`, from pilot runs of up to four balls spread over the batch (first, last and
    two between); the pick is in ``settings``. Outputs and ``dt`` as in `simulate`.
    """
    if tol is not None:  # automatic accuracy, piloted on a few balls spread over the batch
        try:
            arr = np.asarray(states, dtype=float)
        except (TypeError, ValueError):
            raise ValueError("states must be a real array of shape (n, state_size)") from None
        if arr.ndim != 2 or arr.shape[0] < 1:
            raise ValueError(f"states must have shape (n, state_size), got {arr.shape}")
        n = arr.shape[0]
        scene_list = _scene_list(scenes, n)
        pick = sorted({0, n // 3, (2 * n) // 3, n - 1})
        rows = []
        for i in pick:
            row = arr[i]
            if scene_list[i].state_size < arr.shape[1] <= runner.K.DYNAMICS_WIDTH:  # padded
                row = row[: scene_list[i].state_size]
            rows.append(runner._check_state(scene_list[i], row, f"states[{i}]")
                        [: scene_list[i].state_size])
        profiles = runner._profiles(omega, n)
        force = runner._check_force(force)
        t_out = runner._output_times(t_end, dt_out)
        auto = _auto([scene_list[i] for i in pick], rows,
                     [OmegaProfile(*profiles[i]) for i in pick], t_out, dt_out, tol,
                     (method, rtol, atol, dt, max_step), events, force)
        res = runner.run_batch(scenes, states, t_end, omega=omega, dt_out=dt_out, events=events,
                               max_steps=max_steps, force=force, **_run_kwargs(auto, dt_out))
        res.settings = auto.describe()
        return res
    if dt is not None:
        check_fixed_step_fits(runner._finite_number("dt", dt), _spacing(dt_out))
    return runner.run_batch(scenes, states, t_end, omega=omega, dt_out=dt_out, method=method,
                            rtol=rtol, atol=atol, dt=dt, events=events, max_step=max_step,
                            max_steps=max_steps, force=force)


def _scene_list(scenes: object, n: int) -> list[Scene]:
    if isinstance(scenes, Scene):
        return [scenes] * n
    if isinstance(scenes, (list, tuple)) and len(scenes) == n and \
            all(isinstance(s, Scene) for s in scenes):
        return list(scenes)
    raise ValueError(f"scenes must be a Scene or a sequence of {n} Scenes (one per ball)")


__all__ = ["DEFAULT_METHOD", "DEFAULT_RTOL", "BatchResult", "Event", "Settings",
           "SimulationError", "Stats", "Trajectory", "check_rtol", "default_max_step",
           "drive_row", "initial_state", "simulate", "simulate_batch"]
