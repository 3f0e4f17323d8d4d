"""Fit the model's unknowns to measured tracks: least squares with multiple shooting
(`saddle_env.calibrate.model`), intervals from the Jacobian, unidentifiable parameters named.

    >>> result = fit_tracks(tracks, level_config("SaddleTrap-Lab-v0", R=0.0265),
    ...                     ["drag_quadratic", "obs_delay"])          # doctest: +SKIP
    >>> result.estimates["obs_delay"].interval                         # doctest: +SKIP

The intervals: the covariance of the fitted vector is s² (JᵀJ)⁻¹, J the Jacobian of the
weighted residuals at the solution and s² the variance of the measurement residuals (frames
and tachometer readings, noise-weighted) per degree of freedom; a parameter's 95 % interval is
its value ± 1.96 standard deviations, cut to the range the parameter may take. A direction
the residuals do not change along (JᵀJ singular to 1e-9 of its largest singular value) has
no interval: the parameters with a part in it are reported unidentifiable (interval ±∞) with a
warning, never with a number.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from ..envs.config import EnvConfig
from .model import PARAMETERS, Model, TrackPlan, contact_from_centre, plan_track, wrap
from .tracks import Track

Z95 = 1.959963984540054
MIN_FRAMES = 6        # tracked frames a track needs: two segments of three
RCOND = 1e-9          # singular values below this fraction of the largest: no information
MAX_UNKNOWNS = 20_000
ODD_TRACK = 1.2      # a track's residual this many times the others' median is flagged
REWEIGHTS = 2         # refits with the noise re-estimated from the residuals


class FitWarning(UserWarning):
    """A fitted parameter the tracks do not determine (or determine poorly)."""


@dataclass
class Estimate:
    """One fitted parameter: value, standard deviation and 95 % interval.

    Parameters
    ----------
    name : str
        The parameter (a name of `model.PARAMETERS`).
    value : float
        The estimate.
    std : float
        Its standard deviation (inf where the tracks do not determine it).
    low, high : float
        The 95 % interval's ends (±inf where the tracks do not determine it).
    unit : str
        The parameter's unit.
    start : float
        The value the fit started from.
    identifiable : bool
        Whether the tracks determine the parameter.
    """

    name: str
    value: float
    std: float
    low: float
    high: float
    unit: str
    start: float
    identifiable: bool

    @property
    def interval(self) -> tuple[float, float]:
        """The estimate's interval, (low, high)."""
        return self.low, self.high

    def as_dict(self) -> dict[str, Any]:
        """The estimate as JSON-ready values (infinite bounds as "inf", "-inf")."""
        def num(v: float) -> float | str:
            return v if math.isfinite(v) else ("inf" if v > 0 else "-inf")
        return {"value": self.value, "std": num(self.std), "low": num(self.low),
                "high": num(self.high), "unit": self.unit, "start": self.start,
                "identifiable": self.identifiable}


@dataclass
class FitResult:
    """What `fit_tracks` found (see `as_dict` for the results file).

    Parameters
    ----------
    estimates : dict of str to Estimate
        Each fitted parameter's estimate.
    tracks : list of dict
        Per track: its source, frames, segments, residual RMS [m] and the fitted start
        angle (and speed) where they were fitted.
    env_options : dict
        The fitted options, ready for ``gym.make`` or ``--env-kwargs``.
    drive : str
        What drove the saddle's speed in the fit: "omega" or "voltage".
    cost : float
        The final least-squares cost.
    sigma_scale : float
        The residuals' spread in units of the noise they were weighted with.
    iterations : int
        Jacobian evaluations made.
    status : str
        The optimiser's message.
    warnings : list of str
        What the fit found suspect (e.g. a track whose residuals stand out, segments that
        failed to integrate).
    noise : dict of str to float
        The noise levels the residuals were weighted with.
    model : Model, optional
        The fit's model (not written to the results file).
    x : numpy.ndarray, optional
        The final parameter vector (not written to the results file).
    """

    estimates: dict[str, Estimate]
    tracks: list[dict[str, Any]]
    env_options: dict[str, Any]
    drive: str
    cost: float
    sigma_scale: float
    iterations: int
    status: str
    warnings: list[str] = field(default_factory=list)
    noise: dict[str, float] = field(default_factory=dict)
    model: Model | None = field(default=None, repr=False)
    x: np.ndarray | None = field(default=None, repr=False)

    def as_dict(self) -> dict[str, Any]:
        """The fit as JSON-ready values, as ``saddle-fit`` writes it."""
        return {"estimates": {k: e.as_dict() for k, e in self.estimates.items()},
                "tracks": self.tracks, "env_options": self.env_options, "drive": self.drive,
                "cost": self.cost, "noise_scale": self.sigma_scale,
                "noise": self.noise, "iterations": self.iterations, "status": self.status,
                "warnings": self.warnings}


