"""A real saddle's releases, simulated: the lab's objects, its launcher and its imperfections.

`LabModel` holds what a real rig adds to the rigid-ball model, one frozen, validated
dataclass: the saddle's tilt, its square outline, the launcher's spread, the drive's speed
error, the steel ball's rolling resistance and the droplet's vapour-film drag and
evaporation. `release_times` simulates releases like the lab's (at rest in the laboratory
near the centre, at a random turn of the saddle) until each ball leaves the saddle;
`predict_lifetimes` turns them into mean trapping times, with a droplet's evaporation on
top.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields, replace
from importlib import resources
from typing import Any, Literal

import numpy as np

from ..runner import initial_state, run_batch
from ..scene import MAX_TILT, Scene, finite_number

LabObject = Literal["steel", "ln2"]
OBJECTS: tuple[LabObject, ...] = ("steel", "ln2")
# Steel balls a saddle can carry [mm]: the lab's are 6.3 and 19; the top keeps R below the
# flattest saddle's half curvature radius only where the scene says so (`Scene`).
DIAMETER_RANGE_MM = (1.0, 60.0)
MAX_RELEASES = 2000  # per speed: beyond this a curve takes minutes, not seconds
MAX_RPS = 20.0  # revolutions per second: far above any saddle's detachment speed
STEEL_ALPHA = 0.4  # a solid ball, I = 2/5 m R²
REFERENCE_DIAMETER_MM = 19.0  # the ball `LabModel.rolling_drag` is given for
CALIBRATION_FILE = "calibration.json"
# The drive's speed error, as a fraction: 0.2 keeps every drawn speed positive (5 standard
# deviations) and is far beyond any rig a speed is quoted for.
MAX_SPEED_SPREAD = 0.2


@dataclass(frozen=True)
class LabModel:
    """What a real rotating saddle adds to the rigid-ball model (SI units).

    Parameters
    ----------
    tilt : float
        The saddle's axis from the vertical [rad] (`Scene.tilt`), ``0 <= tilt <= 0.2``.
    rolling_resistance : float
        A steel ball's rolling-resistance coefficient c_rr (`Scene.rolling_resistance`): a
        torque c_rr·R·N against its rolling, whatever its speed.
    rolling_drag : float
        A steel ball's viscous loss as it rolls on the saddle [1/s], for a 19 mm ball: a drag
        against its velocity relative to the surface (`Scene.surface_drag`). It scales as
        1/diameter²: the viscous force in the thin gap at the contact grows as the ball's
        radius, and is shared by a mass that grows as its cube.
    film_drag : float
        A droplet's drag against its velocity relative to the saddle [1/s]
        (`Scene.surface_drag`): the vapour film it glides on.
    launch_spread : float
        Standard deviation [m] of each coordinate of the release point around the centre.
    launch_speed_spread : float
        Standard deviation [m/s] of each horizontal component of the release velocity,
        about rest in the laboratory; the ball does not spin in the laboratory.
    speed_spread : float
        Relative standard deviation of the saddle's true speed about the stated one, drawn
        once per release (a speed set by hand and read off a meter is known to a percent or
        so): a release at a stated Ω turns at Ω·(1 + speed_spread·z), z standard normal,
        at most 0.2.
    evaporation_mean, evaporation_spread : float
        A droplet's life before it has evaporated [s]: normal with this mean and standard
        deviation (drawn again below 0.1 s). Its trapping time is the shorter of that and
        the time it leaves the saddle.
    half_width : float
        Half the side of the square saddle [m] (the lab measured its saddles to ±80 mm).
    g : float
        Gravitational acceleration [m/s²].
    t_max : float
        A release still on the saddle after this long [s] counts as trapped this long.
    rtol : float
        The integrator's relative tolerance; lifetimes, not trajectories, are wanted.
    """

    tilt: float = 0.0
    rolling_resistance: float = 0.0
    rolling_drag: float = 0.0
    film_drag: float = 0.0
    launch_spread: float = 1e-3
    launch_speed_spread: float = 0.0
    speed_spread: float = 0.0
    evaporation_mean: float = math.inf
    evaporation_spread: float = 0.0
    half_width: float = 0.08
    g: float = 9.81
    t_max: float = 120.0
    rtol: float = 1e-7

    def __post_init__(self) -> None:
        for f in fields(self):
            value = finite_number(f.name, getattr(self, f.name)) \
                if f.name != "evaporation_mean" else float(getattr(self, f.name))
            if math.isnan(value) or value < 0:
                raise ValueError(f"{f.name} must be >= 0, got {value}")
            object.__setattr__(self, f.name, value)
        if self.speed_spread > MAX_SPEED_SPREAD:
            raise ValueError(f"speed_spread must satisfy 0 <= speed_spread <= "
                             f"{MAX_SPEED_SPREAD} (a fraction of the speed), got "
                             f"{self.speed_spread:g}")
        if self.tilt > MAX_TILT:
            raise ValueError(f"tilt must satisfy 0 <= tilt <= {MAX_TILT} rad, got {self.tilt:g}")
        for name in ("half_width", "g", "t_max", "rtol", "evaporation_mean"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")

    def with_(self, **changes: float) -> LabModel:
        """A copy with some parameters changed (validated again)."""
        return replace(self, **changes)

    def as_dict(self) -> dict[str, float]:
        """Every parameter by name (SI units)."""
        return asdict(self)

    def scene(self, c_plus: float, c_minus: float, obj: str,
              diameter_mm: float | None = None) -> Scene:
        """The scene of one release: the saddle z = c₊x² − c₋y² and the object on it."""
        common = dict(g=self.g, rim_radius=self.half_width, rim_shape="square", tilt=self.tilt)
        if obj == "ln2":
            return Scene.from_curvatures(c_plus, c_minus, R=0.0, contact="point",
                                         surface_drag=self.film_drag, **common)
        if diameter_mm is None:
            raise ValueError("a steel ball needs diameter_mm")
        return Scene.from_curvatures(c_plus, c_minus, R=diameter_mm / 2000.0, contact="rolling",
                                     alpha=STEEL_ALPHA,
                                     rolling_resistance=self.rolling_resistance,
                                     surface_drag=self.rolling_drag
                                     * (REFERENCE_DIAMETER_MM / diameter_mm) ** 2, **common)


@dataclass(frozen=True)
class LifetimePrediction:
    """Predicted trapping times, per speed, and the model that made them.

    Parameters
    ----------
    rps : numpy.ndarray
        The saddle's speeds [revolutions per second].
    mean_s : numpy.ndarray
        Per speed, the mean trapping time over the releases [s].
    std_s : numpy.ndarray
        Per speed, the sample standard deviation over the releases [s] (ddof 1, as the lab's
        spread and the fit's).
    lifetimes : numpy.ndarray
        Each release's trapping time [s], shape (speeds, releases).
    model : dict
        The model's parameters, as ``--json`` prints them.
    mean_s_95 : numpy.ndarray
        Per speed, a 95 % interval for the mean trapping time [s], shape (speeds, 2): the
        simulated releases' sampling error combined with the calibration's uncertainty and,
        with the shipped calibration, the model's own error that its residuals call for
        (`mean_interval`); ``model["mean_s_95_covers"]`` says what it covers.
    """

    rps: np.ndarray
    mean_s: np.ndarray
    std_s: np.ndarray
    lifetimes: np.ndarray
    model: dict[str, object]
    mean_s_95: np.ndarray

    def as_json(self) -> dict[str, object]:
        """What ``saddle-lifetimes --json`` prints: rps, mean_s, std_s, mean_s_95 (a
        [low, high] pair per speed) and the model."""
        return {"rps": [float(f) for f in self.rps],
                "mean_s": [float(m) for m in self.mean_s],
                "std_s": [float(s) for s in self.std_s],
                "mean_s_95": [[float(lo), float(hi)] for lo, hi in self.mean_s_95],
                "model": self.model}


def check_request(c_plus: object, c_minus: object, obj: object, diameter_mm: object,
                  rps: object, releases: object) -> tuple[float, float, str, float | None,
                                                          np.ndarray, int]:
    """Validate a prediction's inputs; a ValueError names the parameter and its range."""
    cp = finite_number("c_plus", c_plus)
    cm = finite_number("c_minus", c_minus)
    for name, c in (("c_plus", cp), ("c_minus", cm)):
        if c <= 0:
            raise ValueError(f"{name} must be > 0 (curvature in 1/m), got {c:g}")
    if not isinstance(obj, str) or obj not in OBJECTS:
        raise ValueError(f"object must be one of {OBJECTS}, got {obj!r}")
    d: float | None = None
    if obj == "steel":
        if diameter_mm is None:
            raise ValueError("diameter_mm is required for a steel ball (mm, "
                             f"{DIAMETER_RANGE_MM[0]:g}-{DIAMETER_RANGE_MM[1]:g})")
        d = finite_number("diameter_mm", diameter_mm)
        lo, hi = DIAMETER_RANGE_MM
        limit = 1000.0 / max(cp, cm)  # R < min(a, b)/2, in mm of diameter
        if not lo <= d <= hi or d >= limit:
            raise ValueError(f"diameter_mm must lie in [{lo:g}, {hi:g}] mm and below "
                             f"{limit:.4g} mm (the ball must fit the saddle's curvature), "
                             f"got {d:g}")
    elif diameter_mm is not None:
        raise ValueError("diameter_mm applies to object 'steel' only (a droplet is point-like)")
    try:
        speeds = np.atleast_1d(np.asarray(rps, dtype=float))
    except (TypeError, ValueError):
        raise ValueError(f"rps must be numbers (revolutions per second), got {rps!r}") from None
    if speeds.ndim != 1 or speeds.size == 0:
        raise ValueError("rps must be one or more speeds (revolutions per second)")
    if not np.all(np.isfinite(speeds)) or np.any(speeds <= 0) or np.any(speeds > MAX_RPS):
        raise ValueError(f"rps must be > 0 and <= {MAX_RPS:g} revolutions per second, got "
                         f"{speeds.tolist()}")
    if isinstance(releases, bool) or not isinstance(releases, (int, np.integer)):
        raise ValueError(f"releases must be a whole number, got {releases!r}")
    if not 2 <= int(releases) <= MAX_RELEASES:
        raise ValueError(f"releases must lie in [2, {MAX_RELEASES}] per speed (a spread needs "
                         f"two), got {releases}")
    return cp, cm, obj, d, speeds, int(releases)


def release_times(model: LabModel, c_plus: float, c_minus: float, obj: str,
                  diameter_mm: float | None, rps: np.ndarray, releases: int,
                  seed: int) -> np.ndarray:
    """When each release leaves the saddle [s] (``model.t_max`` if it has not),
    speeds × releases. Releases like the lab's: at rest in the laboratory at a point drawn
    around the centre, not spinning, at a random turn of the saddle. The draws depend on
    ``seed`` only (not on the model), so two models see the same releases."""
    scene = model.scene(c_plus, c_minus, obj, diameter_mm)
    rng = np.random.default_rng(seed)
    n = len(rps) * releases
    xy = rng.normal(0.0, 1.0, size=(n, 2)) * model.launch_spread
    angle = rng.uniform(0.0, 2.0 * math.pi, size=n)
    kick = rng.normal(0.0, 1.0, size=(n, 2)) * model.launch_speed_spread
    omega = np.repeat(2.0 * math.pi * np.asarray(rps, dtype=float), releases)
    # The speed error has its own stream of the seed: the other draws do not move with it.
    omega = omega * speed_factor(model.speed_spread,
                                 np.random.default_rng([seed, 2]).standard_normal(n))
    point = scene.with_(R=0.0, contact="point", rolling_resistance=0.0, surface_drag=0.0)
    states = np.zeros((n, scene.state_size))
    for i in range(n):
        # At rest in the laboratory: the contact point's velocity relative to the saddle is
        # the tangential part of -Ω k×c (`initial_state`'s "lab-rest"), and a ball that does
        # not spin in the laboratory spins at -Ω about the vertical relative to the saddle.
        v = initial_state(point, xy[i, 0], xy[i, 1], start="lab-rest", omega=omega[i])[2:4]
        v = v + _to_saddle_axes(kick[i], angle[i])
        if scene.rolling:
            states[i] = initial_state(scene, xy[i, 0], xy[i, 1], v[0], v[1],
                                      spin_normal=-omega[i])
        else:
            states[i] = initial_state(scene, xy[i, 0], xy[i, 1], v[0], v[1])
    # The batch's threads take contiguous rows: ordered release by release, each thread gets
    # every speed alike (speed by speed, one would get the short low-speed lives and wait for
    # the other). Each row's run is its own, so the order changes no result.
    order = np.arange(n).reshape(len(rps), releases).T.ravel()
    result = run_batch(scene, states[order], model.t_max, omega=omega[order], dt_out=None,
                       rtol=model.rtol, angle=angle[order])
    failed = (result.status < 0)
    if np.any(failed):
        raise RuntimeError(f"{int(failed.sum())} of {n} releases failed to integrate")
    t_final = np.empty(n)
    t_final[order] = result.t_final
    return t_final.reshape(len(rps), releases)


def speed_factor(speed_spread: float, z: np.ndarray | float) -> np.ndarray:
    """The drive's speed error: the saddle turns at this factor times the stated speed,
    1 + ``speed_spread``·z for standard normal draws ``z``, kept above 1e-3 (a speed stays
    positive). `release_times` and the environment's ``speed_error`` both draw it here."""
    return np.maximum(1.0 + speed_spread * np.asarray(z, dtype=float), 1e-3)


def _to_saddle_axes(v: np.ndarray, angle: float) -> np.ndarray:
    """A laboratory vector in the axes of a saddle turned by ``angle``."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * v[0] + s * v[1], -s * v[0] + c * v[1]])


def evaporation_times(model: LabModel, shape: tuple[int, int], seed: int) -> np.ndarray:
    """A droplet's life before it evaporates [s], one per release (its own stream of
    ``seed``, so the escape draws do not move when the evaporation changes)."""
    if not math.isfinite(model.evaporation_mean):
        return np.full(shape, math.inf)
    rng = np.random.default_rng([seed, 1])
    z = rng.standard_normal(shape)
    life = model.evaporation_mean + model.evaporation_spread * z
    return np.maximum(life, 0.1)


def lifetimes_of(model: LabModel, obj: str, escapes: np.ndarray, seed: int) -> np.ndarray:
    """Trapping times from escape times: a droplet's capped by its evaporation."""
    if obj == "ln2":
        return np.minimum(escapes, evaporation_times(model, escapes.shape, seed))
    return escapes


