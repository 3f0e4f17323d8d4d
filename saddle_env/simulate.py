"""The simulator's public entry points: `simulate` (one ball) and `simulate_batch` (many).

Each call checks its inputs once (`saddle_env.runner.check_run`, `check_batch`), settles the
integrator settings — the ones given (`Settings.build`), or for ``tol=`` the cheapest that
meets the error asked for (`saddle_env.accuracy.choose`, which pilots runs of the layer
below) — and runs the checked inputs (`saddle_env.runner.run_checked`,
`run_batch_checked`). It is the one place ``tol=`` is resolved and where a fixed step is
checked against the output spacing and, after a single ball's run, against the scene's
dynamics.

The layers, lowest first: `saddle_env.runner` checks inputs and runs them with explicit
settings; `saddle_env.accuracy` picks settings by piloting those runs; this module puts the
two together. Both runs call the same compiled loop (`saddle_env.integrators.integrate`);
the batch path runs it once per ball in parallel threads, so a ball gives bit-identical
results either way. `initial_state`, `Settings`, `Trajectory`, ... live in
`saddle_env.runner` and are re-exported here.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .accuracy import Choice, check_fixed_step, choose_for
from .omega import OmegaProfile
from .runner import (
    DEFAULT_EVENTS,
    DEFAULT_METHOD,
    DEFAULT_RTOL,
    BatchResult,
    Event,
    RunInputs,
    Settings,
    SimulationError,
    Stats,
    Trajectory,
    check_batch,
    check_fixed_step_fits,
    check_rtol,
    check_run,
    default_max_step,
    drive_row,
    initial_state,
    run_batch_checked,
    run_checked,
)
from .scene import Scene


# --------------------------------------------------------------------------------------
# Entry points
# --------------------------------------------------------------------------------------
def simulate(scene: Scene, state: np.ndarray, t_end: float, *,
             omega: float | OmegaProfile = 20.0, dt_out: float | None = 0.01,
             method: str | None = None, rtol: float | None = None, atol: float | None = None,
             dt: float | None = None, events: Sequence[str] = DEFAULT_EVENTS,
             max_step: float | None = None, max_steps: int = 50_000_000,
             force: tuple[float, float] = (0.0, 0.0), tol: float | None = None) -> Trajectory:
    """Integrate one ball from t = 0 to ``t_end`` in the frame rotating with the saddle.

    Parameters
    ----------
    scene : Scene
        The saddle, the ball and its contact model.
    state : ndarray, shape (scene.state_size,)
        The starting state, from `initial_state`.
    t_end : float
        Final time [s].
    omega : float or OmegaProfile
        Ω(t) [rad/s]: a number is a constant speed; a ramp or a ripple is an `OmegaProfile`.
        A sequence is one entry per ball, so here exactly one (else ValueError).
    dt_out : float or None
        Output spacing [s]; None outputs only t = 0 and t_end. The outputs are the
        multiples of ``dt_out`` up to ``t_end``, and ``t_end`` itself when it is not one of
        them.
    method : str
        A name in ``METHODS`` (default ``"dop853"``).
    rtol, atol : float
        Adaptive tolerances (default 1e-10); ``atol`` is relative to the saddle's size (see
        `state_scale`).
    dt : float
        Fixed step [s]; selects fixed-step integration. It must not exceed ``dt_out``
        (ValueError: the loop lands on every output, so a larger step would be cut to the
        output spacing). A step too large for the scene's dynamics runs, with an
        `AccuracyWarning` (`saddle_env.accuracy.check_fixed_step`).
    events : subset of ("detach", "escape")
        Stop when the normal force falls below 0 or the contact point leaves
        ``scene.rim_radius``; the normal force is computed during integration only if
        "detach" is asked for.
    max_step : float
        Largest step [s] (default: π/(2·max|Ω|), half the half-turn period).
    max_steps : int
        Give up after this many steps.
    force : (fx, fy)
        Constant horizontal force per unit mass [m/s²] fixed in the laboratory (whose axes
        coincide with the saddle's at t = 0), e.g. an air current.
    tol : float
        Instead of method/rtol/atol/dt/max_step: the largest position error [m] allowed over
        the run; the cheapest integrator setting that meets it for this scene is picked by a
        short pilot run (`saddle_env.accuracy`) and named in ``settings``.

    Returns
    -------
    Trajectory
        The outputs reached, the event that stopped the run (if one did), the settings used
        and the integrator's counts.

    Raises
    ------
    ValueError
        Invalid input (the message names the parameter and the allowed range).
    SimulationError
        The integration failed (non-finite state or step-size underflow).
    """
    inputs = check_run(scene, state, t_end, omega, dt_out, force)
    explicit = (method, rtol, atol, dt, max_step)
    if tol is not None:  # automatic accuracy (saddle_env.accuracy)
        auto = _auto([inputs], dt_out, tol, explicit, events)
        traj = run_checked(inputs, _picked(auto, dt_out, events, max_steps))
        traj.settings = auto.describe()
        return traj
    settings = _explicit(method, rtol, atol, dt, max_step, events, max_steps, dt_out)
    traj = run_checked(inputs, settings)
    if settings.dt > 0:  # a fixed step too large is reported, not hidden
        check_fixed_step(traj, settings.dt, settings.method.name)
    return traj


def simulate_batch(scenes: Scene | Sequence[Scene], states: np.ndarray, t_end: float, *,
                   omega: float | OmegaProfile | Sequence[float | OmegaProfile] | np.ndarray = 20.0,
                   dt_out: float | None = 0.01, method: str | None = None,
                   rtol: float | None = None, atol: float | None = None,
                   dt: float | None = None, events: Sequence[str] = DEFAULT_EVENTS,
                   max_step: float | None = None, max_steps: int = 50_000_000,
                   force: tuple[float, float] = (0.0, 0.0),
                   tol: float | None = None, shared_steps: bool = False) -> BatchResult:
    """Integrate many balls at once (threads over balls; same kernel as `simulate`).

    Parameters
    ----------
    scenes : Scene or sequence of Scene
        One Scene for all balls or one per ball (contact models may differ).
    states : ndarray, shape (n, k)
        Each row a ball's state, padded with zeros to a common k ≤ 7.
    t_end : float
        Final time [s].
    omega : float, OmegaProfile, sequence or ndarray
        One speed [rad/s] or `OmegaProfile` for all balls, or one per ball: a sequence of
        exactly n speeds or profiles, an (n,) array of constant speeds, or an (n, 5) array
        of profile rows (`OmegaProfile.array`). Any other length is a ValueError naming
        ``omega`` and n; a ramp for every ball is one `OmegaProfile`, never a pair.
    dt_out, method, rtol, atol, dt, events, max_step, max_steps, force
        As in `simulate`.
    tol : float
        As in `simulate`, piloted on up to four balls spread over the batch (first, last
        and two between); the pick is in ``settings``.
    shared_steps : bool
        False (the default): each ball takes its own steps, exactly those `simulate` takes
        for it alone, so each row is bit for bit `simulate`'s. True: balls in blocks of
        up to 64 (one contact model each) share every step, and the step's arithmetic runs
        on the whole block at once in the CPU's vector instructions: several times less
        time per ball, each ball's error still held to the tolerance at every step (a row
        then differs from `simulate`'s by about the tolerance). A ball that meets an event
        is finished alone, as `simulate` would; coulomb balls, rolling resistance and the
        ion models always step alone (docs/simulator.md, "Many balls at once").

    Returns
    -------
    BatchResult
        Failures do not raise; they are reported per ball in ``status``.

    Raises
    ------
    ValueError
        Invalid input (the message names the parameter and the allowed range).
    """
    inputs = check_batch(scenes, states, t_end, omega, dt_out, force)
    explicit = (method, rtol, atol, dt, max_step)
    if not isinstance(shared_steps, bool):
        raise ValueError(f"shared_steps must be True or False, got {shared_steps!r}")
    if tol is None:
        return run_batch_checked(inputs, _explicit(method, rtol, atol, dt, max_step, events,
                                                   max_steps, dt_out), shared_steps)
    # automatic accuracy, piloted on a few balls spread over the batch
    n = len(inputs.scenes)
    pick = sorted({0, n // 3, (2 * n) // 3, n - 1})
    auto = _auto([RunInputs(inputs.scenes[i], inputs.states[i], OmegaProfile(*inputs.omegas[i]),
                            inputs.force, inputs.t_out) for i in pick],
                 dt_out, tol, explicit, events)
    res = run_batch_checked(inputs, _picked(auto, dt_out, events, max_steps), shared_steps)
    res.settings = auto.describe()
    return res


def _explicit(method: str | None, rtol: float | None, atol: float | None, dt: float | None,
              max_step: float | None, events: Sequence[str], max_steps: int,
              dt_out: float | None) -> Settings:
    """The settings given, checked; a fixed step must fit the output spacing (``dt_out``,
    already checked with the output times)."""
    settings = Settings.build(method, rtol, atol, dt, events, max_step, max_steps)
    if dt is not None:
        check_fixed_step_fits(settings.dt, None if dt_out is None else float(dt_out))
    return settings


def _auto(balls: list[RunInputs], dt_out: float | None, tol: float, explicit: tuple,
          events: Sequence[str]) -> Choice:
    """Pick the integrator for ``tol`` from pilots of the checked ``balls`` (see
    saddle_env.accuracy); ``explicit`` (method, rtol, atol, dt, max_step) must be unset."""
    if any(v is not None for v in explicit):
        raise ValueError("give either tol (automatic accuracy) or method/rtol/atol/dt/"
                         "max_step, not both")
    return choose_for(balls, tol, dt_out, events)


def _picked(choice: Choice, dt_out: float | None, events: Sequence[str],
            max_steps: int) -> Settings:
    """The run's settings from a pick. A fixed step above the output spacing runs at the
    spacing (the loop lands on every output), which is what the pilot measured."""
    kw = choice.kwargs()
    dt = kw.get("dt")
    if dt is not None and dt_out is not None:
        dt = min(float(dt), float(dt_out))
    return Settings.build(kw.get("method"), kw.get("rtol"), kw.get("atol"), dt, events,
                          kw.get("max_step"), max_steps)


__all__ = ["DEFAULT_METHOD", "DEFAULT_RTOL", "BatchResult", "Event", "Settings",
           "SimulationError", "Stats", "Trajectory", "check_rtol", "default_max_step",
           "drive_row", "initial_state", "simulate", "simulate_batch"]