def check_fit_names(names: Sequence[str], config: EnvConfig, drive: str) -> tuple[str, ...]:
    """The parameters to fit, checked: known, once each, and meaningful for this scene."""
    names = tuple(str(n).strip() for n in names if str(n).strip())
    unknown = [n for n in names if n not in PARAMETERS]
    if unknown:
        raise ValueError(f"--fit: unknown parameter(s) {unknown}; the fittable parameters are "
                         f"{list(PARAMETERS)} (the saddle's angle θ₀ of each track without a "
                         f"theta column is always fitted)")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"--fit: {twice} given twice")
    contact = config.contact
    if "mu" in names and contact != "coulomb":
        raise ValueError(f"--fit mu: the friction coefficient applies to contact='coulomb' "
                         f"balls only; this scene's contact is {contact!r}")
    if "rolling_resistance" in names and contact not in ("rolling", "coulomb"):
        raise ValueError(f"--fit rolling_resistance: applies to contact 'rolling' or "
                         f"'coulomb'; this scene's contact is {contact!r}")
    motor = [n for n in names if n in ("motor_tau", "motor_gain")]
    if motor and drive != "voltage":
        raise ValueError(f"--fit {motor}: the motor is seen only through a 'voltage' column "
                         f"(drive 'voltage'); this fit's drive is {drive!r}")
    return names


def choose_drive(tracks: Sequence[Track], names: Sequence[str], drive: str | None) -> str:
    """'omega' (the tachometer) when every track has one and no motor parameter is fitted,
    else 'voltage'; an explicit ``drive`` is checked against the tracks."""
    if drive not in (None, "auto", "omega", "voltage"):
        raise ValueError(f"drive must be 'auto', 'omega' or 'voltage', got {drive!r}")
    if drive in (None, "auto"):
        motor = any(n in ("motor_tau", "motor_gain") for n in names)
        drive = "omega" if not motor and all(t.omega is not None for t in tracks) else "voltage"
    for t in tracks:
        if getattr(t, drive) is None:
            has = [c for c in ("omega", "voltage") if getattr(t, c) is not None]
            raise ValueError(f"{t.source}: the saddle's motion is read from the '{drive}' "
                             f"column, which this track lacks (it has {has or 'neither'}); a "
                             f"fit needs 'omega' (the tachometer) or 'voltage' in every track")
    return drive


def prepare_config(config: EnvConfig, names: Sequence[str]) -> EnvConfig:
    """The scene to start from: a ball of the fixed size ``R`` (not drawn from
    ``ball_radii``), its quadratic drag a number when it is fitted (not ``ball_density``'s)."""
    changes: dict[str, Any] = {}
    if config.ball_radii is not None:
        changes["ball_radii"] = None
    if "drag_quadratic" in names and config.ball_density is not None:
        changes.update(ball_density=None, drag_quadratic=config.scene().drag_quadratic)
    return replace(config, **changes) if changes else config


