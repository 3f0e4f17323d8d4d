"""Calibrate the real-saddle model on the lab's series, with intervals and a held-out check.

``python -m saddle_env.lifetimes.fit --out runs/lifetimes`` simulates the grid
(`saddle_env.lifetimes.grid`), then:

* **fits** the imperfections to every series at once. The objective is a weighted sum of
  squares of log lifetimes: over series and speeds, (ln predicted − ln measured)² /
  (σ_lab² + σ_sim² + 0.1²), where σ_lab and σ_sim are the standard errors of the log of the
  lab's and the simulation's mean, and 0.1 stands for the model's own error (a tenth of a
  lifetime). A steel ball's rolling resistance and a droplet's surface drag and evaporation
  are its own; the tilt, the launcher's spread and the speed's are shared by all series;
* gives **intervals** by bootstrap: each speed's releases are drawn again from the lab's and
  the fit repeated (the 2.5th and 97.5th percentiles of the grid values chosen);
* checks the **prediction** series by series (leave-one-series-out): calibrated on the others,
  each series is predicted and its onset, cutoff and median |ln(predicted/measured)| are
  compared with the lab's; the same for restricted models (rigid ball; tilt only;
  dissipation only), so the table shows what each effect buys.

It writes ``calibration.json`` (``--ship`` also copies it into the package, where
`saddle-lifetimes` reads it; it keeps each bootstrap draw's model, for the predictions'
intervals, and the grid's stated bounds, `PRIORS`), ``validation.json``, ``validation.csv``
and ``lifetimes.png``. Any error ends it with status 2 and a message naming it.

`Fitter` takes its curves from any escape-time source and its values from any `grid.Grid`:
the command gives it the simulated grid; tests/test_lifetimes_fit.py a tiny synthetic one,
where the answer is known.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from datetime import date
from pathlib import Path
from typing import Any

import numpy as np

from ..jobs.files import atomic_open, write_text_atomically
from ..linear import critical_omega, mass_point_band
from ..scene import Scene
from . import grid as G
from .data import Series, cutoff, load_lab_series, median_log_error, onset
from .model import (
    CALIBRATION_FILE,
    MAX_RELEASES,
    STEEL_ALPHA,
    LabModel,
    lifetimes_of,
    load_calibration,
)

# Bounds the grid holds on purpose: a fitted value or an interval at one of them is clipped
# by what is known of the rig, not by a grid too small. Each names its parameter (as
# calibration.json's "model" and "intervals_95" do), the bound and why it is physical;
# tests check that no shipped value sits on a grid edge without one.
PRIORS: dict[str, dict[str, Any]] = {
    "tilt": {"upper": 4e-3, "why": (
        "the lab levelled its saddles to about 3 mrad; a tilt beyond 4 mrad would contradict "
        "how they were set up, so the grid stops there and an interval reaching 4 mrad is "
        "clipped by that bound")},
    "evaporation_spread_fraction": {"upper": 0.45, "why": (
        "a droplet's evaporation time is drawn normal; at a spread of 45 % of its mean, "
        "1.3 % of droplets are drawn with no life at all (cut at 0.1 s), and more spread "
        "gives a droplet put down whole no life more often still, which is not how one "
        "evaporates; so the spread stops at 45 % and an interval reaching it is clipped by "
        "that bound (a broader, skewed evaporation law would be the way past it)")},
}
MODEL_ERROR = 0.1  # the model's own error in ln(lifetime), added to the standard errors
HELD_OUT_DRAWS = 40  # bootstrap fits per held-out series (`validate`)
COMMAND = "python -m saddle_env.lifetimes.fit --out runs/lifetimes --ship"

# The restricted models of the validation table: which grid values each may use.
VARIANTS: dict[str, dict[str, Any]] = {
    "rigid ball": dict(tilt=(0.0,), speed_spread=(0.0,), own=False, evaporation=(math.inf,)),
    "+ tilt, speed error": dict(own=False, evaporation=(math.inf,)),
    "+ dissipation": dict(tilt=(0.0,), speed_spread=(0.0,)),
    "calibrated": {},
}


@dataclass(frozen=True)
class Choice:
    """A fitted set of imperfections (a grid point per object) and its objective."""

    tilt: float
    launch_spread: float
    launch_speed_spread: float
    speed_spread: float
    rolling_resistance: float
    rolling_drag: float
    film_drag: float
    evaporation_mean: float
    evaporation_fraction: float
    objective: float

    def model(self) -> LabModel:
        """The lab model with these parameters."""
        finite = math.isfinite(self.evaporation_mean)
        return LabModel(tilt=self.tilt, launch_spread=self.launch_spread,
                        launch_speed_spread=self.launch_speed_spread,
                        speed_spread=self.speed_spread, rolling_resistance=self.rolling_resistance,
                        rolling_drag=self.rolling_drag, film_drag=self.film_drag,
                        evaporation_mean=self.evaporation_mean,
                        evaporation_spread=self.evaporation_fraction * self.evaporation_mean
                        if finite else 0.0)

    def point(self, obj: str) -> G.Point:
        """The grid point of the object ``obj`` ("steel" or a liquid-nitrogen drop)."""
        own = ((self.rolling_resistance, self.rolling_drag) if obj == "steel"
               else (self.film_drag, 0.0))
        return (self.tilt, self.launch_spread, self.launch_speed_spread, self.speed_spread,
                *own)


def _evaporations(allowed: dict, grid: G.Grid) -> list[tuple[float, float]]:
    means = allowed.get("evaporation", grid.evaporation_means)
    return [(m, f) for m in means
            for f in (grid.evaporation_spreads if math.isfinite(m) else (0.0,))]


def curve(escapes: np.ndarray, obj: str, evaporation: tuple[float, float],
          seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean lifetime per speed and the standard error of its log, from escape times."""
    mean_s, frac = evaporation
    model = LabModel(evaporation_mean=mean_s,
                     evaporation_spread=frac * mean_s if math.isfinite(mean_s) else 0.0)
    life = lifetimes_of(model, obj, escapes, seed)
    m = life.mean(axis=1)
    se = life.std(axis=1, ddof=1) / (m * math.sqrt(life.shape[1]))
    return m, se


