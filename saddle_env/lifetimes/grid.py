"""Escape times of the lab's series over a grid of imperfections, simulated once and kept.

The fit, its bootstrap and the leave-one-series-out check all choose among the same
simulated curves, so each curve is simulated once (`simulate_grid`) and stored as
``<out>/escapes.npz`` as it comes: an interrupted run (Ctrl-C, SIGTERM) keeps what it has
and resumes where it stopped. Every grid point sees the same releases (`release_times`
draws them from the seed only). A droplet's evaporation is applied afterwards
(`model.lifetimes_of`), so it costs no simulation.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import time
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from ..jobs.files import atomic_open
from ..jobs.signals import sigterm_interrupts
from .data import Series
from .model import MAX_RELEASES, LabModel, release_times

# The grid [SI units]. A point is (tilt, launch spread, launch speed spread, speed spread)
# shared by every series, then the object's own dissipation: a steel ball's (rolling
# resistance, rolling drag), a droplet's (film drag, 0). Zeros included, so the rigid-ball
# model and each effect alone are points of it. A droplet's evaporation (mean [s], spread
# as a fraction of the mean) is chosen afterwards, without simulating again.
TILTS = (0.0, 1e-3, 2e-3, 3e-3, 4e-3)
LAUNCH_SPREADS = (5e-4, 1e-3, 2e-3, 3e-3)
LAUNCH_SPEED_SPREADS = (0.0, 0.01, 0.02)
SPEED_SPREADS = (0.0, 0.01, 0.02, 0.03, 0.05, 0.07, 0.1)  # fractions of the stated speed
ROLLING_RESISTANCES = (0.0, 5e-4, 1e-3, 1.5e-3, 2e-3)
ROLLING_DRAGS = (0.0, 0.03, 0.05, 0.07, 0.1)
FILM_DRAGS = (0.0, 0.2, 0.3, 0.4, 0.5, 0.6)
EVAPORATION_MEANS = (math.inf, 12.0, 15.0, 18.0, 21.0, 24.0, 28.0, 35.0)
EVAPORATION_SPREADS = (0.15, 0.3, 0.45)  # fractions of the mean

Point = tuple[float, float, float, float, float, float]


@dataclass(frozen=True)
class Grid:
    """The values tried for each imperfection; `DEFAULT` is the shipped calibration's grid.

    The fit, its bootstrap and the held-out check take a `Grid`, so a test can run them on a
    tiny one (a few points, a synthetic simulator) in a second.
    """

    tilts: tuple[float, ...] = TILTS
    launch_spreads: tuple[float, ...] = LAUNCH_SPREADS
    launch_speed_spreads: tuple[float, ...] = LAUNCH_SPEED_SPREADS
    speed_spreads: tuple[float, ...] = SPEED_SPREADS
    rolling_resistances: tuple[float, ...] = ROLLING_RESISTANCES
    rolling_drags: tuple[float, ...] = ROLLING_DRAGS
    film_drags: tuple[float, ...] = FILM_DRAGS
    evaporation_means: tuple[float, ...] = EVAPORATION_MEANS
    evaporation_spreads: tuple[float, ...] = EVAPORATION_SPREADS

    def __post_init__(self) -> None:
        for f in fields(self):
            values = tuple(float(v) for v in getattr(self, f.name))
            if not values:
                raise ValueError(f"grid axis {f.name} needs at least one value")
            object.__setattr__(self, f.name, values)

    def shared_points(self) -> list[tuple[float, float, float, float]]:
        """The parameters every object shares (the tilt, the launcher's spreads and the
        speed's)."""
        return list(itertools.product(self.tilts, self.launch_spreads,
                                      self.launch_speed_spreads, self.speed_spreads))

    def own_points(self, obj: str) -> list[tuple[float, float]]:
        """The object ``obj``'s own dissipation parameters."""
        if obj == "steel":
            return list(itertools.product(self.rolling_resistances, self.rolling_drags))
        return [(d, 0.0) for d in self.film_drags]

    def points(self, obj: str) -> list[Point]:
        """The points simulated for an object."""
        return [shared + own for shared in self.shared_points() for own in self.own_points(obj)]

    def as_dict(self) -> dict[str, list[float | None]]:
        """Every axis by name (an endless evaporation as None), as calibration.json holds it."""
        return {f.name: [v if math.isfinite(v) else None for v in getattr(self, f.name)]
                for f in fields(self)}


DEFAULT = Grid()


def shared_points() -> list[tuple[float, float, float, float]]:
    """The shipped grid's shared points (`Grid.shared_points`)."""
    return DEFAULT.shared_points()


def own_points(obj: str) -> list[tuple[float, float]]:
    """The shipped grid's points of the object ``obj``'s own dissipation."""
    return DEFAULT.own_points(obj)


def grid_points(obj: str) -> list[Point]:
    """The shipped grid's points simulated for an object."""
    return DEFAULT.points(obj)


def point_model(obj: str, point: Point) -> LabModel:
    """The model of a grid point (without evaporation)."""
    tilt, spread, launch_speed_spread, speed_spread, first, second = point
    common = dict(tilt=tilt, launch_spread=spread, launch_speed_spread=launch_speed_spread,
                  speed_spread=speed_spread)
    if obj == "steel":
        return LabModel(rolling_resistance=first, rolling_drag=second, **common)
    return LabModel(film_drag=first, **common)


# What the escape times of a stored curve depend on besides its series and point: bumped
# whenever a change to `release_times` or to the integrator moves an escape time, so a run
# resumed after such a change refuses the old file instead of mixing old and new curves.
PHYSICS_VERSION = 1
FORMAT = 2  # escapes.npz layout: 1 keyed curves by series index, 2 by a hash of their inputs


def curve_key(series: Series, point: Point, releases: int, seed: int) -> str:
    """A stored curve's name: a hash of everything its escape times depend on (the series'
    saddle, object and speeds, the grid point, the releases, the seed and `PHYSICS_VERSION`).

    A changed lab file or grid then names different curves, so a resumed run simulates what
    changed and never reads an old curve for it; a point both grids share is reused, as it
    should be (its escape times are the same)."""
    inputs = {"c_plus": series.c_plus, "c_minus": series.c_minus, "object": series.obj,
              "diameter_mm": series.diameter_mm, "rps": [float(f) for f in series.rps],
              "point": [float(v) for v in point], "releases": int(releases), "seed": int(seed),
              "physics": PHYSICS_VERSION}
    text = json.dumps(inputs, sort_keys=True)
    return "c_" + hashlib.sha256(text.encode()).hexdigest()[:24]


def simulate_grid(series: list[Series], out: Path, *, releases: int, seed: int,
                  progress: bool = True, grid: Grid = DEFAULT) -> dict[str, np.ndarray]:
    """Escape times (speeds × releases) of every series at every grid point of its object,
    keyed by `curve_key`; read from and saved to ``out/escapes.npz`` (a file of plain arrays,
    read without pickle).

    Raises
    ------
    ValueError
        If ``releases`` < 2, or the file holds a grid of other releases, seed or physics, or
        of the old layout (keyed by series index, which a changed lab file would mix up).
    """
    if isinstance(releases, bool) or not isinstance(releases, (int, np.integer)) \
            or not 2 <= releases <= MAX_RELEASES:
        raise ValueError(f"releases must lie in [2, {MAX_RELEASES}] per speed (a spread needs "
                         f"two), got {releases!r}")
    path = Path(out) / "escapes.npz"
    meta = np.array([FORMAT, releases, seed, PHYSICS_VERSION])
    done: dict[str, np.ndarray] = {}
    if path.exists():
        with np.load(path, allow_pickle=False) as f:
            done = {k: f[k] for k in f.files}
        old = done.get("meta")
        if old is None or old.size != meta.size or int(old[0]) != FORMAT:
            raise ValueError(f"{path} was written by an older version (curves keyed by series "
                             "index, which a changed lab file would mix up); use another --out")
        if not np.array_equal(old, meta):
            raise ValueError(f"{path} holds a grid of releases={int(old[1])}, seed={int(old[2])}, "
                             f"physics version {int(old[3])}; this run has releases={releases}, "
                             f"seed={seed}, physics version {PHYSICS_VERSION}: use another --out "
                             "or the same settings")
    done["meta"] = meta
    todo = [(s, p) for s in series for p in grid.points(s.obj)
            if curve_key(s, p, releases, seed) not in done]
    total = sum(len(grid.points(s.obj)) for s in series)
    start, last_save = time.monotonic(), time.monotonic()
    with sigterm_interrupts() as record:
        try:
            for n, (s, p) in enumerate(todo, 1):
                model = point_model(s.obj, p)
                done[curve_key(s, p, releases, seed)] = release_times(
                    model, s.c_plus, s.c_minus, s.obj, s.diameter_mm, s.rps, releases, seed)
                if progress and (n % 25 == 0 or n == len(todo)):
                    rate = n / (time.monotonic() - start)
                    print(f"grid: {total - len(todo) + n}/{total} curves "
                          f"({rate:.1f}/s, {(len(todo) - n) / rate:.0f} s left)", flush=True)
                if time.monotonic() - last_save > 60:
                    _save(path, done)
                    last_save = time.monotonic()
                record.raise_if_lost()
        finally:  # what was simulated is kept, whatever stopped the loop
            _save(path, done)
    return done


def _save(path: Path, arrays: dict[str, np.ndarray]) -> None:
    # (numpy's stub types savez's keywords as its own flags, not as names of arrays)
    with atomic_open(path, "wb") as fh:
        np.savez(fh, **arrays)  # type: ignore[arg-type]


def escapes_of(table: dict[str, np.ndarray], series: Series, point: Point, *, releases: int,
               seed: int) -> np.ndarray:
    """``series``' simulated escape times at grid ``point`` (`simulate_grid`'s table)."""
    return table[curve_key(series, point, releases, seed)]


class OnDemand:
    """Escape times read from a `simulate_grid` table where it has them, else simulated when
    first asked for and kept in memory: ``escapes(i, point)`` as `fit.Fitter` takes it, for
    checks that need some of the grid's curves, not all 60,000 (a curve simulated here is
    the one `simulate_grid` would store: the same releases and seed)."""

    def __init__(self, series: list[Series], releases: int, seed: int,
                 table: dict[str, np.ndarray] | None = None):
        self.series, self.releases, self.seed = series, releases, seed
        self.table = table or {}
        self.curves: dict[tuple[int, Point], np.ndarray] = {}

    def __call__(self, i: int, point: Point) -> np.ndarray:
        """Series ``i``'s escape times at grid ``point``, speeds × releases."""
        if (i, point) not in self.curves:
            s = self.series[i]
            stored = self.table.get(curve_key(s, point, self.releases, self.seed))
            self.curves[(i, point)] = stored if stored is not None else release_times(
                point_model(s.obj, point), s.c_plus, s.c_minus, s.obj, s.diameter_mm, s.rps,
                self.releases, self.seed)
        return self.curves[(i, point)]


def stored_curves(out: Path) -> dict[str, np.ndarray]:
    """The curves ``out/escapes.npz`` holds (none if there is no such file), read without
    pickle; `simulate_grid` checks a file's settings before it adds to it, `OnDemand` finds
    curves by their keys, which hold the settings."""
    path = Path(out) / "escapes.npz"
    if not path.exists():
        return {}
    with np.load(path, allow_pickle=False) as f:
        return {k: f[k] for k in f.files if k != "meta"}