def _typical(model: Model) -> np.ndarray:
    """A size for each unknown: finite-difference steps are 1e-6 of it."""
    lay = model.layout
    typ = np.empty(lay.size)
    for i, n in enumerate(lay.names):
        typ[i] = PARAMETERS[n][3]
    for slots in lay.track_slots:
        for key, i in slots.items():
            typ[i] = 1.0 if key == "theta0" else 10.0
    node = np.array([0.01, 0.01, 0.1, 0.1, 10.0])[:lay.width]
    for k, plan in enumerate(lay.plans):
        s = lay.node_slots[k]
        typ[s:s + len(plan.nodes) * lay.width] = np.tile(node, len(plan.nodes))
    return typ


def _bounds(model: Model) -> tuple[np.ndarray, np.ndarray]:
    lo = np.full(model.layout.size, -np.inf)
    hi = np.full(model.layout.size, np.inf)
    for i, n in enumerate(model.names):
        lo[i], hi[i] = PARAMETERS[n][1], PARAMETERS[n][2]
    return lo, hi


def _initial_nodes(model: Model, v: np.ndarray) -> None:
    """Each segment start's state from the measured positions at ``v``'s angles: the contact
    point under the seen centre, its velocity from the neighbouring frames (2 each side)."""
    lay = model.layout
    values = model.values(v)
    scene = model.scene_at(values)
    for k, plan in enumerate(lay.plans):
        slots = lay.track_slots[k]
        theta0 = float(v[slots["theta0"]]) if "theta0" in slots else 0.0
        omega0 = float(v[slots["omega0"]]) if "omega0" in slots else 0.0
        B, frames, _, _, wt = model.timeline(plan, values, theta0, omega0)
        th = wt[1, frames]
        X = plan.xy[:, 0] - values["x0"]
        Y = plan.xy[:, 1] - values["y0"]
        cx, cy = np.cos(th) * X + np.sin(th) * Y, -np.sin(th) * X + np.cos(th) * Y
        q = contact_from_centre(scene, cx, cy)
        n = len(q)
        i = np.arange(n)
        a, b = np.clip(i - 2, 0, n - 1), np.clip(i + 2, 0, n - 1)
        t = plan.t
        vel = (q[b] - q[a]) / (t[b] - t[a])[:, None]
        block = lay.node_block(v, k)
        block[:] = 0.0
        block[:, :2] = q[plan.nodes]
        block[:, 2:4] = vel[plan.nodes]


def noise_spread(model: Model, v: np.ndarray) -> tuple[float, float]:
    """The RMS of the position and of the tachometer residuals at ``v``, in units of their
    assumed noise (1: as assumed; 1.0 for a kind with no residuals)."""
    r = model.residuals(v)
    kinds = model.row_kinds()
    out = []
    for kind in (0, 2):
        rows = r[kinds == kind]
        out.append(float(np.sqrt(np.mean(rows ** 2))) if rows.size else 1.0)
    return out[0], out[1]


def _track_costs(model: Model, v: np.ndarray) -> np.ndarray:
    r = model.residuals(v)
    return np.array([float(np.sum(r[rows] ** 2)) for rows in model.track_rows()])


