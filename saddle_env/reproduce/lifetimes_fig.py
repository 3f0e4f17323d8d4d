"""``lifetimes``: real saddles (not in the paper). For every series of the lab's releases
(`saddle_env.lifetimes.load_lab_series`), the measured mean trapping time ± its standard
deviation by speed, the shipped calibration's prediction and the level rigid ball's.

The rigid ball gets the calibrated launcher and nothing else a real saddle adds: below its
threshold it leaves as fast as the lab's balls do, above it it is kept for the whole
``t_max`` (120 s). The held-out check (each series predicted by a model calibrated on the
others) is `python -m saddle_env.lifetimes.fit`'s figure.
"""

from __future__ import annotations

import numpy as np

from ..lifetimes import load_calibration, load_lab_series, predict_lifetimes
from ..lifetimes.figure import figure_of
from ..lifetimes.fit import theory_threshold
from .context import Context

RELEASES = 24  # per speed, as the calibration simulated (quick: QUICK_RELEASES)
QUICK_RELEASES = 3
QUICK_T_MAX = 20.0  # [s] quick runs keep a trapped ball this long, not the model's t_max


def fig_lifetimes(ctx: Context) -> None:
    """Draw the real-saddle lifetimes figure (the module's docstring) into ``ctx``'s folder."""
    model, record = load_calibration()
    releases = QUICK_RELEASES if ctx.quick else RELEASES
    if ctx.quick:
        model = model.with_(t_max=QUICK_T_MAX)
    rigid = model.with_(tilt=0.0, rolling_resistance=0.0, rolling_drag=0.0, film_drag=0.0,
                        evaporation_mean=float("inf"), evaporation_spread=0.0)
    series = load_lab_series()
    curves: list[dict[str, list[float]]] = []
    thresholds: list[float] = []
    rows: dict[str, list] = {k: [] for k in ("series", "rps", "lab_mean_s", "lab_std_s",
                                                     "calibrated_s", "rigid_s")}
    seed = int(str(record["seed"]))
    for s in series:
        cal, rig = (predict_lifetimes(s.c_plus, s.c_minus, s.obj, s.rps, model=m,
                                      diameter_mm=s.diameter_mm, releases=releases,
                                      seed=seed) for m in (model, rigid))
        curves.append({"rigid ball": rig.mean_s.tolist(), "calibrated": cal.mean_s.tolist()})
        thresholds.append(theory_threshold(s, model.g))
        for col, values in (("rps", s.rps), ("lab_mean_s", s.mean), ("lab_std_s", s.std),
                            ("calibrated_s", cal.mean_s), ("rigid_s", rig.mean_s)):
            rows[col].extend(np.asarray(values, dtype=float).tolist())
        rows["series"].extend([s.name] * len(s.rps))
    ctx.write_csv("lifetimes", rows, comments=[
        "Mean trapping times by speed: the lab's (Barnett et al. 2025, arXiv:2505.04035) and "
        f"predicted ({releases} releases per speed, seed {record['seed']}).",
        f"calibration: {record['command']} ({record['date']})"])
    fig = figure_of(series, curves, thresholds,
                    "Trapping times on real saddles: the shipped calibration against the lab")
    ctx.save_png(fig, "lifetimes")
    ctx.update_summary({"lifetimes": {
        "releases_per_speed": releases, "calibration": record["model"],
        "convention": "lab-rest: released at rest in the laboratory, not spinning, at a random "
                      "turn of the saddle"}})