def load_calibration() -> tuple[LabModel, dict[str, Any]]:
    """The shipped calibration (`saddle_env.lifetimes.fit` writes it).

    Returns
    -------
    model : LabModel
        The calibrated model.
    record : dict
        How it was fitted: the fit's settings, the objective and the bootstrap intervals.
    """
    text = resources.files(__package__).joinpath(CALIBRATION_FILE).read_text(encoding="utf-8")
    record = json.loads(text)
    known = {f.name for f in fields(LabModel)}
    params = {k: (math.inf if v is None else float(v)) for k, v in record["model"].items()
              if k in known}
    return LabModel(**params), record


def predict_lifetimes(c_plus: float, c_minus: float, object: str,  # noqa: A002
                      rps: float | list[float] | np.ndarray, *,
                      diameter_mm: float | None = None, releases: int = 24, seed: int = 0,
                      tilt: float | None = None, model: LabModel | None = None,
                      calibration_models: int = 8) -> LifetimePrediction:
    """Mean trapping times of releases like the lab's on a real saddle.

    Parameters
    ----------
    c_plus, c_minus : float
        The saddle z = c₊x² − c₋y² [1/m], both > 0.
    object : {"steel", "ln2"}
        A solid steel ball that rolls (needs ``diameter_mm``), or a liquid-nitrogen droplet:
        a frictionless point that slides on its vapour film and evaporates.
    rps : float or sequence of float
        The saddle's speeds [revolutions per second], each > 0.
    diameter_mm : float, optional
        The steel ball's diameter [mm].
    releases : int
        Releases simulated per speed (1-2000).
    seed : int
        Seed of the release points, saddle turns and evaporation times.
    tilt : float, optional
        Overrides the model's tilt [rad]; 0 is a level saddle.
    model : LabModel, optional
        The imperfections; by default the project's calibration (`load_calibration`).
    calibration_models : int
        Models of the calibration's uncertainty simulated for ``mean_s_95`` (`spread_models`;
        the model's own error the calibration found is added with them; 0: the releases'
        sampling error only). A ``model`` given carries no calibration
        uncertainty, so then none is simulated.

    Returns
    -------
    LifetimePrediction
        ``model`` holds every parameter used, the object and the saddle included;
        ``mean_s_95`` the 95 % interval of each mean.
    """
    cp, cm, obj, d, speeds, n = check_request(c_plus, c_minus, object, diameter_mm, rps,
                                              releases)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative whole number, got {seed!r}")
    if isinstance(calibration_models, bool) or not isinstance(calibration_models, int) \
            or not 0 <= calibration_models <= 64:
        raise ValueError("calibration_models must be a whole number in [0, 64], got "
                         f"{calibration_models!r}")
    calibration: dict[str, Any]
    if model is None:
        base, calibration = load_calibration()
    else:
        base, calibration = model, {}
    if tilt is not None:
        base = base.with_(tilt=finite_number("tilt", tilt))
    life = _lifetimes(base, cp, cm, obj, d, speeds, n, int(seed))
    # The calibration's uncertainty: the same releases under models that span it (the tilt,
    # if given, is not uncertain). A model of the user's own carries none.
    others = [m if tilt is None else m.with_(tilt=base.tilt)
              for m in spread_models(calibration, base, calibration_models, int(seed))]
    curves = [life] + [_lifetimes(m, cp, cm, obj, d, speeds, n, int(seed)) for m in others]
    # The model's own error, as the calibration's residuals put it: part of the calibration's
    # uncertainty (none with calibration_models=0, a calibration of before that estimate, or
    # a model of the user's own).
    error = float(calibration.get("model_error_ln") or 0.0) if others else 0.0
    record: dict[str, Any] = {
        **{k: (None if isinstance(v, float) and math.isinf(v) else v)
           for k, v in base.as_dict().items()},
        "c_plus": cp, "c_minus": cm, "object": obj, "diameter_mm": d, "releases": n,
        "seed": int(seed), "alpha": STEEL_ALPHA if obj == "steel" else None,
        "contact": "rolling" if obj == "steel" else "point",
        "release": "at rest in the laboratory, not spinning, at a random turn of the saddle",
        "mean_s_95_covers": _covers(len(others), calibration, error),
    }
    return LifetimePrediction(speeds, life.mean(axis=1), life.std(axis=1, ddof=1), life, record,
                              mean_interval(curves, extra_var=np.full(len(speeds), error ** 2)))