def initial_vector(model: Model, progress: Callable[[str], None]) -> np.ndarray:
    """The starting point: the parameters at the scene's values; each track's Ω₀ from its
    first tachometer reading (else the motor's steady speed); θ₀ from a scan of 12 angles
    over [0, π) (the saddle looks the same turned by π), each track taking its best."""
    lay = model.layout
    v = np.zeros(lay.size)
    values = model.defaults()
    for i, n in enumerate(lay.names):
        lo, hi = PARAMETERS[n][1], PARAMETERS[n][2]
        v[i] = min(max(values[n], lo), hi)
    for k, plan in enumerate(lay.plans):
        slots = lay.track_slots[k]
        if "omega0" in slots:
            if plan.omega_obs is not None:
                v[slots["omega0"]] = plan.omega_obs[1][0]
            else:
                v[slots["omega0"]] = model.values(v)["motor_gain"] * plan.knot_v[0]
    free = [k for k, s in enumerate(lay.track_slots) if "theta0" in s]
    if not free:
        _initial_nodes(model, v)
        return v
    best = np.full(len(lay.plans), np.inf)
    best_angle = np.zeros(len(lay.plans))
    for angle in np.linspace(0.0, math.pi, 12, endpoint=False):
        for k in free:
            v[lay.track_slots[k]["theta0"]] = angle
        _initial_nodes(model, v)
        costs = _track_costs(model, v)
        better = costs < best
        best[better], best_angle[better] = costs[better], angle
    for k in free:
        v[lay.track_slots[k]["theta0"]] = best_angle[k]
    _initial_nodes(model, v)
    progress(f"start: saddle angles θ₀ from a 12-angle scan, cost {0.5 * best.sum():.4g}")
    return v


class _Objective:
    """Residuals and their finite-difference Jacobian (columns that never share a residual
    perturbed together), remembering the best point seen (for an interrupted fit)."""

    def __init__(self, model: Model, lo: np.ndarray, hi: np.ndarray,
                 progress: Callable[[str], None]):
        self.model, self.lo, self.hi, self.progress = model, lo, hi, progress
        self.groups = model.column_groups()
        self.typ = _typical(model)
        self.best_x: np.ndarray | None = None
        self.best_cost = math.inf
        self.iteration = 0
        self.started = time.monotonic()
        self._last: tuple[np.ndarray, np.ndarray] | None = None

    def fun(self, v: np.ndarray) -> np.ndarray:
        r = self.model.residuals(v)
        cost = 0.5 * float(r @ r)
        if cost < self.best_cost:
            self.best_cost, self.best_x = cost, v.copy()
        self._last = (v.copy(), r)
        return r

    def jac(self, v: np.ndarray, *_: Any) -> np.ndarray:
        if self._last is not None and np.array_equal(self._last[0], v):
            f0 = self._last[1]
        else:
            f0 = self.fun(v)
        J = np.zeros((len(f0), len(v)))
        h = 1e-6 * np.maximum(np.abs(v), self.typ)
        h = np.where(v + h > self.hi, -h, h)
        for cols in self.groups:
            vp = v.copy()
            vp[cols] += h[cols]
            df = self.model.residuals(vp) - f0
            if len(cols) == 1:
                J[:, cols[0]] = df / h[cols[0]]
                continue
            # each residual belongs to at most one column of the group: assign it by the
            # column's own rows (the model's structure), found from a unit probe
            for c in cols:
                J[:, c] = 0.0
            owner = self._owners(cols)
            for c, rows in owner:
                J[rows, c] = df[rows] / h[c]
        self.iteration += 1
        vals = ", ".join(f"{n}={v[i]:.6g}" for i, n in enumerate(self.model.names))
        self.progress(f"iteration {self.iteration}: cost {0.5 * float(f0 @ f0):.6g}  {vals}  "
                      f"({time.monotonic() - self.started:.1f} s)")
        return J

    _owner_cache: dict[bytes, list[tuple[int, np.ndarray]]]

    def _owners(self, cols: np.ndarray) -> list[tuple[int, np.ndarray]]:
        if not hasattr(self, "_owner_cache"):
            self._owner_cache = {}
        key = cols.tobytes()
        if key not in self._owner_cache:
            self._owner_cache[key] = [(int(c), self.model.rows_of(int(c))) for c in cols]
        return self._owner_cache[key]


