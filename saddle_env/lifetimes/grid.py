"""Escape times of the lab's series over a grid of imperfections, simulated once and kept.

The fit, its bootstrap and the leave-one-series-out check all choose among the same
simulated curves, so each curve is simulated once (`simulate_grid`) and stored as
``<out>/escapes.npz`` as it comes: an interrupted run (Ctrl-C, SIGTERM) keeps what it has
and resumes where it stopped. Every grid point sees the same releases (`release_times`
draws them from the seed only). A droplet's evaporation is applied afterwards
(`model.lifetimes_of`), so it costs no simulation.
"""

from __future__ import annotations

import itertools
import math
import time
from pathlib import Path

import numpy as np

from ..jobs.files import atomic_open
from ..jobs.signals import sigterm_interrupts
from .data import Series
from .model import LabModel, release_times

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


def shared_points() -> list[tuple[float, float, float, float]]:
    """The grid of the parameters every object shares (the tilt, the launcher's spreads and
    the speed's)."""
    return list(itertools.product(TILTS, LAUNCH_SPREADS, LAUNCH_SPEED_SPREADS, SPEED_SPREADS))


def own_points(obj: str) -> list[tuple[float, float]]:
    """The grid of the object ``obj``'s own dissipation parameters."""
    if obj == "steel":
        return list(itertools.product(ROLLING_RESISTANCES, ROLLING_DRAGS))
    return [(d, 0.0) for d in FILM_DRAGS]


def grid_points(obj: str) -> list[Point]:
    """The points simulated for an object."""
    return [shared + own for shared in shared_points() for own in own_points(obj)]


def point_model(obj: str, point: Point) -> LabModel:
    """The model of a grid point (without evaporation)."""
    tilt, spread, launch_speed_spread, speed_spread, first, second = point
    common = dict(tilt=tilt, launch_spread=spread, launch_speed_spread=launch_speed_spread,
                  speed_spread=speed_spread)
    if obj == "steel":
        return LabModel(rolling_resistance=first, rolling_drag=second, **common)
    return LabModel(film_drag=first, **common)


def _key(index: int, point: Point) -> str:
    return f"s{index}_" + "_".join(f"{v:.6g}" for v in point)


def simulate_grid(series: list[Series], out: Path, *, releases: int, seed: int,
                  progress: bool = True) -> dict[str, np.ndarray]:
    """Escape times (speeds × releases) of every series at every grid point of its object,
    keyed ``s<series index>_<point's values>``; read from and saved to
    ``out/escapes.npz`` (a file of plain arrays, read without pickle)."""
    path = Path(out) / "escapes.npz"
    done: dict[str, np.ndarray] = {}
    if path.exists():
        with np.load(path, allow_pickle=False) as f:
            done = {k: f[k] for k in f.files}
        if "meta" in done and tuple(done["meta"]) != (releases, seed):
            raise ValueError(f"{path} holds a grid of releases={int(done['meta'][0])}, "
                             f"seed={int(done['meta'][1])}; use another --out or the same "
                             "settings")
    done["meta"] = np.array([releases, seed])
    todo = [(i, s, p) for i, s in enumerate(series) for p in grid_points(s.obj)
            if _key(i, p) not in done]
    total = sum(len(grid_points(s.obj)) for s in series)
    start, last_save = time.monotonic(), time.monotonic()
    with sigterm_interrupts() as record:
        try:
            for n, (i, s, p) in enumerate(todo, 1):
                model = point_model(s.obj, p)
                done[_key(i, p)] = release_times(model, s.c_plus, s.c_minus, s.obj,
                                                 s.diameter_mm, s.rps, releases, seed)
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


def escapes_of(table: dict[str, np.ndarray], index: int, point: Point) -> np.ndarray:
    """Series ``index``'s simulated escape times at grid ``point``."""
    return table[_key(index, point)]
