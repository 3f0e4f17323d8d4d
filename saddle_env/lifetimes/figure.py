"""The lifetime figures: for every lab series, measured trapping times against predicted ones.

`draw_series` draws one series' panel (the lab's mean ± standard deviation by speed, model
curves, rigid-ball theory's threshold); `plot_validation` draws the leave-one-series-out
check that `saddle_env.lifetimes.fit` writes, and `saddle-reproduce --only lifetimes` draws
the shipped calibration with the same function.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from .data import Series

CITATION = "lab data: Barnett et al. 2025, arXiv:2505.04035"
STYLES = {
    "rigid ball": dict(color="0.55", ls=":", lw=1.5, label="rigid ball, level (launch only)"),
    "calibrated": dict(color="C3", ls="-", marker="o", ms=3, label="calibrated model"),
    "held out": dict(color="C3", ls="-", marker="o", ms=3,
                     label="calibrated on the other series"),
}


def draw_series(ax: Any, s: Series, curves: Mapping[str, Sequence[float]],
                threshold_rps: float) -> None:
    """One series: the lab's points with error bars, each curve in ``curves`` (its
    `STYLES` key → mean lifetime per speed), and the rigid-ball threshold as a dashed line."""
    ax.errorbar(s.rps, s.mean, yerr=s.std, fmt="s", color="k", ms=4, capsize=2,
                label="lab: mean ± s.d.")
    for key, values in curves.items():
        ax.plot(s.rps, values, **STYLES[key])
    if math.isfinite(threshold_rps):
        ax.axvline(threshold_rps, color="C0", lw=0.8, ls="--", label="rigid-ball threshold")
    ax.set_yscale("log")
    ax.set_ylim(0.5, 150)
    ax.set_title(s.name, fontsize=10)
    ax.set_xlabel("saddle speed [rev/s]")
    ax.set_ylabel("lifetime [s]")
    ax.grid(alpha=0.3, which="both")


def figure_of(series: Sequence[Series], curves: Sequence[Mapping[str, Sequence[float]]],
              thresholds: Sequence[float], title: str) -> Any:
    """A figure with one panel per series (4 columns)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = 4
    fig, axes = plt.subplots(math.ceil(len(series) / cols), cols, figsize=(16, 7.5),
                             squeeze=False)
    for ax, s, c, th in zip(axes.flat, series, curves, thresholds):
        draw_series(ax, s, c, th)
    for ax in list(axes.flat)[len(series):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7, loc="lower right")
    fig.suptitle(f"{title} ({CITATION})", fontsize=11)
    fig.tight_layout()
    return fig


def plot_validation(series: Sequence[Series], rows: list[dict], path: Path) -> Path:
    """The leave-one-series-out figure, written to ``path`` (PNG)."""
    import matplotlib.pyplot as plt

    from ..jobs.files import atomic_open

    curves, thresholds = [], []
    for s in series:
        mine = {r["variant"]: r for r in rows if r["series"] == s.name}
        curves.append({"rigid ball": mine["rigid ball"]["predicted_s"],
                       "held out": mine["calibrated"]["predicted_s"]})
        thresholds.append(mine["calibrated"]["theory_threshold_rps"])
    fig = figure_of(series, curves, thresholds,
                    "Trapping times on real saddles, each series predicted by the model "
                    "calibrated on the others")
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, dpi=100, format="png")
    plt.close(fig)
    return Path(path)