def covariance(J: np.ndarray, scale2: float) -> tuple[np.ndarray, np.ndarray]:
    """Variances of every unknown (s² (JᵀJ)⁻¹'s diagonal, +inf where a direction J does not
    see has a part) and the null space's weight per unknown."""
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    _, s, Vt = np.linalg.svd(J / norms, full_matrices=False)
    keep = s > RCOND * s[0] if s.size else np.zeros(0, bool)
    V = Vt.T
    var = (V[:, keep] ** 2 / s[keep] ** 2).sum(axis=1) * scale2 / norms ** 2
    null = (V[:, ~keep] ** 2).sum(axis=1)
    zero_col = np.linalg.norm(J, axis=0) == 0
    null = np.where(zero_col, 1.0, null)
    var = np.where(null > 1e-6, np.inf, var)
    return var, null


HINTS = {
    "obs_delay": "while the saddle's speed stays constant the scene looks the same at every "
                 "moment in the saddle's frame, so without a theta column a latency trades "
                 "against each track's start angle: record the encoder's angle (theta) or vary "
                 "the speed",
    "motor_tau": "the motor's lag shows only while the voltage changes: vary it",
    "motor_gain": "needs a tachometer column or a speed that changes the ball's motion",
    "x0": "the axis offset trades against the orbit's own centre when few turns are seen",
    "y0": "the axis offset trades against the orbit's own centre when few turns are seen",
}


def _check_arguments(tracks: list[Track], config: EnvConfig, segment: float,
                     max_iterations: int) -> None:
    """`fit_tracks`' arguments that need no model: some tracks, the config, the segments'
    length and the iteration budget (ValueError naming the argument)."""
    if not tracks:
        raise ValueError("no tracks to fit")
    if not isinstance(config, EnvConfig):
        raise ValueError(f"config must be an EnvConfig, got {type(config).__name__}")
    if not (isinstance(segment, (int, float)) and 0.02 <= segment <= 2.0):
        raise ValueError(f"segment must be in [0.02, 2] s, got {segment!r}")
    if not (isinstance(max_iterations, int) and 1 <= max_iterations <= 1000):
        raise ValueError(f"max_iterations must be an integer in [1, 1000], got {max_iterations!r}")


def _noise_weights(tracks: list[Track], config: EnvConfig, position_noise: float | None,
                   omega_noise: float | None) -> tuple[float, float]:
    """The residuals' starting weights (camera [m], tachometer [rad/s]), after checking
    that every track has enough tracked frames."""
    for t in tracks:
        if int(t.tracked.sum()) < MIN_FRAMES:
            raise ValueError(f"{t.source}: {int(t.tracked.sum())} tracked frames; a fit needs "
                             f"at least {MIN_FRAMES} per track")
    sigma = position_noise if position_noise is not None else (config.position_noise or 1e-3)
    sigma_w = omega_noise if omega_noise is not None else (config.omega_noise or 0.2)
    for nm, val in (("position_noise", sigma), ("omega_noise", sigma_w)):
        if not (isinstance(val, (int, float)) and 0 < val < 1):
            raise ValueError(f"{nm} must be in (0, 1), got {val!r}")
    return sigma, sigma_w


def _restart_latency(model: Model, plans: list[TrackPlan], v: np.ndarray, v0: np.ndarray,
                     lo: np.ndarray, hi: np.ndarray, max_iterations: int,
                     say: Callable[[str], None]) -> np.ndarray:
    """The fit ``v`` or a better one started from another camera latency.

    The cost along the latency can be nearly flat with a worse minimum far off (seen: 96 ms
    fitted for 27 ms, one track's residual 1.3x the others'). Start again from no latency
    and from twice the start, with ``model``'s weights; keep the lowest cost."""
    names = model.names
    i = names.index("obs_delay")
    start_delay = float(v0[i])
    for d in (0.0, min(2.0 * start_delay + 0.02, PARAMETERS["obs_delay"][2])):
        say(f"one track fits worse than the others: starting again from "
            f"obs_delay = {d:g} s")
        alt = Model(replace(model.config, obs_delay=d), plans, names, model.drive,
                    model.sigma, model.sigma_omega, rtol=model.rtol)
        alt_obj = _Objective(alt, lo, hi, say)
        w, st = _solve(alt, alt_obj, initial_vector(alt, say), lo, hi,
                       max_iterations, say, reweight=False)
        cost_w, cost_v = (float(np.sum(model.residuals(x) ** 2)) for x in (w, v))
        say(f"cost {0.5 * cost_w:.6g} against {0.5 * cost_v:.6g}")
        if st == "converged" and cost_w < cost_v:
            v = w
    return v