def _covers(models: int, calibration: dict[str, Any], error: float) -> str:
    """What ``mean_s_95`` covers, in words."""
    parts = ["the releases' sampling error"]
    if models:
        parts.append(f"the calibration's uncertainty ({models} models "
                     f"{calibration_source(calibration)})")
    if error:
        parts.append(f"the model's own error ({error:.2f} in ln, from the calibration's "
                     "residuals)")
    return ", ".join(parts[:-1]) + " and " + parts[-1] if len(parts) > 1 \
        else parts[0] + " only"


def _lifetimes(model: LabModel, cp: float, cm: float, obj: str, d: float | None,
               speeds: np.ndarray, n: int, seed: int) -> np.ndarray:
    return lifetimes_of(model, obj, release_times(model, cp, cm, obj, d, speeds, n, seed), seed)


def calibration_source(record: dict[str, Any]) -> str:
    """Where `spread_models` takes its models from, in words."""
    if record.get("bootstrap_models"):
        return "of the calibration's bootstrap"
    return "drawn from the calibration's 95 % bootstrap intervals, each parameter on its own"


def spread_models(record: dict[str, Any], base: LabModel, k: int, seed: int) -> list[LabModel]:
    """``k`` models that span the calibration's uncertainty (none if ``record`` has none).

    The bootstrap's own fitted models where the calibration keeps them (``bootstrap_models``,
    ``k`` of them chosen by the seed); otherwise, for a calibration that kept only its
    intervals, each parameter drawn on its own among the grid values inside its 95 %
    interval (uniformly between the ends where the grid has none there). The second ignores
    how the parameters move together, so it errs towards a wider interval.
    """
    if k == 0:
        return []
    rng = np.random.default_rng([seed, 3])
    known = {f.name for f in fields(LabModel)}
    kept = record.get("bootstrap_models") or []
    if kept:
        chosen = rng.choice(len(kept), size=min(k, len(kept)), replace=False)
        return [base.with_(**{n: (math.inf if v is None else float(v))
                              for n, v in kept[int(i)].items() if n in known})
                for i in sorted(chosen)]
    intervals, grid = record.get("intervals_95") or {}, record.get("grid") or {}
    out = []
    for _ in range(k):
        changes: dict[str, float] = {}
        for name, bounds in intervals.items():
            if name not in known or None in bounds:  # an open end (no evaporation): kept
                continue
            lo, hi = (float(b) for b in bounds)
            inside = [float(v) for v in grid.get(name) or () if v is not None and lo <= v <= hi]
            changes[name] = float(rng.choice(inside)) if inside else float(rng.uniform(lo, hi))
        out.append(base.with_(**changes))
    return out


