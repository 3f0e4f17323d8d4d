"""The figure of a fit: each track's measured positions against the fitted model's, and the
residuals over time."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .fit import FitResult

MAX_PANELS = 4


def plot_fit(result: FitResult, path: str | Path, title: str = "") -> Path:
    """Write a PNG of up to four tracks: the orbit seen from above (measured dots, fitted
    line, mm) and the position residual over time (mm). Needs matplotlib."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:  # pragma: no cover - the [test] extra has it
        raise ImportError("the fit's plot needs matplotlib: pip install matplotlib") from exc
    model = result.model
    if model is None or result.x is None:
        raise ValueError("this FitResult carries no model to plot")
    ev = model.evaluate(result.x)
    plans = model.layout.plans[:MAX_PANELS]
    fig, axes = plt.subplots(2, len(plans), figsize=(3.6 * len(plans), 6.4), squeeze=False)
    for k, plan in enumerate(plans):
        meas, pred = plan.xy * 1e3, ev.predicted[k] * 1e3
        ax = axes[0, k]
        ax.plot(meas[:, 0], meas[:, 1], ".", ms=2.5, color="0.55", label="measured")
        ax.plot(pred[:, 0], pred[:, 1], "-", lw=0.9, color="C3", label="fitted model")
        ax.plot(pred[plan.nodes, 0], pred[plan.nodes, 1], "o", ms=2.5, mfc="none",
                color="C0", label="segment starts")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x [mm] (lab)")
        if k == 0:
            ax.set_ylabel("y [mm] (lab)")
            ax.legend(fontsize=7, loc="upper right")
        ax.set_title(f"{Path(plan.track.source).name}\nrms {result.tracks[k]['rms_m'] * 1e3:.2f} mm",
                     fontsize=8)
        ax = axes[1, k]
        err = np.hypot(*(pred - meas).T)
        ax.plot(plan.t - plan.t[0], err, lw=0.8, color="C3")
        ax.set_xlabel("t − t₀ [s]")
        if k == 0:
            ax.set_ylabel("|model − measured| [mm]")
    lines = [f"{e.name} = {e.value:.4g} [{e.low:.4g}, {e.high:.4g}] {e.unit}"
             for e in result.estimates.values()]
    fig.suptitle((title + "\n" if title else "") + ";  ".join(lines), fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


__all__ = ["plot_fit"]