def fit_tracks(tracks: Sequence[Track], config: EnvConfig, fit: Sequence[str], *,
               drive: str | None = None, segment: float = 0.15,
               position_noise: float | None = None, omega_noise: float | None = None,
               max_iterations: int = 50, rtol: float = 1e-9,
               progress: Callable[[str], None] | None = None) -> FitResult:
    """Fit ``fit`` (names from `model.PARAMETERS`) to ``tracks``, everything else at
    ``config``'s values.

    Parameters
    ----------
    tracks
        The measured tracks (`read_tracks`).
    config
        The scene's known parameters (a level's `EnvConfig` with overrides); a fitted
        parameter starts from its value there.
    fit
        The parameters to fit.
    drive
        'omega', 'voltage' or None/'auto' (`choose_drive`).
    segment
        Shooting segments' length [s], 0.02-2.
    position_noise, omega_noise
        The camera's and the tachometer's noise [m], [rad/s], the
        residuals' starting weights (default: the config's noise, else 1 mm and 0.2 rad/s);
        after a first fit each is re-estimated from its residuals' spread and the fit
        repeated (up to twice), so the intervals follow the data's own noise.
    max_iterations
        Jacobian evaluations at most (1-1000).
    progress
        Called with a line per iteration (default: silent).

    Returns
    -------
    FitResult
        The estimates, the fitted options for ``gym.make`` and the fit's diagnostics.

    Raises
    ------
    ValueError
        If there are no tracks, a track has too few tracked frames, or an argument is out
        of range (the message names it).
    """
    say = progress or (lambda _: None)
    tracks = list(tracks)
    _check_arguments(tracks, config, segment, max_iterations)
    drive = choose_drive(tracks, fit, drive)
    names = check_fit_names(fit, config, drive)
    config = prepare_config(config, names)
    sigma, sigma_w = _noise_weights(tracks, config, position_noise, omega_noise)
    plans = [plan_track(t, drive, segment) for t in tracks]
    model = Model(config, plans, names, drive, float(sigma), float(sigma_w), rtol=rtol)
    if model.layout.size > MAX_UNKNOWNS:
        raise ValueError(f"{model.layout.size:,} unknowns (segment starts' states): at most "
                         f"{MAX_UNKNOWNS:,}; fit fewer or shorter tracks, or longer segments")
    # The fit's linear algebra is a few hundred columns while numba integrates in threads: a
    # threaded OpenBLAS waking its workers on a busy machine took 4 s per SVD instead of 0.1.
    from ..jobs.blas import blas_threads
    with blas_threads(1):   # back to the caller's count after
        n_frames = sum(len(p.t) for p in plans)
        say(f"fitting {list(names)} to {len(tracks)} track(s), {n_frames} frames, drive "
            f"{drive!r}, {sum(p.segments for p in plans)} segments of ~{segment:g} s, "
            f"{model.layout.size} unknowns")
        lo, hi = _bounds(model)
        v0 = initial_vector(model, say)
        obj = _Objective(model, lo, hi, say)
        status = "converged"
        iterations = 0
        try:
            v, status = _solve(model, obj, v0, lo, hi, max_iterations, say)
            if status == "converged" and "obs_delay" in names and _odd_tracks(model, v):
                v = _restart_latency(model, plans, v, v0, lo, hi, max_iterations, say)
            iterations = obj.iteration
        except KeyboardInterrupt:
            if obj.best_x is None:
                raise
            say("interrupted: reporting the best point so far")
            v, status = obj.best_x, "interrupted"
            iterations = obj.iteration
        return summarise(model, v, v0, obj, names, status, iterations, say)


