"""The lab's measured trapping times and the figures read off a lifetime curve.

`lab_lifetimes.csv` (shipped beside this module) holds 836 releases on real rotating
saddles from R. Hart's public lab notebooks (2020-21), the measurements behind Barnett et
al. 2025, arXiv:2505.04035: 3D-printed saddles P2, P3 and P4, steel balls of 19 and 6.3 mm
and liquid-nitrogen droplets, 5-16 releases per speed. The numbers are the notebooks' own.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

LAB_FILE = "lab_lifetimes.csv"
COLUMNS = ("date", "saddle", "c_plus_per_m", "c_minus_per_m", "object", "diameter_mm", "rps",
           "release", "lifetime_s")
OBJECT_NAMES = {"steel ball": "steel", "LN2 droplet": "ln2"}


@dataclass(frozen=True)
class Series:
    """One day's releases of one object on one saddle: per speed, every lifetime [s]."""

    date: str
    saddle: str
    c_plus: float
    c_minus: float
    obj: str  # "steel" or "ln2"
    diameter_mm: float | None
    rps: np.ndarray
    lifetimes: tuple[np.ndarray, ...]

    @property
    def name(self) -> str:
        """The series' label: date, saddle and object."""
        what = f"steel {self.diameter_mm:g} mm" if self.obj == "steel" else "LN2 droplets"
        return f"{self.date} {self.saddle} {what}"

    @property
    def mean(self) -> np.ndarray:
        """Mean lifetime per speed [s]."""
        return np.array([t.mean() for t in self.lifetimes])

    @property
    def std(self) -> np.ndarray:
        """Sample standard deviation of the lifetimes per speed [s]."""
        return np.array([t.std(ddof=1) if t.size > 1 else 0.0 for t in self.lifetimes])

    @property
    def counts(self) -> np.ndarray:
        """Releases per speed."""
        return np.array([t.size for t in self.lifetimes])

    def resampled(self, rng: np.random.Generator) -> Series:
        """The same series with each speed's releases drawn again with replacement."""
        return Series(self.date, self.saddle, self.c_plus, self.c_minus, self.obj,
                      self.diameter_mm, self.rps,
                      tuple(rng.choice(t, size=t.size, replace=True) for t in self.lifetimes))


def load_lab_series(path: str | Path | None = None) -> list[Series]:
    """The lab's series of releases, in the file's order.

    Parameters
    ----------
    path : str or Path, optional
        A lifetimes CSV file in the lab's layout; default the shipped one.

    Returns
    -------
    list of Series
        One day's releases of one object on one saddle each.

    Raises
    ------
    ValueError
        If the file is not in the lab's layout, naming what is wrong.
    """
    if path is None:
        text = resources.files(__package__).joinpath(LAB_FILE).read_text(encoding="utf-8")
    else:
        text = Path(path).read_text(encoding="utf-8")
    rows = list(csv.DictReader(text.splitlines()))
    if not rows or tuple(rows[0]) != COLUMNS:
        raise ValueError(f"a lab lifetimes file needs the columns {COLUMNS}")
    groups: dict[tuple[str, str, str, str], list[dict[str, str]]] = {}
    for row in rows:
        groups.setdefault((row["date"], row["saddle"], row["object"], row["diameter_mm"]),
                          []).append(row)
    out = []
    for (date, saddle, obj, diameter), group in groups.items():
        if obj not in OBJECT_NAMES:
            raise ValueError(f"object must be one of {sorted(OBJECT_NAMES)}, got {obj!r}")
        speeds = sorted({float(r["rps"]) for r in group})
        times = tuple(np.array([float(r["lifetime_s"]) for r in group if float(r["rps"]) == f])
                      for f in speeds)
        d = float(diameter)
        out.append(Series(date, saddle, float(group[0]["c_plus_per_m"]),
                          float(group[0]["c_minus_per_m"]), OBJECT_NAMES[obj],
                          d if d > 0 else None, np.array(speeds), times))
    return out


def _crossing(rps: np.ndarray, mean: np.ndarray, level: float, i: int) -> float:
    """The speed between points i-1 and i where the curve crosses ``level`` (linear)."""
    m0, m1 = mean[i - 1], mean[i]
    return float(rps[i - 1] + (level - m0) * (rps[i] - rps[i - 1]) / (m1 - m0))


def onset(rps: np.ndarray, mean: np.ndarray) -> float:
    """The speed where the mean lifetime first rises through half the curve's highest mean
    (linear between speeds); NaN if it never does."""
    half = float(np.max(mean)) / 2
    for i in range(1, len(mean)):
        if mean[i - 1] < half <= mean[i]:
            return _crossing(rps, mean, half, i)
    return math.nan


def cutoff(rps: np.ndarray, mean: np.ndarray) -> float:
    """Where a window closes: the speed above the highest mean where the mean first falls
    back below half of it (linear between speeds); NaN if it never does."""
    top = int(np.argmax(mean))
    half = float(mean[top]) / 2
    for i in range(top + 1, len(mean)):
        if mean[i] < half <= mean[i - 1]:
            return _crossing(rps, mean, half, i)
    return math.nan


def median_log_error(predicted: np.ndarray, measured: np.ndarray) -> float:
    """The median over speeds of |ln(predicted / measured)|."""
    return float(np.median(np.abs(np.log(np.asarray(predicted) / np.asarray(measured)))))