def mean_interval(curves: list[np.ndarray], level: float = 0.95,
                  extra_var: np.ndarray | None = None) -> np.ndarray:
    """A ``level`` interval for the mean lifetime per speed, shape (speeds, 2).

    Each curve (speeds × releases, one per model) gives the log of its mean with the
    standard error of that log, s / (mean √n); the interval holds the central ``level`` of
    the equal mixture of these normals in ln(mean): the spread between models (the
    calibration's uncertainty) and within each (the releases' sampling error) together.
    ``extra_var`` (per speed, in ln², optional) widens every model's normal alike: the
    coverage check uses it for what a lab's own mean of few releases adds.
    """
    from scipy.special import ndtr  # scipy only where an interval is made

    means = np.array([c.mean(axis=1) for c in curves])  # models × speeds
    n = curves[0].shape[1]
    se = np.array([c.std(axis=1, ddof=1) for c in curves]) / (means * math.sqrt(n))
    mu = np.log(means)
    # a speed where every release lived alike (all kept to t_max) has no sampling error;
    # a floor of 1e-6 in ln keeps the mixture a distribution there
    se = np.maximum(se, 1e-6)
    if extra_var is not None:
        se = np.sqrt(se * se + np.asarray(extra_var, dtype=float)[None, :])
    out = np.empty((means.shape[1], 2))
    for j in range(means.shape[1]):
        for col, q in enumerate(((1 - level) / 2, (1 + level) / 2)):
            lo, hi = float(np.min(mu[:, j] - 8 * se[:, j])), float(np.max(mu[:, j] + 8 * se[:, j]))
            for _ in range(60):  # bisection on the mixture's distribution function
                mid = 0.5 * (lo + hi)
                if float(np.mean(ndtr((mid - mu[:, j]) / se[:, j]))) < q:
                    lo = mid
                else:
                    hi = mid
            out[j, col] = math.exp(0.5 * (lo + hi))
    return out