def _solve(model: Model, obj: _Objective, v: np.ndarray, lo: np.ndarray, hi: np.ndarray,
           max_iterations: int, say: Callable[[str], None],
           reweight: bool = True) -> tuple[np.ndarray, str]:
    """Least squares from ``v``; then (``reweight``) the camera's and the tachometer's noise
    from their residuals' own spread and again, up to `REWEIGHTS` times, so that neither
    is trusted more than it earned and the intervals follow the data."""
    for rounds in range(REWEIGHTS + 1):
        sol = least_squares(obj.fun, v, jac=obj.jac, bounds=(lo, hi), x_scale="jac",
                            method="trf", tr_solver="exact", max_nfev=max_iterations * 4,
                            xtol=1e-10, ftol=1e-10, gtol=1e-10)
        v = sol.x
        if sol.status <= 0:
            return v, f"stopped: {sol.message}"
        spread = noise_spread(model, v)
        if not reweight or rounds == REWEIGHTS or all(abs(f - 1.0) < 0.1 for f in spread):
            break
        model.set_noise(model.sigma * spread[0], model.sigma_omega * spread[1])
        obj.best_cost, obj.best_x = math.inf, None
        say(f"reweighting: camera noise {model.sigma * 1e3:.3g} mm, tachometer "
            f"{model.sigma_omega:.3g} rad/s (from the residuals)")
    return v, "converged"


def _odd_tracks(model: Model, v: np.ndarray) -> list[int]:
    """Tracks (3 or more) whose position residual RMS is `ODD_TRACK` times the others'."""
    ev = model.evaluate(v)
    rms = np.array([float(np.sqrt(np.nanmean((p - plan.xy) ** 2)))
                    for p, plan in zip(ev.predicted, model.layout.plans)])
    return [k for k in odd_ratios(rms) if odd_ratios(rms)[k] > ODD_TRACK]


def odd_ratios(rms: np.ndarray) -> dict[int, float]:
    """Each track's residual over the median of the others' (3 tracks or more)."""
    if len(rms) < 3:
        return {}
    return {k: float(rms[k] / max(np.median(np.delete(rms, k)), 1e-300))
            for k in range(len(rms))}