def lab_terms(lab: Series) -> tuple[np.ndarray, np.ndarray]:
    """ln of the lab's mean lifetime per speed and the square of its standard error."""
    m = lab.mean
    return np.log(m), (lab.std / (m * np.sqrt(lab.counts))) ** 2


def objective_share(log_p: np.ndarray, var_sim: np.ndarray, log_m: np.ndarray,
                    var_lab: np.ndarray) -> float:
    """One series' share of the objective: Σ (ln p − ln m)² / (σ_lab² + σ_sim² + 0.1²)."""
    r = log_p - log_m
    return float(np.sum(r * r / (var_lab + var_sim + MODEL_ERROR ** 2)))


Escapes = Callable[[int, G.Point], np.ndarray]


class Fitter:
    """Chooses grid points for a set of series (`fit`) among simulated curves.

    Parameters
    ----------
    series : list of Series
        The lab's series (their lifetimes are what the fit matches).
    escapes : callable
        ``escapes(i, point)``: series ``i``'s escape times at a grid point, speeds × releases
        (`from_table` reads them from `grid.simulate_grid`'s table; a test passes a small
        synthetic simulator).
    seed : int
        Seed of the droplets' evaporation times (`model.lifetimes_of`).
    grid : Grid
        The values the fit chooses among (default the shipped grid).
    """

    def __init__(self, series: list[Series], escapes: Escapes, seed: int,
                 grid: G.Grid = G.DEFAULT):
        self.series, self.escapes, self.seed, self.grid = series, escapes, seed, grid
        self._curves: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}

    @classmethod
    def from_table(cls, series: list[Series], table: dict[str, np.ndarray], *, releases: int,
                   seed: int, grid: G.Grid = G.DEFAULT) -> Fitter:
        """A fitter over `grid.simulate_grid`'s table of escape times."""
        return cls(series, lambda i, point: G.escapes_of(table, series[i], point,
                                                          releases=releases, seed=seed),
                   seed, grid)

    def curve(self, i: int, point: G.Point,
              evaporation: tuple[float, float] = (math.inf, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """Series ``i``'s predicted curve at grid ``point`` (cached)."""
        key = (i, point, evaporation if self.series[i].obj == "ln2" else None)
        if key not in self._curves:
            self._curves[key] = curve(self.escapes(i, point), self.series[i].obj,
                                      evaporation, self.seed)
        return self._curves[key]

    def log_curve(self, i: int, point: G.Point,
                  evaporation: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """ln of `curve`'s means and the square of its standard errors (cached)."""
        key = ("log", i, point, evaporation if self.series[i].obj == "ln2" else None)
        if key not in self._curves:
            m, se = self.curve(i, point, evaporation)
            self._curves[key] = (np.log(m), se * se)
        return self._curves[key]

    def fit(self, use: list[int], allowed: dict | None = None,
            measured: dict[int, Series] | None = None) -> Choice:
        """The grid point with the least objective over the series ``use``: the tilt and the
        launcher shared, each object's own dissipation (and a droplet's evaporation)."""
        allowed = allowed or {}
        measured = measured or {}
        labs = {i: lab_terms(measured.get(i, self.series[i])) for i in use}

        def cost_of(i: int, point: G.Point, ev: tuple[float, float]) -> float:
            return objective_share(*self.log_curve(i, point, ev), *labs[i])

        best: Choice | None = None
        grid = self.grid
        for shared in grid.shared_points():
            if (shared[0] not in allowed.get("tilt", grid.tilts)
                    or shared[3] not in allowed.get("speed_spread", grid.speed_spreads)):
                continue
            total, parts = 0.0, {"steel": (0.0, 0.0, math.inf, 0.0),
                                 "ln2": (0.0, 0.0, math.inf, 0.0)}
            for obj in ("steel", "ln2"):
                members = [i for i in use if self.series[i].obj == obj]
                if not members:
                    continue
                owns = grid.own_points(obj) if allowed.get("own", True) else [(0.0, 0.0)]
                evaporations = _evaporations(allowed, grid) if obj == "ln2" \
                    else [(math.inf, 0.0)]
                options = []
                for own in owns:
                    for ev in evaporations:
                        cost = sum(cost_of(i, shared + own, ev) for i in members)
                        options.append((cost, own, ev))
                cost, own, ev = min(options, key=lambda o: o[0])
                total += cost
                parts[obj] = (*own, *ev)
            if best is None or total < best.objective:
                best = Choice(*shared, parts["steel"][0], parts["steel"][1], parts["ln2"][0],
                              parts["ln2"][2], parts["ln2"][3], total)
        assert best is not None
        return best

    def predicted(self, i: int, choice: Choice) -> np.ndarray:
        """Series ``i``'s predicted mean trapping times under ``choice``."""
        s = self.series[i]
        return self.curve(i, choice.point(s.obj),
                          (choice.evaporation_mean, choice.evaporation_fraction))[0]


def theory_threshold(s: Series, g: float = 9.81) -> float:
    """Rigid-ball theory's threshold [rps]: the rolling ball's Ω_crt, or the mass point's
    lower band edge for a droplet."""
    if s.obj == "steel" and s.diameter_mm is not None:
        scene = Scene.from_curvatures(s.c_plus, s.c_minus, R=s.diameter_mm / 2000.0, g=g,
                                      alpha=STEEL_ALPHA)
        return critical_omega(scene) / (2 * math.pi)
    band = mass_point_band(1.0 / s.c_plus, 1.0 / s.c_minus, g)
    return math.nan if band is None else band[0] / (2 * math.pi)


def bootstrap(fitter: Fitter, draws: int, seed: int, use: list[int] | None = None,
              progress: bool = True) -> list[Choice]:
    """The fit over the series ``use`` (default all) repeated on ``draws`` resamplings of
    their lab releases."""
    rng = np.random.default_rng(seed)
    use = list(range(len(fitter.series))) if use is None else list(use)
    out = []
    for k in range(draws):
        measured = {i: fitter.series[i].resampled(rng) for i in use}
        out.append(fitter.fit(use, measured=measured))
        if progress and (k + 1) % 20 == 0:
            print(f"bootstrap: {k + 1}/{draws}", flush=True)
    return out


def free_parameters(fitter: Fitter, use: list[int]) -> int:
    """How many parameters a fit over the series ``use`` chooses: the four shared ones, the
    steel ball's two if a steel series is among them, a droplet's three if a droplet is."""
    objects = {fitter.series[i].obj for i in use}
    return 4 + 2 * ("steel" in objects) + 3 * ("ln2" in objects)


def _residuals(fitter: Fitter, use: list[int], choice: Choice
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Over the series ``use`` and their speeds, under ``choice``: ln predicted − ln
    measured, the squared standard error of the lab's log mean and of the model's."""
    r, var_lab, var_sim = [], [], []
    for i in use:
        s = fitter.series[i]
        log_p, v_sim = fitter.log_curve(i, choice.point(s.obj),
                                        (choice.evaporation_mean, choice.evaporation_fraction))
        log_m, v_lab = lab_terms(s)
        r.append(log_p - log_m)
        var_lab.append(v_lab)
        var_sim.append(v_sim)
    return np.concatenate(r), np.concatenate(var_lab), np.concatenate(var_sim)


def objective_of(fitter: Fitter, use: list[int], choice: Choice) -> float:
    """The fit's objective of ``choice`` over the series ``use``: each series'
    `objective_share`, summed (in `Fitter.fit`'s order within an object, not across)."""
    total = 0.0
    for i in use:
        s = fitter.series[i]
        total += objective_share(*fitter.log_curve(
            i, choice.point(s.obj), (choice.evaporation_mean, choice.evaporation_fraction)),
            *lab_terms(s))
    return total


def model_error(fitter: Fitter, use: list[int], choice: Choice) -> float:
    """The model's own error in ln(lifetime) that ``choice``'s residuals on the series ``use``
    call for: the s >= 0 at which Σ r² / (σ_lab² + σ_sim² + s²) equals the number of speeds
    less the fitted parameters (a reduced χ² of one), 0 when the standard errors alone
    explain the residuals.

    The objective's 0.1 (`MODEL_ERROR`) is a weight chosen beforehand; this is what the
    data say. A prediction's interval (`model.predict_lifetimes`' ``mean_s_95``) carries it,
    and the held-out check estimates it from the training series only."""
    r, var_lab, var_sim = _residuals(fitter, use, choice)
    res, v = r * r, var_lab + var_sim
    dof = res.size - free_parameters(fitter, use)

    def excess(s: float) -> float:
        return float(np.sum(res / (v + s * s))) - dof

    if dof <= 0 or excess(0.0) <= 0.0:
        return 0.0
    lo, hi = 0.0, 1.0
    while excess(hi) > 0.0:
        lo, hi = hi, 2.0 * hi
    for _ in range(60):  # bisection: the sum falls as s grows
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if excess(mid) > 0.0 else (lo, mid)
    return hi


def validate(fitter: Fitter, draws: int = 0, seed: int = 1,
             progress: bool = False) -> list[dict[str, object]]:
    """Leave-one-series-out rows: every series under every variant; the calibrated rows
    with ``draws`` bootstrap fits of their own (on the other series' releases only)."""
    rows = []
    for i in range(len(fitter.series)):
        for name in VARIANTS:
            rows.append(validation_row(fitter, i, name,
                                       draws if name == "calibrated" else 0, seed))
        if progress:
            print(f"held out: {i + 1}/{len(fitter.series)} series", flush=True)
    return rows


def validation_row(fitter: Fitter, i: int, variant: str, draws: int = 0,
                   seed: int = 1) -> dict[str, object]:
    """Series ``i`` predicted by the model ``variant`` fitted on every other series: the fit
    never sees series ``i``'s lifetimes (only `predicted` and the row's comparison do). With
    ``draws``, the row keeps that many bootstrap fits on the other series
    (``held_out_models``) for the held-out interval (`coverage`, which also estimates the
    model's own error from the other series' residuals)."""
    s = fitter.series[i]
    others = [j for j in range(len(fitter.series)) if j != i]
    choice = fitter.fit(others, VARIANTS[variant])
    pred = fitter.predicted(i, choice)
    extra: dict[str, object] = {}
    if draws:
        extra["held_out_models"] = [choice_dict(c) for c in
                                    bootstrap(fitter, draws, seed + i, others, progress=False)]
    return {
        "series": s.name, "variant": variant, "lab_onset_rps": onset(s.rps, s.mean),
        "theory_threshold_rps": theory_threshold(s),
        "onset_rps": onset(s.rps, pred), "lab_cutoff_rps": cutoff(s.rps, s.mean),
        "cutoff_rps": cutoff(s.rps, pred),
        "median_abs_log_ratio": median_log_error(pred, s.mean),
        "max_predicted_s": float(pred.max()),
        "predicted_s": [float(v) for v in pred],
        "rps": [float(v) for v in s.rps], "lab_mean_s": [float(v) for v in s.mean],
        "lab_std_s": [float(v) for v in s.std],
        "fitted_on_others": choice_dict(choice),
        **extra,
    }


def choice_of(params: dict[str, Any], grid: G.Grid = G.DEFAULT) -> Choice:
    """The `Choice` whose `choice_dict` is ``params`` (a validation row's or calibration.json's
    model), its evaporation spread back as the grid's fraction of the mean."""
    mean = math.inf if params["evaporation_mean"] is None else float(params["evaporation_mean"])
    fraction = 0.0
    if math.isfinite(mean):
        spread = float(params["evaporation_spread"] or 0.0)
        fraction = min(grid.evaporation_spreads, key=lambda f: abs(f * mean - spread))
    own = {n: float(params[n]) for n in ("tilt", "launch_spread", "launch_speed_spread",
                                         "speed_spread", "rolling_resistance", "rolling_drag",
                                         "film_drag")}
    return Choice(**own, evaporation_mean=mean, evaporation_fraction=fraction,
                  objective=math.nan)


def choice_dict(c: Choice) -> dict[str, float | None]:
    """``c``'s model parameters as calibration.json's "model" holds them (an endless
    evaporation as None)."""
    m = c.model().as_dict()
    return {k: (None if isinstance(v, float) and math.isinf(v) else v) for k, v in m.items()}


def _interval(values: list[float]) -> list[float | None]:
    finite = [v for v in values if math.isfinite(v)]
    if len(finite) < len(values):  # some draws chose no evaporation at all
        return [float(np.percentile(finite, 2.5)) if finite else None, None]
    return [float(np.percentile(values, 2.5)), float(np.percentile(values, 97.5))]


def calibration_record(fitter: Fitter, best: Choice, draws: list[Choice], releases: int,
                       seed: int) -> dict[str, object]:
    """The calibration as ``calibration.json`` holds it: the best fit and bootstrap intervals."""
    names = ("tilt", "launch_spread", "launch_speed_spread", "speed_spread", "rolling_resistance",
             "rolling_drag", "film_drag", "evaporation_mean")
    intervals = {n: _interval([getattr(c, n) for c in draws]) for n in names} if draws else {}
    if draws:
        intervals["evaporation_spread"] = _interval(
            [c.evaporation_fraction * c.evaporation_mean for c in draws
             if math.isfinite(c.evaporation_mean)] or [math.nan])
    return {
        "model": choice_dict(best),
        "intervals_95": intervals,
        "objective": best.objective,
        # what the residuals say of the model's own error (`model_error`), for the
        # predictions' intervals
        "model_error_ln": model_error(fitter, list(range(len(fitter.series))), best),
        "objective_definition": ("sum over series and speeds of (ln predicted - ln measured)^2 "
                                 "/ (se_lab^2 + se_sim^2 + 0.1^2); se = standard error of the "
                                 "log of a mean lifetime"),
        "series": [s.name for s in fitter.series],
        "releases_per_speed": releases, "seed": seed, "bootstrap_draws": len(draws),
        # each draw's fitted parameters, so a prediction can carry the calibration's
        # uncertainty (`model.predict_lifetimes`'s mean_s_95) without refitting
        "bootstrap_models": [choice_dict(c) for c in draws],
        "grid": _grid_record(fitter.grid),
        "priors": PRIORS,
        "command": COMMAND, "date": date.today().isoformat(),
    }


def _grid_record(grid: G.Grid) -> dict[str, list[float | None]]:
    g = grid.as_dict()
    return {"tilt": g["tilts"], "launch_spread": g["launch_spreads"],
            "launch_speed_spread": g["launch_speed_spreads"], "speed_spread": g["speed_spreads"],
            "rolling_resistance": g["rolling_resistances"], "rolling_drag": g["rolling_drags"],
            "film_drag": g["film_drags"], "evaporation_mean": g["evaporation_means"],
            "evaporation_spread_fraction": g["evaporation_spreads"]}


def write_validation(rows: list[dict[str, object]], out: Path) -> None:
    """Write the validation ``rows`` to ``out`` as JSON and CSV."""
    write_text_atomically(out / "validation.json", json.dumps(rows, indent=1) + "\n")
    keys = ("series", "variant", "lab_onset_rps", "theory_threshold_rps", "onset_rps",
            "lab_cutoff_rps", "cutoff_rps", "median_abs_log_ratio", "max_predicted_s")
    with atomic_open(out / "validation.csv") as fh:
        w = csv.writer(fh)
        w.writerow(keys)
        for r in rows:
            w.writerow([r[k] if isinstance(r[k], str) else f"{r[k]:.4g}" for k in keys])


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The parsed command line of ``python -m saddle_env.lifetimes.fit``."""
    p = argparse.ArgumentParser(
        prog="python -m saddle_env.lifetimes.fit",
        description="Calibrate the real-saddle model on the lab's series (grid fit, bootstrap "
                    "intervals, leave-one-series-out validation).")
    p.add_argument("--out", type=Path, default=Path("runs/lifetimes"),
                   help="folder for the grid's escape times, calibration.json, "
                        "validation.json/.csv and lifetimes.png (resumes a grid found there)")
    p.add_argument("--releases", type=int, default=24, help="releases simulated per speed")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated releases")
    p.add_argument("--bootstrap", type=int, default=200,
                   help="bootstrap draws for the intervals (0: none)")
    p.add_argument("--held-out-draws", type=int, default=HELD_OUT_DRAWS,
                   help="bootstrap draws of each held-out fit, for the held-out intervals "
                        "(0: none)")
    p.add_argument("--model-error-only", action="store_true",
                   help="no fit: estimate the shipped calibration's model error again from its "
                        "own curves (simulated, 8 curves) and write calibration.json with it")
    p.add_argument("--ship", action="store_true",
                   help="copy calibration.json into the package (what saddle-lifetimes uses)")
    p.add_argument("--no-progress", action="store_true", help="print no progress lines")
    args = p.parse_args(argv)
    if not 2 <= args.releases <= MAX_RELEASES:
        p.error(f"--releases must lie in [2, {MAX_RELEASES}] (a spread needs two), got "
                f"{args.releases}")
    for name in ("bootstrap", "held_out_draws"):
        if getattr(args, name) < 0:
            p.error(f"--{name.replace('_', '-')} must be >= 0, got {getattr(args, name)}")
    if args.seed < 0:
        p.error(f"--seed must be >= 0, got {args.seed}")
    return args


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (2 with a named message on an error)."""
    args = parse_args(argv)
    try:
        return _run(args)
    except (ValueError, RuntimeError, OSError) as exc:  # a stale grid, a failed release, a disk
        print(f"python -m saddle_env.lifetimes.fit: error: {type(exc).__name__}: {exc}",
              file=sys.stderr)
        return 2


def _run(args: argparse.Namespace) -> int:
    if args.model_error_only:
        return _refresh_model_error(args)
    series = load_lab_series()
    table = G.simulate_grid(series, args.out, releases=args.releases, seed=args.seed,
                            progress=not args.no_progress)
    fitter = Fitter.from_table(series, table, releases=args.releases, seed=args.seed)
    best = fitter.fit(list(range(len(series))))
    draws = bootstrap(fitter, args.bootstrap, args.seed + 1)
    record = calibration_record(fitter, best, draws, args.releases, args.seed)
    write_text_atomically(args.out / CALIBRATION_FILE, json.dumps(record, indent=1) + "\n")
    calibrated = {s.name: [float(v) for v in fitter.predicted(i, best)]
                  for i, s in enumerate(series)}
    write_text_atomically(args.out / "calibrated.json", json.dumps(calibrated, indent=1) + "\n")
    rows = validate(fitter, args.held_out_draws, args.seed + 2, progress=not args.no_progress)
    write_validation(rows, args.out)
    from .figure import plot_validation  # matplotlib only when the figure is made
    plot_validation(series, rows, args.out / "lifetimes.png")
    if args.ship:
        ship(args.out)
    print(json.dumps(record["model"], indent=1))
    print(f"wrote {args.out}/calibration.json, calibrated.json, validation.json, "
          "validation.csv, lifetimes.png")
    return 0


def with_model_error(record: dict[str, Any], series: list[Series]) -> dict[str, Any]:
    """The calibration ``record`` with its model error (`model_error`) estimated from its own
    curves, simulated afresh (a curve per series: no grid, no refit).

    Raises
    ------
    RuntimeError
        If those curves do not give the record's objective: they would not be the curves it
        was fitted on.
    """
    releases, seed = int(record["releases_per_speed"]), int(record["seed"])
    fitter = Fitter(series, G.OnDemand(series, releases, seed), seed)
    everything = list(range(len(series)))
    choice = choice_of(record["model"])
    objective = objective_of(fitter, everything, choice)
    if not math.isclose(objective, record["objective"], rel_tol=1e-9):
        raise RuntimeError(f"the calibration's own curves give the objective {objective!r}, "
                           f"not its {record['objective']!r}: the lab file, the grid or the "
                           "physics changed since it was fitted; refit it")
    return dict(record, model_error_ln=model_error(fitter, everything, choice))


def _refresh_model_error(args: argparse.Namespace) -> int:
    record = with_model_error(load_calibration()[1], load_lab_series())
    args.out.mkdir(parents=True, exist_ok=True)
    write_text_atomically(args.out / CALIBRATION_FILE, json.dumps(record, indent=1) + "\n")
    if args.ship:
        shutil.copyfile(args.out / CALIBRATION_FILE, Path(__file__).parent / CALIBRATION_FILE)
    print(f"model error {record['model_error_ln']:.3f} in ln(lifetime); wrote "
          f"{args.out}/{CALIBRATION_FILE}" + (" and the package's" if args.ship else ""))
    return 0


def ship(out: Path) -> None:
    """Copy the calibration into the package and the check's files into the docs (a clone's
    docs/figures, where the validation page reads them)."""
    package = Path(__file__).parent
    figures = package.parents[1] / "docs" / "figures"
    if not figures.is_dir():
        raise SystemExit(f"--ship needs the repository's docs/figures folder ({figures}): "
                         "run it in a clone")
    shutil.copyfile(out / CALIBRATION_FILE, package / CALIBRATION_FILE)
    shutil.copyfile(out / "validation.json", figures / "lifetimes_validation.json")
    shutil.copyfile(out / "calibrated.json", figures / "lifetimes_calibrated.json")
    shutil.copyfile(out / "lifetimes.png", figures / "lifetimes_validation.png")


if __name__ == "__main__":
    sys.exit(main())