def summarise(model: Model, v: np.ndarray, v0: np.ndarray, obj: _Objective,
              names: tuple[str, ...], status: str, iterations: int,
              say: Callable[[str], None]) -> FitResult:
    """Intervals, per-track residuals, warnings and the environment's options at ``v``."""
    ev = model.evaluate(v)
    J = obj.jac(v)
    r = ev.residuals
    meas = model.measurement_rows()
    n_def = int((~meas).sum())
    dof = max(int(meas.sum()) - (len(v) - n_def), 1)
    scale2 = float(r[meas] @ r[meas]) / dof
    var, _ = covariance(J, scale2)
    values = model.values(v)
    estimates: dict[str, Estimate] = {}
    messages: list[str] = []
    start = model.values(v0)
    for i, n in enumerate(names):
        unit, low_b, high_b, typical, _ = PARAMETERS[n]
        std = math.sqrt(var[i]) if math.isfinite(var[i]) else math.inf
        # an interval wider than every value the parameter may take says nothing
        ok = math.isfinite(std) and Z95 * std < high_b - low_b
        if not ok:
            std = math.inf
        low = max(v[i] - Z95 * std, low_b) if ok else -math.inf
        high = min(v[i] + Z95 * std, high_b) if ok else math.inf
        est = Estimate(n, float(v[i]), std, low, high, unit, float(start[n]), ok)
        estimates[n] = est
        if not ok:
            msg = (f"{n} is not identifiable from these tracks (no interval; left at "
                   f"{start[n]:.6g} {unit} in the environment's options): "
                   f"{HINTS.get(n, 'the residuals do not change with it')}")
        elif Z95 * std > max(abs(v[i]), typical):
            msg = (f"{n} is poorly determined: {v[i]:.4g} ± {Z95 * std:.3g} {unit} (95 %); "
                   f"{HINTS.get(n, 'more or longer tracks narrow it')}")
        else:
            continue
        messages.append(msg)
        warnings.warn(msg, FitWarning, stacklevel=3)
        say("warning: " + msg)
    per_track = []
    lay = model.layout
    for k, plan in enumerate(lay.plans):
        d = ev.predicted[k] - plan.xy
        slots = lay.track_slots[k]
        row: dict[str, Any] = {
            "source": plan.track.source, "frames": int(len(plan.t)),
            "segments": plan.segments,
            "rms_m": float(np.sqrt(np.nanmean(d ** 2))),
            "max_defect_sigma": float(np.max(np.abs(ev.defects[k])) / 10.0)
            if ev.defects[k].size else 0.0}
        if "theta0" in slots:
            i = slots["theta0"]
            sd = math.sqrt(var[i]) if math.isfinite(var[i]) else math.inf
            row["theta0"] = wrap(float(v[i]))
            row["theta0_std"] = sd if math.isfinite(sd) else "inf"
        if "omega0" in slots:
            row["omega0"] = float(v[slots["omega0"]])
        per_track.append(row)
    rms = np.array([t["rms_m"] for t in per_track])
    for k, ratio in odd_ratios(rms).items():
        if ratio > ODD_TRACK:
            msg = (f"{per_track[k]['source']}: residual {rms[k] * 1e3:.3g} mm, {ratio:.2g}x "
                   f"the other tracks': mistracked, or the fit sits in a wrong minimum (the "
                   f"intervals assume it does not); look at it in the plot, fit without "
                   f"it, or start from other values (--set)")
            messages.append(msg)
            warnings.warn(msg, FitWarning, stacklevel=3)
            say("warning: " + msg)
    if ev.failed:
        msg = (f"{ev.failed} segment(s) failed to integrate at the fitted point; their "
               f"residuals are placeholders: check the scene's known parameters")
        messages.append(msg)
        warnings.warn(msg, FitWarning, stacklevel=3)
    env_options = env_options_of(model.config, estimates, values)
    noise = {"position_m": model.sigma, "omega_rad_s": model.sigma_omega}
    return FitResult(estimates, per_track, env_options, model.drive, 0.5 * float(r @ r),
                     math.sqrt(scale2), iterations, status, messages, noise, model, v)


def env_options_of(config: EnvConfig, estimates: dict[str, Estimate],
                   values: dict[str, float]) -> dict[str, Any]:
    """The environment's options of the fitted scene: each fitted option (the axis offset is
    the tracker's, not the scene's), the ball's size, and what the fit replaced (a fitted
    quadratic drag in place of ``ball_density``, one ball in place of ``ball_radii``)."""
    out: dict[str, Any] = {"R": config.R, "ball_radii": None}
    if config.ball_density is None:
        out["ball_density"] = None
    for n, e in estimates.items():
        if PARAMETERS[n][4] and e.identifiable:   # an unidentifiable value is no estimate
            out[n] = values[n]
    if "mu" in out and config.mu_static is not None and config.mu_static < out["mu"]:
        out["mu_static"] = out["mu"]
    if config.action_mode == "voltage":
        top = out.get("motor_gain", config.motor_gain) * config.voltage_max
        if top > config.omega_max:   # the env requires K·V_max <= omega_max
            out["omega_max"] = math.ceil(top * 100.0) / 100.0
    return out


__all__ = ["Estimate", "FitResult", "FitWarning", "covariance", "fit_tracks"]
